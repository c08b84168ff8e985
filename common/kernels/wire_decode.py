"""Decode of a task's wire payload (common.codec, version 1), compiled: a tile's decompressed,
byte-shuffled sections are converted in tile order (float16 -> float32 exactly, depth from its
4 byte planes, octahedral snorm16 normals) and written to planar destination arrays — the
master's per-sub-image planes (n = 1, tile pixel (r, c) at (y0 + r, x0 + c)), a frame in
image order (step n), or a tile's own arrays.

Why: the numpy decode made a byte-plane copy, a table gather, a transpose and a scatter per
section, each a pass over memory with its temporaries; here each section is read once in
unit-stride loops and each value written once to its destination. The byte layout itself is
owned by :mod:`common.codec` (``section_offsets``); callers pass the section offsets in. The
float operations of the octahedral decode are the codec's, in the same order, so results are
bit-identical to the numpy decode (tests/common/test_wire_decode_kernel.py).
``error_model="numpy"``: no ZeroDivisionError checks (no divisor here can be 0), so the
loops vectorize; the arithmetic is IEEE float32 either way (no fastmath).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_SNORM_INV = np.float32(1.0 / 32767)
_ZERO_NORMAL = -32768


@njit(cache=True, nogil=True, error_model="numpy")
def oct_decode_one(qx: int, qy: int) -> tuple:
    """int16 octahedral codes -> float32 unit normal (x, y, z); (0, 0, 0) for the reserved code.

    p = max(q/32767, -1); z = 1 - |px| - |py|; below the diamond (z < 0) fold
    (1 - |p_other|)·sign(p); normalise by 1/sqrt((x x + y y) + z z) — float32 throughout."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    m1 = np.float32(-1.0)
    px = max(np.float32(qx) * _SNORM_INV, m1)
    py = max(np.float32(qy) * _SNORM_INV, m1)
    ax = abs(px)
    ay = abs(py)
    z = (one - ax) - ay
    lower = z < zero
    # below the diamond: (1 - |p_other|) with p's sign (px is never -0: q/32767 of an
    # integer, so sign(0) = +1); selects, not branches (the fold is data-dependent)
    ux = one - ay
    uy = one - ax
    ux = -ux if px < zero else ux
    uy = -uy if py < zero else uy
    vx = ux if lower else px
    vy = uy if lower else py
    n2 = vx * vx + vy * vy
    n2 = n2 + z * z
    inv = one / np.float32(math.sqrt(n2))
    # the reserved code (a zero normal, +0 exactly): selects, not a branch
    zn = (qx == _ZERO_NORMAL) & (qy == _ZERO_NORMAL)
    return (zero if zn else vx * inv), (zero if zn else vy * inv), (zero if zn else z * inv)


@njit(cache=True, nogil=True, error_model="numpy")
def oct_decode_into(qx, qy, out) -> None:
    """Planar decode of int16 codes ``qx``, ``qy`` (P,) into ``out`` (3, P) float32."""
    for i in range(qx.shape[0]):
        x, y, z = oct_decode_one(np.int64(qx[i]), np.int64(qy[i]))
        out[0, i] = x
        out[1, i] = y
        out[2, i] = z


@njit(cache=True, nogil=True, error_model="numpy")
def f16_to_f32(lo, hi, bits, out) -> None:
    """float16 values (little-endian bytes ``lo``, ``hi``) -> float32 ``out``; ``bits`` is
    ``out`` viewed as uint32. Exact for every code, the way numpy's cast defines it: the
    magnitude bits shifted into float32 position are the value x 2^-112 for normal and
    subnormal halves alike (one exact multiply); exponent 31 becomes inf / NaN with the
    mantissa kept. Unit-stride, branch-free loops (vectorized)."""
    m = out.shape[0]
    for i in range(m):
        h = np.uint32(lo[i]) | (np.uint32(hi[i]) << np.uint32(8))
        bits[i] = (h & np.uint32(0x7FFF)) << np.uint32(13)
    scale = np.float32(2.0 ** 112)
    for i in range(m):
        out[i] = out[i] * scale
    for i in range(m):
        h = np.uint32(lo[i]) | (np.uint32(hi[i]) << np.uint32(8))
        sign = (h & np.uint32(0x8000)) << np.uint32(16)
        special = (h & np.uint32(0x7C00)) == np.uint32(0x7C00)
        b = (np.uint32(0x7F800000) | ((h & np.uint32(0x3FF)) << np.uint32(13))) if special else bits[i]
        bits[i] = b | sign


