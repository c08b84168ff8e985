"""Python's cyclic garbage collector kept off the frame path.

A worker or master holds ~160 000 long-lived objects once its kernels are loaded (numba's
dispatchers and type caches, the scene, the BVH wrappers, cached sets). Every full collection
walks all of them: ~40 ms with the GIL held, once every ~20 accumulated frames at 320×240 on
cornell-box-sphere — a stall of a fifth of a frame in the middle of one, on top of ~0.2 ms a
frame of young collections. The frame path makes almost no reference cycles (numpy arrays and
tuples are freed by reference counting), so after start-up and after a scene is installed the
objects alive are moved out of the collector's view (``gc.freeze``, CPython ≥ 3.7), and young
collections run less often. Garbage made later is still collected; objects frozen and dropped
later are freed by reference counting as before, and the next settle collects any cycle among
them first (``gc.unfreeze`` + ``gc.collect``).
"""
from __future__ import annotations

import gc
import threading

YOUNG_THRESHOLD = 10_000  # allocations between young collections (CPython's default: 700)

_lock = threading.Lock()


def settle_long_lived() -> int:
    """Collect what is garbage now, then keep every object alive out of later collections and
    raise the young generation's threshold to :data:`YOUNG_THRESHOLD`. Returns the number of
    objects frozen. Call after start-up and after a scene is installed (one full collection:
    ~40 ms at a point where no frame waits)."""
    with _lock:  # threads settling at once would collect twice for nothing
        gc.unfreeze()
        gc.collect()
        gc.freeze()
        young, middle, old = gc.get_threshold()
        if young < YOUNG_THRESHOLD:
            gc.set_threshold(YOUNG_THRESHOLD, middle, old)
        return gc.get_freeze_count()
