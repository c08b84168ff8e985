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
    ``out`` (count, d) float64."""
    d, bits = sv.shape
    for i in range(count):
        j = start + i
        g = j ^ (j >> 1)
        for a in range(d):
            q = shift[a]
            b = 0
            gg = g
            while gg != 0 and b < bits:
                if gg & 1:
                    q ^= sv[a, b]
                gg >>= 1
                b += 1
            out[i, a] = np.float64(q) * scale
