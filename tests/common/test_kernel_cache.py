"""common.kernel_cache: a kernel module's cached machine code is dropped when its sources or
those of a kernel module it imports (transitively) change — and only then."""
from __future__ import annotations

import os

from igi.common import kernel_cache as kc


def _tree(root):
    files = {
        "common/kernels/a.py": "def f():\n    return 1\n",
        "common/kernels/b.py": "from .a import f\n",
        "worker/kernels/c.py": "from igi.common.kernels import b as kb\n",
        "worker/kernels/d.py": "import math\n",
        "master/kernels/e.py": "from igi.common.kernels.a import f\n",
    }
    for rel, text in files.items():
        path = os.path.join(root, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as fh:
            fh.write(text)


def _cache(root):
    """Fake cached kernels, two files per module, as numba names them."""
    for pkg, mods in (("common/kernels", "ab"), ("worker/kernels", "cd"), ("master/kernels", "e")):
        cache = os.path.join(root, pkg, "__pycache__")
        os.makedirs(cache, exist_ok=True)
        for m in mods:
            for name in (f"{m}.k-1.py311.nbi", f"{m}.k-1.py311.1.nbc"):
                open(os.path.join(cache, name), "w").close()


def _cached(root):
    return sorted(name.split(".")[0] for pkg in kc.KERNEL_PACKAGES
                  for name in os.listdir(os.path.join(root, pkg, "__pycache__")) if name.endswith(".nbi"))


def test_imports_are_resolved_relative_absolute_and_from_the_package(tmp_path):
    _tree(tmp_path)
    mods = kc.kernel_modules(str(tmp_path))
    dep = {m: kc.imported_kernel_modules(m, open(p).read(), mods) for m, p in mods.items()}
    assert dep["common.kernels.b"] == {"common.kernels.a"}
    assert dep["worker.kernels.c"] == {"common.kernels.b"}
    assert dep["master.kernels.e"] == {"common.kernels.a"}
    assert dep["worker.kernels.d"] == set() and dep["common.kernels.a"] == set()


def test_a_changed_module_drops_its_own_and_its_importers_caches_only(tmp_path):
    root = str(tmp_path)
    _tree(root)
    _cache(root)
    assert len(kc.drop_stale(root)) == 5  # first seen: stamped, caches of unknown sources dropped
    _cache(root)
    assert kc.drop_stale(root) == []  # same sources: every cache kept
    assert _cached(root) == ["a", "b", "c", "d", "e"]
    with open(os.path.join(root, "common/kernels/a.py"), "a") as fh:
        fh.write("# changed\n")
    dropped = kc.drop_stale(root)
    assert sorted(dropped) == ["common.kernels.a", "common.kernels.b", "master.kernels.e", "worker.kernels.c"]
    assert _cached(root) == ["d"]  # c inlines b, which imports a: all three stale
    _cache(root)
    assert kc.drop_stale(root) == []  # stamped anew
