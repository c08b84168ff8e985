"""The discontinuity buffer (paper §4.3) and the compose, fused and compiled.

Per pixel c with a finite depth: average the irradiance of c and of every neighbour j in the
window (offsets ``-lo .. hi`` on both axes, clipped to the image) with

    d_c (1 - t) <= d_j <= d_c (1 + t)      (|d_j - d_c| <= t d_c, t = depth threshold)
    (n_jx n_cx + n_jy n_cy) + n_jz n_cz >= normal threshold,

then (compose) radiance = reflectance · filtered + unfiltered. Misses (non-finite depth)
keep their irradiance and are never anyone's neighbour; a non-finite neighbour irradiance
counts as 0 (one firefly must not wipe out its window), the centre keeps its own value.

Why a kernel: the numpy version made ~10 passes over memory per window offset (comparisons,
masks, products, sums, all as temporaries of a strip); here a row's sums and counts stay in
cache while every window offset adds to them in one branch-free, vectorized pass, and the
compose follows at once. The master runs it in sub-image space (``finish_sub``), straight on
the planes the wire decode wrote. The float32 operations are the numpy version's, in the
same order (offsets row by row, as its loop did, rejected and outside neighbours adding +0),
so the image is bit-identical to it, signed zeros included (tests/master/test_master_kernels.py;
only which NaN payload survives when two NaNs meet may differ). Rows are independent: callers
split a frame into row blocks across threads (``nogil``). ``error_model="numpy"``: no
ZeroDivisionError checks (the only divisor is a count >= 1), so loops vectorize; IEEE
float32 arithmetic either way, no fastmath.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _filter_row(irr, i0, nrm, depth, y, lo, hi, t, nt, acc, cnt, dlo, dhi) -> None:
    """Sum and count of row y's continuous neighbours, as the numpy version computed them:
    ``acc`` (3, W) = centre + every offset's (irradiance or 0) x (1 or 0), offsets row by row,
    ``cnt`` (W,) = neighbours counted. Rejected and outside neighbours add +0 exactly as
    there (it matters only for a -0 sum). Branch-free inner loops over x (vectorizable)."""
    H, W = depth.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    d0 = depth[y]
    c0, c1, c2 = nrm[0, y], nrm[1, y], nrm[2, y]
    a0, a1, a2 = acc[0], acc[1], acc[2]
    for x in range(W):
        dlo[x] = d0[x] * (one - t)
        dhi[x] = d0[x] * (one + t)
        a0[x] = irr[i0, y, x]
        a1[x] = irr[i0 + 1, y, x]
        a2[x] = irr[i0 + 2, y, x]
        cnt[x] = 0
    for oy in range(-lo, hi + 1):
        j = y + oy
        if j < 0 or j >= H:
            for x in range(W):
                a0[x] += zero
                a1[x] += zero
                a2[x] += zero
            continue
        dj = depth[j]
        m0, m1, m2 = nrm[0, j], nrm[1, j], nrm[2, j]
        v0, v1, v2 = irr[i0, j], irr[i0 + 1, j], irr[i0 + 2, j]
        for ox in range(-lo, hi + 1):
            if oy == 0 and ox == 0:
                continue
            xa = max(0, -ox)
            xb = min(W, W - ox)
            for x in range(0, xa):
                a0[x] += zero
                a1[x] += zero
                a2[x] += zero
            for x in range(max(xa, xb), W):
                a0[x] += zero
                a1[x] += zero
                a2[x] += zero
            if xb > xa:
                s0, s1 = xa + ox, xb + ox
                _add_offset(dj[s0:s1], m0[s0:s1], m1[s0:s1], m2[s0:s1], v0[s0:s1], v1[s0:s1], v2[s0:s1],
                            c0[xa:xb], c1[xa:xb], c2[xa:xb], dlo[xa:xb], dhi[xa:xb],
                            a0[xa:xb], a1[xa:xb], a2[xa:xb], cnt[xa:xb], nt)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")  # inlined: its row views then cost nothing
def _add_offset(dj, m0, m1, m2, v0, v1, v2, c0, c1, c2, dlo, dhi, a0, a1, a2, cnt, nt) -> None:
    """One window offset over a row: neighbour arrays (depth, normal, irradiance) already
    shifted to line up with the centres'. Branch-free, so LLVM vectorizes it."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    inf = np.float32(np.inf)
    for x in range(dj.shape[0]):
        d = dj[x]
        dot = (m0[x] * c0[x] + m1[x] * c1[x]) + m2[x] * c2[x]
        ok = (d >= dlo[x]) & (d <= dhi[x]) & (abs(d) < inf) & (dot >= nt)
        f = one if ok else zero
        u0 = v0[x]
        u1 = v1[x]
        u2 = v2[x]
        a0[x] += (u0 if abs(u0) < inf else zero) * f
        a1[x] += (u1 if abs(u1) < inf else zero) * f
        a2[x] += (u2 if abs(u2) < inf else zero) * f
        cnt[x] += np.int32(ok)


