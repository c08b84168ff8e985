"""The hashed-grid photon query (Wald et al. 2002 §4.1), compiled: per query, the 2×2×2 cells
of size 2r around it (a third layer where rounding widens the ball's cell span), each found by
binary search in the sorted occupied-cell keys (skipped for cells an occupancy bitmap marks
empty: photon sets are sparse, most cells a query touches hold nothing), and the photons
within r.

Two passes (count, then fill) so the pair arrays are allocated once at their exact size; the
fill visits only the queries the count found photons for (most of a frame's end points are
nowhere near a caustic: the second pass was half the query's time).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_CELL_LIMIT = float(2 ** 60)


@njit(cache=True, nogil=True, error_model="numpy")
def _cell(v: float, inv: float) -> tuple:
    c = math.floor(v * inv)
    if not math.isfinite(c) or abs(c) >= _CELL_LIMIT:
        return False, 0
    return True, np.int64(c)


@njit(cache=True, nogil=True, error_model="numpy")
def _find(keys, key) -> int:
    lo, hi = 0, keys.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo < keys.shape[0] and keys[lo] == key:
        return lo
    return -1


@njit(cache=True, nogil=True, error_model="numpy")
def _visit(q, rows, nrows, every, r, w, inv, origin, ext, keys, starts, counts, order, points, occupied, out_p,
           out_q, fill):
    """Pairs of queries ``rows[:nrows]`` (``every``: queries 0 … nrows - 1): counted, or
    written to out_p/out_q (``fill``). Counting, the queries that found a photon are written
    to ``rows`` in order (it may be the list read: a query is written after it is read);
    returns (pairs, queries that found one)."""
    r2 = r * r
    bitmap = occupied.shape[0] > 0
    ey, ez = ext[1], ext[2]
    total = 0
    found = 0
    for t in range(nrows):
        i = t if every else rows[t]
        before = total
        g0, lx = _cell(q[i, 0] - w, inv)
        g1, hx = _cell(q[i, 0] + w, inv)
        g2, ly = _cell(q[i, 1] - w, inv)
        g3, hy = _cell(q[i, 1] + w, inv)
        g4, lz = _cell(q[i, 2] - w, inv)
        g5, hz = _cell(q[i, 2] + w, inv)
        if not (g0 and g1 and g2 and g3 and g4 and g5):
            continue
        # Rounding can widen the ball's span to a third layer; never less than two.
        hx, hy, hz = max(hx, lx + 1), max(hy, ly + 1), max(hz, lz + 1)
        for cx in range(lx, hx + 1):
            rx = cx - origin[0]
            if rx < 0 or rx >= ext[0]:
                continue
            for cy in range(ly, hy + 1):
                ry = cy - origin[1]
                if ry < 0 or ry >= ey:
                    continue
                for cz in range(lz, hz + 1):
                    rz = cz - origin[2]
                    if rz < 0 or rz >= ez:
                        continue
                    key = (rx * ey + ry) * ez + rz
                    if bitmap and (occupied[key >> 3] >> (key & 7)) & 1 == 0:
                        continue
                    h = _find(keys, key)
                    if h < 0:
                        continue
                    s = starts[h]
                    for t in range(s, s + counts[h]):
                        p = order[t]
                        d0 = points[p, 0] - q[i, 0]
                        d1 = points[p, 1] - q[i, 1]
                        d2 = points[p, 2] - q[i, 2]
                        if d0 * d0 + d1 * d1 + d2 * d2 <= r2:
                            if fill:
                                out_p[total] = p
                                out_q[total] = i
                            total += 1
        if not fill and total > before:
            rows[found] = i
            found += 1
    return total, found


@njit(cache=True, nogil=True, error_model="numpy")
def query(q, r, w, inv, origin, ext, keys, starts, counts, order, points, occupied):
    """(photon index, query index) of every photon within r of each query, grouped by
    ascending query index; the cells read span the query ± ``w`` (r, widened a little: see
    worker.hash_grid.SPAN_MARGIN); queries outside the grid's key space find nothing.
    ``occupied``: one bit per key of the key space (bit key & 7 of byte key >> 3), or empty:
    none kept."""
    empty = np.empty(0, np.int64)
    rows = np.empty(q.shape[0], np.int64)
    # (np.bool_, not literals: each literal would compile _visit once more)
    n, found = _visit(q, rows, q.shape[0], np.bool_(True), r, w, inv, origin, ext, keys, starts, counts, order, points,
                      occupied, empty, empty, np.bool_(False))
    out_p = np.empty(n, np.int64)
    out_q = np.empty(n, np.int64)
    _visit(q, rows, found, np.bool_(False), r, w, inv, origin, ext, keys, starts, counts, order, points, occupied,
           out_p, out_q, np.bool_(True))
    return out_p, out_q
