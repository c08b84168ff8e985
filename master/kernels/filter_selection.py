"""The per-pixel blend of the filtered and the raw running means (``master.filter_selection``),
compiled: one pass for the statistics, box means by running sums (two passes a box, rows then
columns, clipped to the image), one pass for the output. float64 throughout: the blend weights a
difference of running means. ``error_model="numpy"``: the divisors are counts >= 1 or guarded.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS

_LR, _LG, _LB = LUMINANCE_WEIGHTS


@njit(cache=True, nogil=True, error_model="numpy")
def box_mean(src, r, tmp, dst) -> None:
    """dst = the mean of ``src`` (H, W) over the (2r+1)² window around each pixel, clipped to the
    image (the mean of the pixels inside); ``tmp`` (H, W) scratch."""
    H, W = src.shape
    for y in range(H):
        s = 0.0
        for x in range(min(r, W)):
            s += src[y, x]
        for x in range(W):
            if x + r < W:
                s += src[y, x + r]
            if x - r - 1 >= 0:
                s -= src[y, x - r - 1]
            tmp[y, x] = s / (min(x + r, W - 1) - max(x - r, 0) + 1)
    for x in range(W):
        s = 0.0
        for y in range(min(r, H)):
            s += tmp[y, x]
        for y in range(H):
            if y + r < H:
                s += tmp[y + r, x]
            if y - r - 1 >= 0:
                s -= tmp[y - r - 1, x]
            dst[y, x] = s / (min(y + r, H - 1) - max(y - r, 0) + 1)


@njit(cache=True, nogil=True, error_model="numpy")
def select(mean, sh, sh2, count, c, reach, out) -> None:
    """out = mean - a · sh / count per pixel (``master.filter_selection``): ``mean`` (H, W, 3)
    float32, the filter's share sums ``sh`` (H, W, 3) and luminance squares ``sh2`` (H, W) of
    ``count`` >= 2 frames; the share's bias² is the box mean (reach ``reach``) of d² - c·v (d the
    mean share's luminance, v its variance), a = b²/(b² + v) per pixel, then its box mean of
    reach 1."""
    H, W = sh2.shape
    inv = 1.0 / count
    dof = 1.0 / (count - 1.0)
    v = np.empty((H, W))
    e = np.empty((H, W))
    tmp = np.empty((H, W))
    b2 = np.empty((H, W))
    for y in range(H):
        for x in range(W):
            d = (_LR * sh[y, x, 0] + _LG * sh[y, x, 1] + _LB * sh[y, x, 2]) * inv
            var = max(sh2[y, x] * inv - d * d, 0.0) * dof
            v[y, x] = var
            e[y, x] = d * d - c * var
    box_mean(e, reach, tmp, b2)
    for y in range(H):
        for x in range(W):
            b = max(b2[y, x], 0.0)
            e[y, x] = b / (b + v[y, x]) if b > 0.0 else 0.0
    box_mean(e, 1, tmp, b2)
    for y in range(H):
        for x in range(W):
            a = b2[y, x] * inv
            for ch in range(3):
                out[y, x, ch] = np.float32(mean[y, x, ch] - a * sh[y, x, ch])