@njit(cache=True, nogil=True, error_model="numpy")
def filter_rows(irr, nrm, depth, y0, y1, lo, hi, depth_threshold, normal_threshold, out) -> None:
    """Filtered irradiance of rows y0 .. y1: ``irr``, ``nrm``, ``out`` (3, H, W) float32,
    ``depth`` (H, W) float32 (non-finite = miss)."""
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    W = depth.shape[1]
    one = np.float32(1.0)
    acc = np.empty((3, W), np.float32)
    cnt = np.empty(W, np.int32)
    dlo = np.empty(W, np.float32)
    dhi = np.empty(W, np.float32)
    for y in range(y0, y1):
        _filter_row(irr, 0, nrm, depth, y, lo, hi, t, nt, acc, cnt, dlo, dhi)
        for x in range(W):
            if math.isfinite(depth[y, x]):
                cf = np.float32(cnt[x]) + one
                for c in range(3):
                    out[c, y, x] = acc[c, x] / cf
            else:
                for c in range(3):
                    out[c, y, x] = irr[c, y, x]


@njit(cache=True, nogil=True, error_model="numpy")
def gather_rows(vals_s, nrm_s, dep_s, n, W, ya, yb, vals, nrm, depth) -> None:
    """Image rows ya .. yb of the frame kept as sub-images (interleave n): ``vals_s`` (n², 9,
    sh, sw), ``nrm_s`` (n², 3, sh, sw), ``dep_s`` (n², sh, sw); image pixel (y, x) is pixel
    (y div n, x div n) of sub-image (y mod n)·n + x mod n. Written to row 0 .. yb - ya of
    ``vals`` (9, R, W), ``nrm`` (3, R, W), ``depth`` (R, W)."""
    for y in range(ya, yb):
        r = y - ya
        ky = y % n
        sy = y // n
        for kx in range(n):
            k = ky * n + kx
            cols = (W - kx + n - 1) // n
            for b in range(9):
                src = vals_s[k, b, sy]
                dst = vals[b, r]
                for sx in range(cols):
                    dst[sx * n + kx] = src[sx]
            for b in range(3):
                src = nrm_s[k, b, sy]
                dst = nrm[b, r]
                for sx in range(cols):
                    dst[sx * n + kx] = src[sx]
            src = dep_s[k, sy]
            dst = depth[r]
            for sx in range(cols):
                dst[sx * n + kx] = src[sx]


