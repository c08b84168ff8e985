"""The discontinuity buffer (paper §4.3) and the compose, fused and compiled.

Per pixel c with a finite depth: average the irradiance of c and of every neighbour j in the
window (offsets ``-lo .. hi`` on both axes, clipped to the image) with

    d_c (1 - t) <= d_j <= d_c (1 + t)      (|d_j - d_c| <= t d_c, t = depth threshold)
    (n_jx n_cx + n_jy n_cy) + n_jz n_cz >= normal threshold,

then (compose) radiance = reflectance · filtered + unfiltered. Misses (non-finite depth)
keep their irradiance and are never anyone's neighbour; a non-finite neighbour irradiance
counts as 0 (one firefly must not wipe out its window), the centre keeps its own value.

Why a kernel: the numpy version made ~10 passes over memory per window offset (comparisons,
masks, products, sums, all as full-frame temporaries); here each pixel reads its window once
from cache and writes its final radiance once. The float32 operations are the numpy
version's, in the same order (the sum runs over offsets row by row, as its loop did), so the
image is bit-identical to it, signed zeros included (tests/master/test_master_kernels.py).
Rows are independent: callers split a frame into row stripes across threads (``nogil``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _filter_px(irr, i0, nrm, depth, y, x, lo, hi, t, nt, exact):
    """Filtered irradiance (3 float32) of pixel (y, x) with a finite depth. ``irr`` planes
    i0 .. i0 + 2 hold the irradiance. ``exact``: also add the +0 terms the numpy version
    added for rejected or outside neighbours (they only matter for a -0 sum)."""
    H, W = depth.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    dc = depth[y, x]
    dlo = dc * (one - t)
    dhi = dc * (one + t)
    n0 = nrm[0, y, x]
    n1 = nrm[1, y, x]
    n2 = nrm[2, y, x]
    a0 = irr[i0, y, x]
    a1 = irr[i0 + 1, y, x]
    a2 = irr[i0 + 2, y, x]
    cnt = 0
    for oy in range(-lo, hi + 1):
        j = y + oy
        for ox in range(-lo, hi + 1):
            if oy == 0 and ox == 0:
                continue
            i = x + ox
            if j < 0 or j >= H or i < 0 or i >= W:
                if exact:
                    a0 += zero
                    a1 += zero
                    a2 += zero
                continue
            dj = depth[j, i]
            ok = math.isfinite(dj) and dj >= dlo and dj <= dhi
            if ok:
                dot = (nrm[0, j, i] * n0 + nrm[1, j, i] * n1) + nrm[2, j, i] * n2
                ok = dot >= nt
            if ok or exact:
                f = one if ok else zero
                v0 = irr[i0, j, i]
                v1 = irr[i0 + 1, j, i]
                v2 = irr[i0 + 2, j, i]
                a0 += (v0 if math.isfinite(v0) else zero) * f
                a1 += (v1 if math.isfinite(v1) else zero) * f
                a2 += (v2 if math.isfinite(v2) else zero) * f
            if ok:
                cnt += 1
    cf = np.float32(cnt) + one
    return a0 / cf, a1 / cf, a2 / cf


@njit(cache=True, nogil=True)
def _minus_zero(v) -> bool:
    return v == 0 and math.copysign(1.0, v) < 0


@njit(cache=True, nogil=True)
def _filtered(irr, i0, nrm, depth, y, x, lo, hi, t, nt):
    f0, f1, f2 = _filter_px(irr, i0, nrm, depth, y, x, lo, hi, t, nt, False)
    if _minus_zero(f0) or _minus_zero(f1) or _minus_zero(f2):  # rare: redo with every +0 term
        f0, f1, f2 = _filter_px(irr, i0, nrm, depth, y, x, lo, hi, t, nt, True)
    return f0, f1, f2


@njit(cache=True, nogil=True)
def filter_rows(irr, nrm, depth, y0, y1, lo, hi, depth_threshold, normal_threshold, out) -> None:
    """Filtered irradiance of rows y0 .. y1: ``irr``, ``nrm``, ``out`` (3, H, W) float32,
    ``depth`` (H, W) float32 (non-finite = miss)."""
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    W = depth.shape[1]
    for y in range(y0, y1):
        for x in range(W):
            if math.isfinite(depth[y, x]):
                f0, f1, f2 = _filtered(irr, 0, nrm, depth, y, x, lo, hi, t, nt)
            else:
                f0, f1, f2 = irr[0, y, x], irr[1, y, x], irr[2, y, x]
            out[0, y, x] = f0
            out[1, y, x] = f1
            out[2, y, x] = f2


@njit(cache=True, nogil=True)
def finish_rows(vals, nrm, depth, y0, y1, use_filter, lo, hi, depth_threshold, normal_threshold,
                w, img) -> None:
    """Image rows y0 .. y1 (``img`` (H, W, 3) float32) from the frame's planes: ``vals``
    (9, H, W) reflectance, irradiance, unfiltered x RGB; ``nrm`` (3, H, W); ``depth`` (H, W).

    radiance = reflectance · f + unfiltered, with f the irradiance (``use_filter`` false), the
    filtered irradiance (w >= 1) or w·filtered + (1 - w)·irradiance (0 < w < 1, the consistent
    mode's fading filter; w and 1 - w rounded to float32 as numpy's scalar arithmetic does)."""
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    blend = w < 1.0
    wf = np.float32(w)
    wr = np.float32(1.0 - w)
    W = depth.shape[1]
    for y in range(y0, y1):
        for x in range(W):
            r0 = vals[3, y, x]
            r1 = vals[4, y, x]
            r2 = vals[5, y, x]
            if use_filter and math.isfinite(depth[y, x]):
                f0, f1, f2 = _filtered(vals, 3, nrm, depth, y, x, lo, hi, t, nt)
            else:
                f0, f1, f2 = r0, r1, r2
            if use_filter and blend:
                f0 = wf * f0 + wr * r0
                f1 = wf * f1 + wr * r1
                f2 = wf * f2 + wr * r2
            img[y, x, 0] = vals[0, y, x] * f0 + vals[6, y, x]
            img[y, x, 1] = vals[1, y, x] * f1 + vals[7, y, x]
            img[y, x, 2] = vals[2, y, x] * f2 + vals[8, y, x]
