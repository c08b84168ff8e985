"""Encode side of the wire codec (common.codec, version 1), compiled: the octahedral snorm16
normals of a task's buffers.

Why: the numpy form made a dozen passes with temporaries over each tile's normals (~0.5 ms a
12k-pixel tile, the largest piece of a task's encode); here each normal is read once. The float
operations are the numpy encoder's, in float32 and in the same order, so the codes are
bit-identical to it (tests/common/test_wire_encode_kernel.py against tests/support/oracle_codec.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_SNORM = np.float32(32767.0)
_ZERO_NORMAL = -32768  # outside the snorm16 range: a zero or non-finite normal


@njit(cache=True, nogil=True, error_model="numpy")
def oct_encode_into(n, out) -> None:
    """(P, 3) float32 normals -> ``out`` (P, 2) int16 octahedral snorm16: p = n_xy / |n|_1, the
    lower hemisphere folded across the diamond's edges ((1 - |p_other|)·sign(p), sign(0) = +1),
    rint(clip(p, -1, 1)·32767); (-32768, -32768) where |n|_1 is 0 or not finite."""
    one = np.float32(1.0)
    for i in range(n.shape[0]):
        x, y, z = n[i, 0], n[i, 1], n[i, 2]
        l1 = (abs(x) + abs(y)) + abs(z)
        if not (math.isfinite(l1) and l1 > 0):
            out[i, 0] = _ZERO_NORMAL
            out[i, 1] = _ZERO_NORMAL
            continue
        inv = one / l1
        px = x * inv
        py = y * inv
        if z < 0:
            fx = (one - abs(py)) * (one if px >= 0 else -one)
            fy = (one - abs(px)) * (one if py >= 0 else -one)
            px, py = fx, fy
        out[i, 0] = np.int16(np.rint(min(max(px, -one), one) * _SNORM))
        out[i, 1] = np.int16(np.rint(min(max(py, -one), one) * _SNORM))
