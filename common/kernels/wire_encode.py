"""Encode side of the wire codec (common.codec, version 3), compiled: the octahedral snorm16
normals of a task's buffers, and the whole byte-shuffled payload (float16 colours, float32
depth, the normals) written in one pass (:func:`payload_into`).

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



_F16_MAX = np.float32(65504.0)
_F16_MAX_BITS = 0x477FE000  # float32 bits of +65504


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def f16_bits(x, b) -> int:
    """common.codec.to_f16 of one float32 ``x`` (float32 bits ``b``), as float16 bits: NaN -> 0,
    ±inf and overflow clamped to ±65504, float16 subnormals by rint(|x|·2^24) (as the numpy
    form writes them), normals rounded to nearest even (numpy's cast)."""
    if x != x:
        x, b = np.float32(0.0), np.uint32(0)
    elif x > _F16_MAX:
        x, b = _F16_MAX, np.uint32(_F16_MAX_BITS)
    elif x < -_F16_MAX:
        x, b = -_F16_MAX, np.uint32(_F16_MAX_BITS | 0x80000000)
    bits = np.int64(b)
    sign = (bits >> 16) & 0x8000
    a = bits & 0x7FFFFFFF
    if a < 0x38800000:  # |x| < 2^-14: a float16 subnormal (or zero)
        return sign | np.int64(np.rint(abs(x) * np.float32(16777216.0)))
    return sign | ((a - 0x38000000 + 0xFFF + ((a >> 13) & 1)) >> 13)


@njit(cache=True, nogil=True, error_model="numpy")
def payload_into(colours, colour_bits, depth, depth_bits, normal_codes, out) -> None:
    """The uncompressed wire payload of one task into ``out`` (uint8, 26 bytes a pixel, 32 with
    the lobe): ``colours`` (3 or 4, P, 3) float32 — reflectance, irradiance, unfiltered[, lobe] —
    as float16 (3P items each), ``depth`` (P,) float32 with NaN as +inf, ``normal_codes`` (P, 2) int16; items channel
    by channel (all P of channel 0, then channel 1, ...), each section byte-shuffled (all first
    bytes of its items, then all second bytes, ...). ``*_bits``: the float32 arrays' uint32
    views."""
    p = depth.shape[0]
    off = 0
    n = 3 * p
    for part in range(colours.shape[0]):
        for c in range(3):
            lo = off + c * p
            hi = off + n + c * p
            for i in range(p):
                h = f16_bits(colours[part, i, c], colour_bits[part, i, c])
                out[lo + i] = h & 0xFF
                out[hi + i] = h >> 8
        off += 2 * n
    for i in range(p):
        x = depth[i]
        b = np.uint32(0x7F800000) if x != x else depth_bits[i]
        out[off + i] = b & 0xFF
        out[off + p + i] = (b >> 8) & 0xFF
        out[off + 2 * p + i] = (b >> 16) & 0xFF
        out[off + 3 * p + i] = b >> 24
    off += 4 * p
    n = 2 * p
    for c in range(2):
        lo = off + c * p
        hi = off + n + c * p
        for i in range(p):
            v = np.int64(normal_codes[i, c]) & 0xFFFF
            out[lo + i] = v & 0xFF
            out[hi + i] = v >> 8
