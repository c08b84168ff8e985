"""The package layout as a test (issue 15): imports only point down, no cycles, no huge classes.

Layers, lowest first: ``common`` (scene, sampling, wire formats) < ``worker`` (rendering a task)
< ``master`` (scheduling, frame assembly, viewer, CLI) < ``bench`` (benchmarks). A module may
import its own layer and the layers below it, never one above. One exception, by rule: the
``igi bench`` subcommand of ``master/cli.py`` imports the ``bench`` registry, and only inside
a function (a lazy import), so that nothing of ``bench`` loads unless a benchmark runs. The
product packages never import ``tests`` (``tests/support`` is for tests only).

Every import counts for cycles, also the ones inside functions: a lazy import hides a cycle
from the interpreter, not from the reader. Imports through ``importlib`` are not followed.
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

from tests.support.paths import ROOT

PACKAGES = ("common", "worker", "master", "bench")
LAYER = {p: i for i, p in enumerate(PACKAGES)}
# (importing file, imported top-level package): allowed upward imports, only inside functions
LAZY_UPWARD_OK = {("master/cli.py", "bench")}
MAX_CLASS_LINES = 500
# classes over MAX_CLASS_LINES that are known and being worked on: "file:Class" -> why
KNOWN_LONG_CLASSES: dict[str, str] = {
    # (none: common/mitsuba_xml.py's _Loader, 651 lines when this test was written, was split
    # into the document walk and one module per kind of plugin, issue 15)
}


def _files() -> dict[str, Path]:
    """module name -> file, for every .py file of the product and benchmark packages."""
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _is_package(module: str, files: dict[str, Path]) -> bool:
    if module in PACKAGES:
        return True
    f = files.get(module)
    return f is not None and f.name == "__init__.py"


def _local(name: str) -> str:
    """``igi.common.scene`` -> ``common.scene``: installed names to this file's module names
    (the folders of the repository); a bare top-level ``common`` stays as it is (and fails
    :func:`test_product_imports_name_the_igi_namespace`)."""
    return name[4:] if name.startswith("igi.") else name


def _imports(module: str, path: Path, files: dict[str, Path]):
    """(imported module or top-level name, line, lazy) for every import statement of ``path``;
    ``lazy``: the import is inside a function (runs when the function is called)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if _is_package(module, files) else module.rpartition(".")[0]

    def visit(node, lazy):
        for child in ast.iter_child_nodes(node):
            inner = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    yield _local(alias.name), child.lineno, lazy
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")
                    base = base[:len(base) - (child.level - 1)]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = _local(child.module)
                for alias in child.names:  # `from pkg import mod` imports the module pkg.mod
                    sub = _local(f"{child.module}.{alias.name}") if not child.level else f"{target}.{alias.name}"
                    yield (sub if sub in files else target), child.lineno, lazy
            yield from visit(child, inner)

    yield from visit(tree, False)


def _graph():
    files = _files()
    edges = defaultdict(set)  # module -> internal modules it imports
    imports = []  # (module, file, target, line, lazy)
    for mod, path in files.items():
        for target, line, lazy in _imports(mod, path, files):
            imports.append((mod, path, target, line, lazy))
            # the deepest module of ours that `target` names (import a.b.c loads a.b.c)
            name = target
            while name and name not in files:
                name = name.rpartition(".")[0]
            if name and name != mod:
                edges[mod].add(name)
    return files, edges, imports


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def test_the_graph_sees_the_known_imports():
    files, edges, _ = _graph()
    assert {"common.scene", "worker.renderer", "master.broker", "bench.scaling"} <= set(files)
    assert "common.scene" in edges["worker.renderer"] or "common.scene" in edges["worker.caustics"]
    assert "master.scheduler" in edges["master.frame_loop"]  # relative import: from . import scheduler
    assert "bench.scaling_model" in edges["bench.scaling"]
    assert "bench" in edges["master.cli"]  # the one lazy upward import


def test_product_imports_name_the_igi_namespace():
    # installed, the packages are igi.common, igi.worker, ...: a bare `import common` works
    # only from a checkout with the repository on sys.path, and names someone else's package
    bad = []
    for pkg in PACKAGES + ("tests",):
        for f in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(), str(f))):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                    names = [node.module]
                bad += [f"{_rel(f)}:{node.lineno} imports {n}" for n in names if n.split(".")[0] in PACKAGES]
    assert not bad, "imports without the igi. namespace:\n" + "\n".join(bad)


def test_pyproject_installs_every_package_folder_under_igi():
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    folders = {"igi." + ".".join(d.relative_to(ROOT).parts)
               for pkg in PACKAGES for d in [ROOT / pkg, *(ROOT / pkg).rglob("*")]
               if d.is_dir() and (d / "__init__.py").is_file()}
    assert folders == listed, f"package folders {sorted(folders)} vs pyproject {sorted(listed)}"
    assert {f"igi.{p}": p for p in PACKAGES} == cfg["package-dir"]


def test_no_import_points_up_a_layer():
    _, _, imports = _graph()
    bad = []
    for mod, path, target, line, lazy in imports:
        src, dst = mod.split(".")[0], target.split(".")[0]
        if dst == "tests":
            bad.append(f"{_rel(path)}:{line} imports {target} (tests/ is for tests only)")
        if dst not in LAYER or LAYER[dst] <= LAYER[src]:
            continue
        if lazy and (_rel(path), dst) in LAZY_UPWARD_OK:
            continue
        bad.append(f"{_rel(path)}:{line} imports {target}{' (inside a function)' if lazy else ''}: "
                   f"{src} must not import {dst}")
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_no_import_cycle_between_files():
    files, edges, _ = _graph()
    # Tarjan's strongly connected components: any component of more than one file is a cycle
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(files):
        if v not in index:
            strong(v)
    assert not comps, "import cycles: " + "; ".join(" <-> ".join(c) for c in comps)


def _long_classes() -> dict[str, int]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(), str(f))):
                if isinstance(node, ast.ClassDef):
                    n = node.end_lineno - node.lineno + 1
                    if n > MAX_CLASS_LINES:
                        out[f"{_rel(f)}:{node.name}"] = n
    return out


def test_no_class_over_500_lines():
    long = _long_classes()
    new = {k: n for k, n in long.items() if k not in KNOWN_LONG_CLASSES}
    assert not new, f"classes over {MAX_CLASS_LINES} lines: {new}"


def test_known_long_classes_are_still_long():
    # once a listed class is split, take it off KNOWN_LONG_CLASSES
    long = _long_classes()
    fixed = sorted(set(KNOWN_LONG_CLASSES) - set(long))
    assert not fixed, f"no longer over {MAX_CLASS_LINES} lines, remove from KNOWN_LONG_CLASSES: {fixed}"


def test_no_benchmarks_in_master():
    assert not sorted(p.name for p in (ROOT / "master").glob("bench_*.py"))


def test_every_registered_benchmark_has_its_entry_points():
    import importlib

    from igi import bench

    for name, b in bench.BENCHES.items():
        assert b.module.startswith("igi.bench."), name
        assert (ROOT / (b.module.removeprefix("igi.").replace(".", "/") + ".py")).is_file(), name
        mod = importlib.import_module(b.module)
        assert callable(getattr(mod, "add_arguments", None)) and callable(getattr(mod, "run", None)), name
