"""Compile the kernels of a cold cache in several processes at once (issue 16, start-up).

numba compiles one function at a time under the GIL: on a fresh checkout the warm-up
(worker.kernels.warm) compiled ~80 kernel signatures one after another, over four minutes
on one 2.25 GHz core, while the machine's other cores idled. Each kernel compiles on its own
given its argument types, so the signatures the warm-up compiles are listed in
``kernel_signatures.json`` beside this module (kernel, numba types as JSON, its own compile
seconds on a cold cache, the kernels it compiled inside it). A cold warm-up hands groups of
them (a kernel with the kernels compiled inside it, so that no two processes compile one
kernel at once) to one helper process per core, longest first (the greedy LPT schedule);
each compiles into numba's on-disk cache, then the warm-up loads them all. A stale list costs
only time: what it misses, the warm-up's render compiles as before.

``python -m igi.worker.kernels.warm --record-signatures`` records the list anew (on a cold
cache of its own); a test holds the committed list to what the warm-up compiles.
"""
from __future__ import annotations

import glob
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MANIFEST = Path(__file__).with_name("kernel_signatures.json")
_MODULE = "igi.worker.kernels.parallel_compile"  # (run with -m, __name__ is "__main__")


# ----------------------------------------------------------------------------------------------
# numba types <-> JSON


def type_spec(t) -> object:
    """A JSON form of one numba argument type (the kinds the kernels take)."""
    from numba.core import types

    if isinstance(t, types.Array):
        return {"array": [str(t.dtype), t.ndim, t.layout, bool(not t.mutable), bool(t.aligned)]}
    if isinstance(t, types.BaseTuple):
        return {"tuple": [type_spec(c) for c in t.types]}
    if isinstance(t, types.NoneType):
        return "none"
    if isinstance(t, types.NumPyRandomGeneratorType):
        return "rng"
    if isinstance(t, (types.Integer, types.Float, types.Boolean)) and not isinstance(t, types.Literal):
        return str(t)
    raise ValueError(f"parallel_compile: no JSON form for the numba type {t!r} ({type(t).__name__})")


def spec_type(s) -> object:
    """The numba type of :func:`type_spec`'s JSON form."""
    import numpy as np
    from numba import typeof
    from numba.core import types
    from numba.np.numpy_support import from_dtype

    if s == "none":
        return types.none
    if s == "rng":
        return typeof(np.random.default_rng(0))
    if isinstance(s, str):
        return from_dtype(np.dtype(s))
    if isinstance(s, dict) and "array" in s:
        dtype, ndim, layout, readonly, aligned = s["array"]
        return types.Array(from_dtype(np.dtype(dtype)), ndim, layout, readonly=readonly, aligned=aligned)
    if isinstance(s, dict) and "tuple" in s:
        return types.Tuple([spec_type(c) for c in s["tuple"]])
    raise ValueError(f"parallel_compile: not a type spec: {s!r}")


# ----------------------------------------------------------------------------------------------
# the list


def load_manifest(path: Path | None = None) -> list[dict]:
    """The recorded signatures ([] when the file is missing or unreadable: then nothing runs in
    parallel and the warm-up compiles as before)."""
    try:
        data = json.loads(Path(path or MANIFEST).read_text())
        # (each entry keeps its place in the list: ``inside`` names its callees by it)
        return [dict(e, index=i) for i, e in enumerate(data["signatures"])]
    except (OSError, ValueError, KeyError, TypeError):
        return []


def _dispatcher(name: str):
    module, attr = name.rsplit(".", 1)
    return getattr(importlib.import_module(module), attr)


def _sources(entries: list[dict]) -> dict[str, str | None]:
    """Module -> its source file (None where it cannot be found), for the entries' kernels:
    found without importing them."""
    import importlib.util

    out: dict[str, str | None] = {}
    for e in entries:
        module = e["kernel"].rsplit(".", 1)[0]
        if module not in out:
            try:
                spec = importlib.util.find_spec(module)
            except (ImportError, ValueError):
                spec = None
            out[module] = spec.origin if spec is not None and spec.origin else None
    return out


