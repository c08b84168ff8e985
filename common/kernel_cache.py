"""numba's on-disk kernel cache kept true to the sources the kernels were compiled from.

numba keys a cached kernel to its own source file only: a kernel that inlines or calls a
function of another module (the gather, the eye paths and the light paths all inline
``common.kernels.bsdf``) keeps its old machine code when only that other module changed — after
a ``git pull`` that touches ``common/kernels/bsdf.py`` alone, a worker would render with the old
BSDFs, silently. So before any kernel runs, each kernel module's sources and those of the kernel
modules it imports (transitively) are hashed; where the hash differs from the one stamped beside
the module's cache, that module's cached kernels are dropped (numba compiles them again on first
use) and the new hash is stamped. Only caches beside the sources (numba's default) are kept
this way; with ``NUMBA_CACHE_DIR`` set, or sources that cannot be written beside, nothing is
done.
"""
from __future__ import annotations

import ast
import glob
import hashlib
import os
import threading

# The packages whose modules hold compiled kernels, relative to the igi package root.
KERNEL_PACKAGES = ("common/kernels", "worker/kernels", "master/kernels")
_STAMP = ".igi-sources.sha1"  # <module><_STAMP> beside the module's cached kernels

_lock = threading.Lock()
_done = False


def kernel_modules(root: str) -> dict[str, str]:
    """Dotted name (relative to the igi package, e.g. ``common.kernels.bsdf``) -> source path
    of every kernel module under ``root``."""
    out = {}
    for pkg in KERNEL_PACKAGES:
        for path in sorted(glob.glob(os.path.join(root, pkg, "*.py"))):
            name = os.path.splitext(os.path.basename(path))[0]
            if name != "__init__":
                out[pkg.replace("/", ".") + "." + name] = path
    return out


def imported_kernel_modules(name: str, source: str, modules: dict[str, str]) -> set[str]:
    """The kernel modules (keys of ``modules``) that module ``name`` imports from."""
    package = name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:  # relative: from . / from .x
            base = package.split(".")
            base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
            target = ".".join(base + ([node.module] if node.module else []))
        else:
            target = node.module or ""
            if not target.startswith("igi."):
                continue
            target = target[len("igi."):]
        if target in modules:
            found.add(target)
        for alias in node.names:  # from package import module
            if f"{target}.{alias.name}" in modules:
                found.add(f"{target}.{alias.name}")
    found.discard(name)
    return found


def _source(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def source_hashes(root: str) -> dict[str, tuple[str, str]]:
    """Module -> (its source path, sha1 over its source and those of every kernel module it
    imports, transitively)."""
    modules = kernel_modules(root)
    text = {m: _source(p) for m, p in modules.items()}
    deps = {m: imported_kernel_modules(m, text[m].decode("utf-8"), modules) for m in modules}
    out = {}
    for m in modules:
        seen, todo = {m}, [m]
        while todo:
            for d in deps[todo.pop()]:
                if d not in seen:
                    seen.add(d)
                    todo.append(d)
        h = hashlib.sha1()
        for d in sorted(seen):
            h.update(d.encode() + b"\0" + text[d] + b"\0")
        out[m] = (modules[m], h.hexdigest())
    return out


def drop_stale(root: str) -> list[str]:
    """Drop the cached kernels of every kernel module under ``root`` whose sources (its own or
    its imported kernel modules') changed since its stamp, and stamp the new hash. Returns the
    modules whose caches were dropped (a module seen for the first time is stamped, and its
    cache, which numba wrote for these very sources or none, is dropped too)."""
    dropped = []
    for m, (path, digest) in source_hashes(root).items():
        cache = os.path.join(os.path.dirname(path), "__pycache__")
        stem = os.path.splitext(os.path.basename(path))[0]
        stamp = os.path.join(cache, stem + _STAMP)
        if _read(stamp) == digest:
            continue
        for old in glob.glob(os.path.join(cache, f"{stem}.*.nbi")) + glob.glob(os.path.join(cache, f"{stem}.*.nbc")):
            try:
                os.remove(old)
            except OSError:  # another process dropped it first
                pass
        try:
            _write(stamp, digest)
        except OSError:  # sources not writable: numba caches elsewhere, nothing to keep true here
            continue
        dropped.append(m)
    return dropped


def keep_true() -> None:
    """:func:`drop_stale` for the installed igi, once per process, before its first kernel runs
    (the kernel packages call it on import); nothing with ``NUMBA_CACHE_DIR`` set."""
    global _done
    with _lock:
        if _done:
            return
        _done = True
        if os.environ.get("NUMBA_CACHE_DIR"):
            return
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        try:
            # the sources' sizes and times as numba itself checks them: unchanged, nothing to hash
            # (~0.2 ms; hashing and parsing the kernel modules ~60 ms a process)
            quick = hashlib.sha1(repr(sorted((p, os.stat(p).st_size, os.stat(p).st_mtime_ns)
                                             for p in kernel_modules(root).values())).encode()).hexdigest()
            mark = os.path.join(root, KERNEL_PACKAGES[0], "__pycache__", "igi-sources.quick")
            if _read(mark) == quick:
                return
            drop_stale(root)
            _write(mark, quick)
        except (OSError, SyntaxError, UnicodeDecodeError):  # never keep a worker from starting
            pass


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return None


def _write(path: str, text: str) -> None:
    """``text`` to ``path`` atomically (processes starting together agree on what is there)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{os.getpid()}"
    with open(tmp, "w") as f:
        f.write(text + "\n")
    os.replace(tmp, path)

