"""The per-pixel blend of the filtered and the raw running means (``master.filter_selection``),
compiled: one pass for the statistics, box means (:func:`box_mean`, clipped to the image), one
pass for the output. Statistics and weights in float32 scratch planes (sums in float64): they only
weigh the float64 sums. ``error_model="numpy"``: the divisors are counts >= 1 or guarded.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS

_LR, _LG, _LB = LUMINANCE_WEIGHTS
_BIG = 1e37  # the scratch planes' bound (float32): a box's row or column sum of up to 15 stays finite


@njit(cache=True, nogil=True, error_model="numpy")
def box_mean(src, r, tmp, dst) -> None:
    """dst = the mean of ``src`` (H, W) float32 over the (2r+1)² window around each pixel, clipped
    to the image (the mean of the pixels inside); ``tmp`` (H, W) scratch. Direct sums of the 2r+1
    values, not running sums: the values span fireflies and flat walls, and a float32 running sum
    that adds and later subtracts a firefly leaves an error larger than the wall's values (the
    weights then left [0, 1]). One unit-stride pass per window offset along the rows, one per
    window row down the columns; every inner loop runs over a slice from index 0 (numba then
    drops its negative-index test and the loop vectorizes; with x + offset indices it did not,
    7x slower)."""
    H, W = src.shape
    inv = np.float32(1.0 / (2 * r + 1))
    L = W - 2 * r
    for y in range(H):
        for x in range(min(r, W)):  # the clipped ends
            lo, hi = max(0, x - r), min(W, x + r + 1)
            tmp[y, x] = np.sum(src[y, lo:hi]) / np.float32(hi - lo)
        for x in range(max(r, W - r), W):
            lo, hi = max(0, x - r), min(W, x + r + 1)
            tmp[y, x] = np.sum(src[y, lo:hi]) / np.float32(hi - lo)
        if L > 0:
            t = tmp[y, r:W - r]
            s0 = src[y, 0:L]
            for x in range(L):
                t[x] = s0[x]
            for o in range(1, 2 * r + 1):
                so = src[y, o:o + L]
                for x in range(L):
                    t[x] += so[x]
            for x in range(L):
                t[x] *= inv
    for y in range(H):
        lo, hi = max(0, y - r), min(H, y + r + 1)
        out = dst[y]
        first = tmp[lo]
        for x in range(W):
            out[x] = first[x]
        for yy in range(lo + 1, hi):
            row = tmp[yy]
            for x in range(W):
                out[x] += row[x]
        rinv = np.float32(1.0 / (hi - lo))
        for x in range(W):
            out[x] *= rinv


@njit(cache=True, nogil=True, error_model="numpy")
def select(mean, sh, sh2, n, pad, SW, count, c, reach, scratch, out) -> None:
    """out = mean - a · d per pixel (``master.filter_selection``): ``mean`` (H, W, 3) float32,
    the filter's share sums ``sh`` (n², 3, cells) and luminance squares ``sh2`` (n², cells) of
    ``count`` >= 2 frames in the planes' layout (image pixel (y, x) in plane (y mod n)·n + x mod n
    at cell (y div n + pad)·SW + x div n + pad); d = the mean share. With l its luminance and v
    that luminance's variance, B and V the box means (reach ``reach``) of l² - (c + 2/(count - 1))·v
    and of v, a = the box mean (reach 1) of max(B, 0) / (max(B, 0) + V). ``scratch`` (4, H, W)
    float32 (kept by the caller: fresh megabytes cost page faults every frame)."""
    H, W = mean.shape[0], mean.shape[1]
    inv = 1.0 / count
    dof = 1.0 / (count - 1.0)
    ce = c + 2.0 * dof
    v, e, tmp, b2 = scratch[0], scratch[1], scratch[2], scratch[3]
    for y in range(H):  # slices from index 0 (no negative-index tests: see box_mean)
        k0 = (y % n) * n
        row = (y // n + pad) * SW + pad
        for kx in range(min(n, W)):  # a plane's cells in a row are unit stride
            k = k0 + kx
            sw = (W - kx + n - 1) // n
            s0, s1, s2 = sh[k, 0, row:row + sw], sh[k, 1, row:row + sw], sh[k, 2, row:row + sw]
            q = sh2[k, row:row + sw]
            vr, er = v[y, kx::n], e[y, kx::n]
            for sx in range(sw):
                lum = (_LR * s0[sx] + _LG * s1[sx] + _LB * s2[sx]) * inv
                var = max(q[sx] * inv - lum * lum, 0.0) * dof
                vr[sx] = min(var, _BIG)  # float32 planes: an absurd firefly must not become inf
                er[sx] = max(min(lum * lum - ce * var, _BIG), -_BIG)
    box_mean(e, reach, tmp, b2)
    box_mean(v, reach, tmp, e)
    for y in range(H):
        br, er, vr = b2[y], e[y], v[y]
        for x in range(W):
            b = max(br[x], np.float32(0.0))
            a = min(b / max(b + er[x], np.float32(1e-30)), np.float32(1.0))  # branch-free: b = 0 gives 0
            vr[x] = a if a >= np.float32(0.0) else np.float32(0.0)  # NaN: 0
    box_mean(v, 1, tmp, b2)
    for y in range(H):
        k0 = (y % n) * n
        row = (y // n + pad) * SW + pad
        for kx in range(min(n, W)):
            k = k0 + kx
            sw = (W - kx + n - 1) // n
            ar, mr, orow = b2[y, kx::n], mean[y, kx::n], out[y, kx::n]
            for ch in range(3):
                sc = sh[k, ch, row:row + sw]
                for sx in range(sw):
                    orow[sx, ch] = np.float32(mr[sx, ch] - (ar[sx] * inv) * sc[sx])
