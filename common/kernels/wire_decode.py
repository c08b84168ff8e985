"""Decode of a task's wire payload (common.codec, version 3), compiled: a tile's decompressed,
byte-shuffled sections are converted channel by channel (float16 -> float32 exactly, depth
from its 4 byte planes, octahedral snorm16 normals) and written to planar destination arrays —
the master's per-sub-image planes (n = 1, tile pixel (r, c) at (y0 + r, x0 + c): each tile row
one unit-stride pass from its bytes to its plane row), a frame in image order (step n), or a
tile's own arrays.

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


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def f16_one(lo, hi) -> float:
    """One float16 (its low and high byte) -> float32, exact for every code, the way numpy's
    cast defines it: the magnitude bits shifted into float32 position are the value x 2^-112
    for normal and subnormal halves alike (one exact multiply); exponent 31 becomes inf / NaN
    with the mantissa kept. Branch-free (selects), so the loops around it vectorize."""
    h = np.uint32(lo) | (np.uint32(hi) << np.uint32(8))
    f = np.uint32((h & np.uint32(0x7FFF)) << np.uint32(13)).view(np.float32) * np.float32(2.0 ** 112)
    special = (h & np.uint32(0x7C00)) == np.uint32(0x7C00)
    inf_nan = np.uint32(0x7F800000) | ((h & np.uint32(0x3FF)) << np.uint32(13))
    b = inf_nan if special else np.float32(f).view(np.uint32)
    return np.uint32(b | ((h & np.uint32(0x8000)) << np.uint32(16))).view(np.float32)


@njit(cache=True, nogil=True, error_model="numpy")
def f16_to_f32(lo, hi, out) -> None:
    """float16 values (little-endian bytes ``lo``, ``hi``) -> float32 ``out``."""
    for i in range(out.shape[0]):
        out[i] = f16_one(lo[i], hi[i])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _u32(b0, b1, b2, b3) -> int:
    """A little-endian uint32 from its four bytes."""
    return (np.uint32(b0) | (np.uint32(b1) << np.uint32(8)) | (np.uint32(b2) << np.uint32(16))
            | (np.uint32(b3) << np.uint32(24)))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _normal(xlo, ylo, xhi, yhi) -> tuple:
    """The normal of one pixel from the bytes of its x and y codes."""
    qx = np.int64(xlo) | (np.int64(xhi) << 8)
    qy = np.int64(ylo) | (np.int64(yhi) << 8)
    qx = qx - 65536 if qx >= 32768 else qx
    qy = qy - 65536 if qy >= 32768 else qy
    return oct_decode_one(qx, qy)


@njit(cache=True, nogil=True, error_model="numpy")
def decode_tile(raw, h, w, o_refl, o_irr, o_unf, o_lobe, o_depth, o_nor, n, y0, x0,
                vals, nrm, depth_bits, no_lobe) -> None:
    """Decode an h x w tile's payload ``raw`` (uint8, codec byte layout, section byte offsets
    ``o_*``; ``o_lobe`` -1: no lobe section) into ``vals`` (12, H, W) float32 (reflectance,
    irradiance, unfiltered, lobe x RGB; the lobe ``no_lobe`` without its section), ``nrm``
    (3, H, W) float32 and ``depth_bits`` (H, W) uint32 (the float32 depth's bits), tile pixel
    (r, c) at (y0 + r n, x0 + c n). Row by row, channel by channel: with n = 1 (the master's
    planes) every pass reads and writes at unit stride (vectorized)."""
    p = h * w
    if o_lobe < 0:
        for c in range(9, 12):
            dst = vals[c]
            for r in range(h):
                y = y0 + r * n
                for x in range(w):
                    dst[y, x0 + x * n] = no_lobe
    for s in range(4 if o_lobe >= 0 else 3):
        base = o_refl if s == 0 else (o_irr if s == 1 else (o_unf if s == 2 else o_lobe))
        for c in range(3):
            lo = raw[base + c * p:base + (c + 1) * p]
            hi = raw[base + (3 + c) * p:base + (4 + c) * p]
            dst = vals[3 * s + c]
            for r in range(h):
                i = r * w
                y = y0 + r * n
                if n == 1:
                    d = dst[y, x0:x0 + w]
                    for x in range(w):
                        d[x] = f16_one(lo[i + x], hi[i + x])
                else:
                    for x in range(w):
                        dst[y, x0 + x * n] = f16_one(lo[i + x], hi[i + x])
    o = o_depth
    b0, b1, b2, b3 = raw[o:o + p], raw[o + p:o + 2 * p], raw[o + 2 * p:o + 3 * p], raw[o + 3 * p:o + 4 * p]
    for r in range(h):
        i = r * w
        y = y0 + r * n
        if n == 1:
            d = depth_bits[y, x0:x0 + w]
            for x in range(w):
                d[x] = _u32(b0[i + x], b1[i + x], b2[i + x], b3[i + x])
        else:
            for x in range(w):
                depth_bits[y, x0 + x * n] = _u32(b0[i + x], b1[i + x], b2[i + x], b3[i + x])
    o = o_nor
    xlo, ylo, xhi, yhi = raw[o:o + p], raw[o + p:o + 2 * p], raw[o + 2 * p:o + 3 * p], raw[o + 3 * p:o + 4 * p]
    for r in range(h):
        i = r * w
        y = y0 + r * n
        if n == 1:
            d0, d1, d2 = nrm[0, y, x0:x0 + w], nrm[1, y, x0:x0 + w], nrm[2, y, x0:x0 + w]
            for x in range(w):
                j = i + x
                d0[x], d1[x], d2[x] = _normal(xlo[j], ylo[j], xhi[j], yhi[j])
        else:
            for x in range(w):
                j = i + x
                nx, ny, nz = _normal(xlo[j], ylo[j], xhi[j], yhi[j])
                nrm[0, y, x0 + x * n] = nx
                nrm[1, y, x0 + x * n] = ny
                nrm[2, y, x0 + x * n] = nz