@njit(cache=True, nogil=True, error_model="numpy")
def finish_sub(vals_s, nrm_s, dep_s, n, H, W, sy0, sy1, use_filter, lo, hi, depth_threshold,
               normal_threshold, w, img) -> None:
    """Image pixels of sub-image rows sy0 .. sy1 of every sub-image k of a frame kept per
    sub-image (interleave n; see :func:`gather_rows` for the layout): the discontinuity
    filter (as :func:`filter_rows`), the fading blend and the compose, written to ``img``
    (H, W, 3) at (sy·n + k div n, sx·n + k mod n). n = 1 with one sub-image is a frame in
    image order.

    The filter runs in sub-image space: the neighbour (oy, ox) of every pixel of sub-image k
    lies in one sub-image k' at a constant shift (dy, dx), so each window offset is one
    unit-stride pass over a row (:func:`_add_offset`, vectorized), and nothing is first
    rearranged into image order. Same terms, same order as in image order: bit-identical."""
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    blend = use_filter and w < 1.0
    wf = np.float32(w)
    wr = np.float32(1.0 - w)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    swm = vals_s.shape[3]
    acc = np.empty((3, swm), np.float32)
    cnt = np.empty(swm, np.int32)
    dlo = np.empty(swm, np.float32)
    dhi = np.empty(swm, np.float32)
    for sy in range(sy0, sy1):  # all k of a row block together: their image rows stay in cache
        for k in range(n * n):
            ky = k // n
            kx = k % n
            sw = (W - kx + n - 1) // n
            sh = (H - ky + n - 1) // n
            if sw <= 0 or sy >= sh:
                continue
            a0, a1, a2 = acc[0, :sw], acc[1, :sw], acc[2, :sw]
            y = sy * n + ky
            d0 = dep_s[k, sy, :sw]
            c0, c1, c2 = nrm_s[k, 0, sy, :sw], nrm_s[k, 1, sy, :sw], nrm_s[k, 2, sy, :sw]
            i0, i1, i2 = vals_s[k, 3, sy, :sw], vals_s[k, 4, sy, :sw], vals_s[k, 5, sy, :sw]
            if use_filter:
                for x in range(sw):
                    dlo[x] = d0[x] * (one - t)
                    dhi[x] = d0[x] * (one + t)
                    a0[x] = i0[x]
                    a1[x] = i1[x]
                    a2[x] = i2[x]
                    cnt[x] = 0
                for oy in range(-lo, hi + 1):
                    ty = ky + oy
                    kyp = ty % n
                    syp = sy + ty // n
                    if syp < 0 or syp >= (H - kyp + n - 1) // n:
                        for x in range(sw):  # a row outside the image: +0 terms
                            a0[x] += zero
                            a1[x] += zero
                            a2[x] += zero
                        continue
                    for ox in range(-lo, hi + 1):
                        if oy == 0 and ox == 0:
                            continue
                        tx = kx + ox
                        kxp = tx % n
                        dx = tx // n
                        kp = kyp * n + kxp
                        xa = max(0, -dx)
                        xb = min(sw, (W - kxp + n - 1) // n - dx)
                        for x in range(0, min(xa, sw)):  # columns outside the image: +0 terms
                            a0[x] += zero
                            a1[x] += zero
                            a2[x] += zero
                        for x in range(max(xa, xb), sw):
                            a0[x] += zero
                            a1[x] += zero
                            a2[x] += zero
                        if xb > xa:
                            s0, s1 = xa + dx, xb + dx
                            _add_offset(dep_s[kp, syp, s0:s1], nrm_s[kp, 0, syp, s0:s1], nrm_s[kp, 1, syp, s0:s1],
                                        nrm_s[kp, 2, syp, s0:s1], vals_s[kp, 3, syp, s0:s1],
                                        vals_s[kp, 4, syp, s0:s1], vals_s[kp, 5, syp, s0:s1],
                                        c0[xa:xb], c1[xa:xb], c2[xa:xb], dlo[xa:xb], dhi[xa:xb],
                                        a0[xa:xb], a1[xa:xb], a2[xa:xb], cnt[xa:xb], nt)
            r0, r1, r2 = vals_s[k, 0, sy, :sw], vals_s[k, 1, sy, :sw], vals_s[k, 2, sy, :sw]
            u0, u1, u2 = vals_s[k, 6, sy, :sw], vals_s[k, 7, sy, :sw], vals_s[k, 8, sy, :sw]
            for sx in range(sw):
                f0, f1, f2 = i0[sx], i1[sx], i2[sx]
                if use_filter and math.isfinite(d0[sx]):
                    cf = np.float32(cnt[sx]) + one
                    f0 = a0[sx] / cf
                    f1 = a1[sx] / cf
                    f2 = a2[sx] / cf
                if blend:
                    f0 = wf * f0 + wr * i0[sx]
                    f1 = wf * f1 + wr * i1[sx]
                    f2 = wf * f2 + wr * i2[sx]
                x = sx * n + kx
                img[y, x, 0] = r0[sx] * f0 + u0[sx]
                img[y, x, 1] = r1[sx] * f1 + u1[sx]
                img[y, x, 2] = r2[sx] * f2 + u2[sx]
