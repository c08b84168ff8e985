"""A small thread pool for the master's per-frame numpy work (issue 12).

numpy releases the GIL inside its ufunc loops, copies and ``take``, and lz4 releases it while
decompressing, so frame finishing (wire → float conversion, discontinuity filter, compose) runs
in parallel stripes on threads over shared arrays — no copies, no processes. Every parallel
stage writes disjoint output elements with exactly the operations of the serial path, so the
result does not depend on the number of threads (tests/bench/test_scaling_model.py checks it).

Threads: ``IGI_MASTER_THREADS`` (default: the machine's cores), or :func:`set_threads`.
With 1 thread everything runs inline in the caller.
"""
from __future__ import annotations

import concurrent.futures as cf
import os
import threading
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")

_lock = threading.Lock()
_pool: cf.ThreadPoolExecutor | None = None
_pool_threads = 0
_threads: int | None = None


def default_threads() -> int:
    env = os.environ.get("IGI_MASTER_THREADS", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    return max(1, os.cpu_count() or 1)


def threads() -> int:
    """Threads the master's parallel stages use."""
    return _threads if _threads is not None else default_threads()


def set_threads(n: int | None) -> int:
    """Use ``n`` threads from now on (None: back to the default); returns the previous count."""
    global _threads
    prev = threads()
    _threads = None if n is None else max(1, int(n))
    return prev


def _executor(n: int) -> cf.ThreadPoolExecutor:
    global _pool, _pool_threads
    with _lock:
        if _pool is None or _pool_threads != n:
            old = _pool
            _pool = cf.ThreadPoolExecutor(max_workers=n, thread_name_prefix="igi-master-par")
            _pool_threads = n
            if old is not None:
                old.shutdown(wait=False)
        return _pool


def pmap(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, spread over the pool (in order; exceptions propagate).

    Do not call from inside ``fn`` (no nesting: a saturated pool would wait on itself)."""
    items = list(items)
    n = threads()
    if n <= 1 or len(items) <= 1 or threading.current_thread().name.startswith("igi-master-par"):
        return [fn(x) for x in items]
    ex = _executor(n)
    # the caller takes the first item itself: one hand-off fewer, and no idle caller
    futs = [ex.submit(fn, x) for x in items[1:]]
    first = fn(items[0])
    return [first] + [f.result() for f in futs]
