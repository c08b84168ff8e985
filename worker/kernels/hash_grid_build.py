"""Building the hashed photon grid (worker.hash_grid, Wald et al. 2002 §4.1), compiled.

Why: a caustic photon set is a few hundred photons, and the numpy build (cells, bounding box,
keys, stable sort, unique, occupancy bitmap) was ~20 calls of ~8 µs each, ~170 µs a set, paid by
every set of every accumulated frame. Here it is one call. The arithmetic is the numpy build's
(float64 floor of x/(2r), int64 mixed-radix keys, a stable sort), so grids are identical to it
(tests/worker/test_hash_grid.py compares both).
"""
from __future__ import annotations

import numpy as np
from numba import njit

OK = 0
NON_FINITE = 1  # a photon position is NaN or infinite
OVERFLOW = 2  # a cell coordinate is beyond cell_limit
HUGE = 3  # the occupied box has >= radix_limit cells: the caller ranks coordinates instead


@njit(cache=True, nogil=True)
def build(pts, inv_cell, cell_limit, radix_limit, bitmap_cells):
    """Grid of the (n, 3) float64 photon positions ``pts`` (n >= 1) with cells of size
    1/inv_cell over the mixed-radix key space of their occupied bounding box.

    Returns (status, origin (3,), ext (3,), order, keys, starts, counts, occupied): status
    OK, or NON_FINITE / OVERFLOW / HUGE (the arrays then empty). ``order`` sorts the photons by
    key (stably); ``keys``/``starts``/``counts`` are the occupied cells in ascending key order and
    their photon ranges in ``order``; ``occupied`` is the bitmap of occupied keys when the box
    has at most ``bitmap_cells`` cells (else empty)."""
    n = pts.shape[0]
    cells = np.empty((n, 3), np.int64)
    origin = np.empty(3, np.int64)
    ext = np.empty(3, np.int64)
    z = np.empty(0, np.int64)
    none = np.empty(0, np.uint8)
    for i in range(n):
        for a in range(3):
            x = pts[i, a]
            if not np.isfinite(x):
                return NON_FINITE, origin, ext, z, z, z, z, none
    for i in range(n):
        for a in range(3):
            c = np.floor(pts[i, a] * inv_cell)
            if not (np.isfinite(c) and abs(c) < cell_limit):
                return OVERFLOW, origin, ext, z, z, z, z, none
            cells[i, a] = np.int64(c)
    for a in range(3):
        lo = cells[0, a]
        hi = cells[0, a]
        for i in range(1, n):
            lo = min(lo, cells[i, a])
            hi = max(hi, cells[i, a])
        origin[a] = lo
        ext[a] = hi - lo + 1
    # ext0·ext1·ext2 < radix_limit, without overflowing int64
    if ext[0] > (radix_limit - 1) // ext[1]:
        return HUGE, origin, ext, z, z, z, z, none
    if ext[2] > (radix_limit - 1) // (ext[0] * ext[1]):
        return HUGE, origin, ext, z, z, z, z, none
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = ((cells[i, 0] - origin[0]) * ext[1] + (cells[i, 1] - origin[1])) * ext[2] + (cells[i, 2] - origin[2])
    order = np.argsort(key, kind="mergesort")  # stable, as the numpy build's
    runs = 0
    prev = np.int64(-1)
    for q in range(n):
        k = key[order[q]]
        if q == 0 or k != prev:
            runs += 1
        prev = k
    keys = np.empty(runs, np.int64)
    starts = np.empty(runs, np.int64)
    counts = np.empty(runs, np.int64)
    r = -1
    for q in range(n):
        k = key[order[q]]
        if q == 0 or k != keys[r]:
            r += 1
            keys[r] = k
            starts[r] = q
            counts[r] = 0
        counts[r] += 1
    total = (np.float64(ext[0]) * np.float64(ext[1])) * np.float64(ext[2])
    occupied = none
    if total <= bitmap_cells:
        occupied = np.zeros((np.int64(total) + 7) // 8, np.uint8)
        for r in range(runs):
            occupied[keys[r] >> 3] |= np.uint8(1 << (keys[r] & 7))
    return OK, origin, ext, order, keys, starts, counts, occupied
