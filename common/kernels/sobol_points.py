"""Scrambled Sobol' points by direct evaluation (common.sobol_stream).

Point j of a scrambled Sobol' engine in scipy's Gray-code order is
``shift XOR (XOR of the scrambled direction numbers sv[:, b] over the set bits b of j^(j>>1))``,
scaled by 2^-bits. Evaluating that per point needs no engine state, so one scrambling serves
every block of every set, from any thread, with bitwise the points scipy would draw.
"""
from __future__ import annotations

import numpy as np
from numba import njit


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
        out[0, a] = np.float64(q[a]) * scale
    for i in range(1, count):
        j = start + i
        c = 0
        while (j >> c) & 1 == 0:
            c += 1
        if c < bits:
            for a in range(d):
                q[a] ^= sv[a, c]
        for a in range(d):
            out[i, a] = np.float64(q[a]) * scale