@njit(cache=True, nogil=True, error_model="numpy")
def _u32(b0, b1, b2, b3, dst) -> None:
    for c in range(dst.shape[0]):
        dst[c] = (np.uint32(b0[c]) | (np.uint32(b1[c]) << np.uint32(8))
                  | (np.uint32(b2[c]) << np.uint32(16)) | (np.uint32(b3[c]) << np.uint32(24)))


@njit(cache=True, nogil=True, error_model="numpy")
def _oct(lo, hi, d0, d1, d2) -> None:
    """Normals of a tile: ``lo``/``hi`` the normal section's two byte planes read as uint16
    (pixel i: low bytes of qx, qy in lo[i], high bytes in hi[i])."""
    for c in range(d0.shape[0]):
        a = np.int64(lo[c])
        b = np.int64(hi[c])
        qx = (a & 0xFF) | ((b & 0xFF) << 8)
        qy = (a >> 8) | (b & 0xFF00)
        qx = qx - 65536 if qx >= 32768 else qx
        qy = qy - 65536 if qy >= 32768 else qy
        x, y, z = oct_decode_one(qx, qy)
        d0[c] = x
        d1[c] = y
        d2[c] = z


@njit(cache=True, nogil=True, error_model="numpy")
def decode_tile(raw, h, w, o_refl, o_irr, o_unf, o_depth, o_nor, n, y0, x0,
                vals, nrm, depth_bits) -> None:
    """Decode an h x w tile's payload ``raw`` (uint8, codec byte layout, section byte offsets
    ``o_*``) into ``vals`` (9, H, W) float32 (reflectance, irradiance, unfiltered x RGB),
    ``nrm`` (3, H, W) float32 and ``depth_bits`` (H, W) uint32 (the float32 depth's bits),
    tile pixel (r, c) at (y0 + r n, x0 + c n). Each section is converted in tile order
    (unit stride, vectorized), then scattered to its planes."""
    p = h * w
    tmp = np.empty(3 * p, np.float32)
    tbits = tmp.view(np.uint32)
    for s in range(3):
        base = o_refl if s == 0 else (o_irr if s == 1 else o_unf)
        f16_to_f32(raw[base:base + 3 * p], raw[base + 3 * p:base + 6 * p], tbits, tmp)
        for r in range(h):
            y = y0 + r * n
            for c in range(w):
                i = 3 * (r * w + c)
                x = x0 + c * n
                vals[3 * s, y, x] = tmp[i]
                vals[3 * s + 1, y, x] = tmp[i + 1]
                vals[3 * s + 2, y, x] = tmp[i + 2]
    o = o_depth
    _u32(raw[o:o + p], raw[o + p:o + 2 * p], raw[o + 2 * p:o + 3 * p], raw[o + 3 * p:o + 4 * p], tbits[:p])
    for r in range(h):
        y = y0 + r * n
        for c in range(w):
            depth_bits[y, x0 + c * n] = tbits[r * w + c]
    o = o_nor
    _oct(raw[o:o + 2 * p].view(np.uint16), raw[o + 2 * p:o + 4 * p].view(np.uint16), tmp[:p], tmp[p:2 * p],
         tmp[2 * p:])
    for r in range(h):
        y = y0 + r * n
        for c in range(w):
            i = r * w + c
            x = x0 + c * n
            nrm[0, y, x] = tmp[i]
            nrm[1, y, x] = tmp[p + i]
            nrm[2, y, x] = tmp[2 * p + i]