def _cache_dir(source: str) -> str:
    """Where numba keeps the cache of the kernels of ``source``: ``__pycache__`` beside it, or
    with NUMBA_CACHE_DIR set, ``<dir>/<parent folder>_<sha1 of the folder>`` (numba's
    UserProvidedCacheLocator)."""
    import hashlib

    folder = os.path.dirname(os.path.abspath(source))
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return os.path.join(user, f"{os.path.basename(folder)}_{hashlib.sha1(folder.encode()).hexdigest()}")
    return os.path.join(folder, "__pycache__")


def cache_located(entries: list[dict]) -> bool:
    """Can :func:`missing` see numba's cache: NUMBA_CACHE_DIR set, or every kernel folder's
    ``__pycache__`` writable (else numba caches in a per-user folder of its own choosing, as
    for an install in a read-only site-packages)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return True
    sources = _sources(entries).values()
    if None in sources:
        return False
    for folder in {os.path.dirname(os.path.abspath(src)) for src in sources}:
        cache = os.path.join(folder, "__pycache__")
        if not os.access(cache if os.path.isdir(cache) else folder, os.W_OK):
            return False
    return True


def missing(entries: list[dict]) -> list[dict]:
    """The entries whose kernel has no fresh index in numba's cache (``<module>.<kernel>-<line>
    .py<ver>.nbi`` written after the source was last changed): checked without importing numba
    or the kernels. An index may hold other signatures than the entry's: that costs the
    warm-up a compile, never a wrong answer."""
    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    sources = _sources(entries)
    out = []
    for e in entries:
        module, attr = e["kernel"].rsplit(".", 1)
        src = sources[module]
        if src is None:
            out.append(e)
            continue
        stem = os.path.basename(src).rsplit(".", 1)[0]
        changed = os.stat(src).st_mtime
        if not [p for p in glob.glob(os.path.join(_cache_dir(src), f"{stem}.{attr}-*.{tag}.nbi"))
                if os.stat(p).st_mtime >= changed]:
            out.append(e)
    return out


def groups(entries: list[dict]) -> list[list[dict]]:
    """The entries joined with the kernels compiled inside them (``inside``: their indices), each
    group ordered callees first: one process compiles a group, so no kernel is compiled by two
    processes at once and a caller finds its callees in the cache."""
    parent = list(range(len(entries)))
    at = {e.get("index", i): i for i, e in enumerate(entries)}  # list place -> place here (a subset: missing())

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, e in enumerate(entries):
        for callee in e.get("inside", []):
            j = at.get(callee)
            if j is not None:
                parent[find(j)] = find(i)
    out: dict[int, list[dict]] = {}
    for i, e in enumerate(entries):
        out.setdefault(find(i), []).append(e)
    return [sorted(g, key=lambda e: -e.get("depth", 0)) for g in out.values()]


def schedule(entries: list[dict], processes: int) -> list[list[dict]]:
    """Greedy LPT: groups by their recorded seconds, longest first, each to the least loaded of
    ``processes`` lists (empty lists dropped)."""
    bins: list[list[dict]] = [[] for _ in range(max(1, processes))]
    load = [0.0] * len(bins)
    for g in sorted(groups(entries), key=lambda g: -sum(e.get("seconds", 0.0) for e in g)):
        b = load.index(min(load))
        bins[b].extend(g)
        load[b] += sum(e.get("seconds", 0.0) for e in g)
    return [b for b in bins if b]


def compile_entries(entries: list[dict]) -> list[str]:
    """Compile each entry's kernel for its signature (numba writes its on-disk cache); returns
    the errors, one line each (a kernel that cannot compile here compiles, or fails, later in
    the warm-up, where its error is reported)."""
    errors = []
    for e in entries:
        try:
            _dispatcher(e["kernel"]).compile(tuple(spec_type(s) for s in e["signature"]))
        except Exception as exc:  # noqa: BLE001 - reported, and the warm-up tries again
            errors.append(f"{e['kernel']}: {type(exc).__name__}: {exc}")
    return errors


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def compile_in_parallel(entries: list[dict], processes: int | None = None, timeout: float = 1800.0) -> dict:
    """Compile ``entries`` in ``processes`` helper processes (default: the usable cores) into
    numba's on-disk cache; returns {"seconds", "processes", "kernels", "errors"}. The helpers
    inherit the environment (NUMBA_CACHE_DIR included), so they fill the cache this process
    then loads."""
    t0 = time.perf_counter()
    lists = schedule(entries, processes or usable_cores())
    procs = []
    for part in lists:
        fh = tempfile.NamedTemporaryFile("w", suffix=".json", delete=False)
        with fh:
            json.dump(part, fh)
        procs.append((subprocess.Popen([sys.executable, "-m", _MODULE, "--compile", fh.name],
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True), fh.name))
    errors = []
    for p, path in procs:
        try:
            out, _ = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            out, _ = p.communicate()
            errors.append(f"a compile helper ran over {timeout:.0f} s and was stopped")
        errors += [line for line in (out or "").splitlines() if line.startswith("error: ")]
        if p.returncode not in (0, None) and not errors:
            errors.append(f"a compile helper exited with status {p.returncode}")
        os.unlink(path)
    return {"seconds": time.perf_counter() - t0, "processes": len(lists), "kernels": len(entries), "errors": errors}


# ----------------------------------------------------------------------------------------------
# recording


def record(warm_up, kernel_dispatchers) -> list[dict]:
    """Run ``warm_up()`` on this process's (cold) cache, timing each kernel's own compile and
    noting the kernels compiled inside it; returns the entries of ``kernel_dispatchers()``'s
    signatures (sorted by kernel). (worker.kernels.warm passes its own: this module must not
    import it, warm imports this.)"""
    from numba.core import dispatcher

    own: dict[tuple, float] = {}
    inside: dict[tuple, list] = {}
    depth: dict[tuple, int] = {}
    stack: list[list] = []  # [key, seconds spent in nested compiles]
    real = dispatcher.Dispatcher.compile

    def timed(self, sig):
        from numba.core import sigutils

        args, _ = sigutils.normalize_signature(sig)
        k = (f"{self.py_func.__module__}.{self.py_func.__name__}", tuple(args))
        fresh = k not in own
        if fresh:
            own[k] = 0.0
            depth[k] = len(stack)
            if stack:
                inside.setdefault(stack[-1][0], []).append(k)
        t = time.perf_counter()
        stack.append([k, 0.0])
        try:
            return real(self, sig)
        finally:
            _, nested = stack.pop()
            dt = time.perf_counter() - t
            own[k] += dt - nested
            if stack:
                stack[-1][1] += dt

    dispatcher.Dispatcher.compile = timed
    try:
        warm_up()
    finally:
        dispatcher.Dispatcher.compile = real
    keys = sorted(((name, tuple(sig)) for name, disp in kernel_dispatchers().items() for sig in disp.signatures),
                  key=lambda k: (k[0], json.dumps([type_spec(t) for t in k[1]])))
    index = {k: i for i, k in enumerate(keys)}
    return [{"kernel": k[0], "signature": [type_spec(t) for t in k[1]], "seconds": round(own.get(k, 0.0), 2),
             "depth": depth.get(k, 0), "inside": sorted(index[c] for c in inside.get(k, []) if c in index)}
            for k in keys]


def write(warm_up, kernel_dispatchers, argv: list[str]) -> int:
    """Record the list anew (:func:`record`) in a fresh process on a cold cache of its own, so
    its seconds are compile times; ``argv``: the command that re-runs this in that process."""
    if not os.environ.get("NUMBA_CACHE_DIR") or os.environ.get("IGI_RECORDING_CACHE") != os.environ["NUMBA_CACHE_DIR"]:
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache, IGI_RECORDING_CACHE=cache)
            return subprocess.call([sys.executable, *argv], env=env)
    import numba

    entries = record(warm_up, kernel_dispatchers)
    lines = ",\n".join(json.dumps(e, separators=(",", ":")) for e in entries)  # one kernel a line
    MANIFEST.write_text(f'{{"numba": "{numba.__version__}", "signatures": [\n{lines}\n]}}\n')
    print(f"wrote {MANIFEST} ({len(entries)} signatures, {sum(e['seconds'] for e in entries):.0f} s of compiles)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The helpers' entry: ``--compile LIST.json``."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--compile"] and len(argv) == 2:
        for line in compile_entries(json.loads(Path(argv[1]).read_text())):
            print(f"error: {line}", flush=True)
        return 0
    print("usage: python -m igi.worker.kernels.parallel_compile --compile LIST.json "
          "(record the list with python -m igi.worker.kernels.warm --record-signatures)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
