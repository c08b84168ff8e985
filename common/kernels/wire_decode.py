"""Decode of a task's wire payload (common.codec, version 1), compiled: one pass over a tile's
decompressed, byte-shuffled planes that rebuilds every value (float16 by table, float32 depth
from its 4 byte planes, octahedral snorm16 normals) and writes it straight to its place in
planar destination arrays — the master's full-frame planes (pixel (r, c) of a tile lands on
(y0 + r·n, x0 + c·n)) or a tile's own arrays (n = 1).

Why: the numpy decode took a byte-plane copy, a table gather, a transpose and a scatter per
section, each a pass over memory; here every byte is read once and every value written once.
The byte layout itself is owned by :mod:`common.codec` (``section_offsets``); callers pass
the section offsets in. The float operations of the octahedral decode are the codec's, in
the same order, so results are bit-identical to the numpy decode (tests/common/test_wire_decode_kernel.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_SNORM_INV = np.float32(1.0 / 32767)
_ZERO_NORMAL = -32768


@njit(cache=True, nogil=True)
def oct_decode_one(qx: int, qy: int) -> tuple:
    """int16 octahedral codes -> float32 unit normal (x, y, z); (0, 0, 0) for the reserved code.

    p = max(q/32767, -1); z = 1 - |px| - |py|; below the diamond (z < 0) fold
    (1 - |p_other|)·sign(p); normalise by 1/sqrt((x x + y y) + z z) — float32 throughout."""
    zero = np.float32(0.0)
    if qx == _ZERO_NORMAL and qy == _ZERO_NORMAL:
        return zero, zero, zero
    one = np.float32(1.0)
    m1 = np.float32(-1.0)
    px = max(np.float32(qx) * _SNORM_INV, m1)
    py = max(np.float32(qy) * _SNORM_INV, m1)
    ax = abs(px)
    ay = abs(py)
    z = (one - ax) - ay
    if z < zero:
        vx = one - ay
        vy = one - ax
        if px < zero:  # px is never -0 (q/32767 of an integer): sign(0) = +1
            vx = -vx
        if py < zero:
            vy = -vy
    else:
        vx = px
        vy = py
    n2 = vx * vx + vy * vy
    n2 = n2 + z * z
    inv = one / np.float32(math.sqrt(n2))
    return vx * inv, vy * inv, z * inv


@njit(cache=True, nogil=True)
def oct_decode_into(qx, qy, out) -> None:
    """Planar decode of int16 codes ``qx``, ``qy`` (P,) into ``out`` (3, P) float32."""
    for i in range(qx.shape[0]):
        x, y, z = oct_decode_one(np.int64(qx[i]), np.int64(qy[i]))
        out[0, i] = x
        out[1, i] = y
        out[2, i] = z


@njit(cache=True, nogil=True)
def decode_tile(raw, h, w, o_refl, o_irr, o_unf, o_depth, o_nor, f16_table, n, y0, x0,
                vals, nrm, depth_bits) -> None:
    """Decode an h x w tile's payload ``raw`` (uint8, codec byte layout, section byte offsets
    ``o_*``) into ``vals`` (9, H, W) float32 (reflectance, irradiance, unfiltered x RGB),
    ``nrm`` (3, H, W) float32 and ``depth_bits`` (H, W) uint32 (the float32 depth's bits),
    tile pixel (r, c) at (y0 + r n, x0 + c n). ``f16_table``: float16 bits -> float32."""
    p = h * w
    p3 = 3 * p
    for r in range(h):
        y = y0 + r * n
        for c in range(w):
            i = r * w + c
            x = x0 + c * n
            for s in range(3):
                base = o_refl if s == 0 else (o_irr if s == 1 else o_unf)
                for ch in range(3):
                    j = base + 3 * i + ch
                    code = np.int64(raw[j]) | (np.int64(raw[j + p3]) << 8)
                    vals[3 * s + ch, y, x] = f16_table[code]
            j = o_depth + i
            bits = (np.int64(raw[j]) | (np.int64(raw[j + p]) << 8) | (np.int64(raw[j + 2 * p]) << 16)
                    | (np.int64(raw[j + 3 * p]) << 24))
            depth_bits[y, x] = np.uint32(bits)
            j = o_nor + 2 * i
            qx = np.int64(raw[j]) | (np.int64(raw[j + 2 * p]) << 8)
            qy = np.int64(raw[j + 1]) | (np.int64(raw[j + 1 + 2 * p]) << 8)
            if qx >= 32768:
                qx -= 65536
            if qy >= 32768:
                qy -= 65536
            a, b, d = oct_decode_one(qx, qy)
            nrm[0, y, x] = a
            nrm[1, y, x] = b
            nrm[2, y, x] = d
