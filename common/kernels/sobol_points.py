"""Scrambled Sobol' points by direct evaluation (common.sobol_stream).

Point j of a scrambled Sobol' engine in scipy's Gray-code order is
``shift XOR (XOR of the scrambled direction numbers sv[:, b] over the set bits b of j^(j>>1))``,
scaled by 2^-bits. Evaluating that per point needs no engine state, so one scrambling serves
every block of every set, from any thread, with bitwise the points scipy would draw.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _real(q):
    """The float64 of a point's digits (< 2^bits ≤ 2^63: exact through int64, which converts in
    one instruction where uint64 takes several)."""
    return np.float64(np.int64(q))


@njit(cache=True, nogil=True)
def draw(sv, shift, start, count, scale, out):
    """Points [start, start+count) of the engine (sv (d, bits) uint, shift (d,) uint) into
    ``out`` (count, d) float64: the first by the formula, each next one from its predecessor by
    one XOR (Gray code: index j flips direction number ctz(j))."""
    d, bits = sv.shape
    if count <= 0:
        return
    q = shift.copy()
    g = start ^ (start >> 1)
    b = 0
    while g != 0 and b < bits:
        if g & 1:
            for a in range(d):
                q[a] ^= sv[a, b]
        g >>= 1
        b += 1
    for a in range(d):
        out[0, a] = _real(q[a]) * scale
    for i in range(1, count):
        j = start + i
        c = 0
        while (j >> c) & 1 == 0:
            c += 1
        if c < bits:
            for a in range(d):
                q[a] ^= sv[a, c]
        for a in range(d):
            out[i, a] = _real(q[a]) * scale


@njit(cache=True, nogil=True)
def draw_padded(sv, shift, dims, scale, start, count, perms, out):
    """Padded replications sampling (common.sobol_stream.SobolStream.padded) in one call: group
    g (engine sv[g, :dims[g]], shift[g, :dims[g]]) draws points [start, start+count) as
    :func:`draw` does, and its rows are taken in the order perms[g] (group 0 in order, row r of
    group g > 0 is point perms[g, r]) into out's columns after the earlier groups'."""
    groups = sv.shape[0]
    d0 = 0
    for g in range(groups):
        d = dims[g]
        tmp = np.empty((count, d))  # (C order, as draw's Python callers pass it: one compiled draw)
        draw(sv[g, :d], shift[g, :d], start, count, scale, tmp)
        for r in range(count):
            i = perms[g, r] if g > 0 else r
            for a in range(d):
                out[r, d0 + a] = tmp[i, a]
        d0 += d
