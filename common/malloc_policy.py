"""The C heap kept for reuse on the frame path (glibc's ``mallopt``).

Every task moves buffers of hundreds of kilobytes through the C heap: the master's lz4
decompression returns a fresh ``bytes`` of the tile's payload (~320 kB at 640x480), a
worker's encode makes its payload and compressed copy. glibc serves blocks that large with
``mmap``, or from the top of its heap which it trims back when they are freed; either way the
pages return to the kernel, and the next tile faults its buffer in page by page again
(measured at 640x480 on the master's decompression: ~2,000 faults a frame, glibc's dynamic
mmap threshold notwithstanding; a fault costs ~4 us on this VM, so 6-8 ms a frame, more than
the decompression itself).

:func:`reuse_freed_blocks` raises the mmap threshold, so such blocks come from the heap and
freed ones are reused, and the trim threshold, so the heap keeps its freed top instead of
returning it at once. The cost is resident memory: a process keeps the high-water mark of its
heap (bounded by the frames in flight on the master, by the tasks in flight on a worker).
Blocks above the threshold are mapped as before. Not glibc (musl, macOS): nothing changes.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import threading

# mallopt's parameter numbers (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

MMAP_THRESHOLD = 64 << 20  # blocks below are served from the heap: every tile-sized buffer
TRIM_THRESHOLD = 128 << 20  # free memory the heap keeps at its top before returning any

_lock = threading.Lock()
_applied: bool | None = None


def reuse_freed_blocks() -> bool:
    """Set the thresholds (once per process); True when glibc took them."""
    global _applied
    with _lock:
        if _applied is None:
            _applied = _mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) and _mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
        return _applied


def _mallopt(param: int, value: int) -> bool:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        fn = libc.mallopt
    except (OSError, AttributeError, TypeError):  # no C library by that name, or not glibc
        return False
    fn.argtypes = (ctypes.c_int, ctypes.c_int)
    fn.restype = ctypes.c_int
    return fn(param, value) == 1
