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
the planes the wire decode wrote (bordered, so that no pass clips at the image's edges). The
float32 operations are the numpy version's, in the same order (offsets row by row, as its
loop did, rejected and outside neighbours adding +0), so the image is bit-identical to it,
signed zeros included (tests/master/test_master_kernels.py; only which NaN payload survives
when two NaNs meet may differ). Rows are independent: callers
split a frame into row blocks across threads (``nogil``). ``error_model="numpy"``: no
ZeroDivisionError checks (the only divisor is a count >= 1), so loops vectorize; IEEE
float32 arithmetic either way, no fastmath.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS

_LR, _LG, _LB = (np.float32(c) for c in LUMINANCE_WEIGHTS)


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
                            a0[xa:xb], a1[xa:xb], a2[xa:xb], cnt[xa:xb], nt, False, dlo[:0])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _continuous(d, dlo, dhi, dot, nt) -> bool:
    """The discontinuity buffer's test of one neighbour: finite depth d within [dlo, dhi] (the
    centre's depth ± the threshold), normals' dot product >= nt."""
    return (d >= dlo) & (d <= dhi) & (abs(d) < np.float32(np.inf)) & (dot >= nt)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_if(ok, u0, u1, u2, a0, a1, a2, cnt, x) -> None:
    """Add (u0, u1, u2) — a non-finite component as 0 — to the sums at x where ``ok``, +0 where
    not (as the numpy version's masked products did), and count it. Selects, not branches."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    inf = np.float32(np.inf)
    f = one if ok else zero
    a0[x] += (u0 if abs(u0) < inf else zero) * f
    a1[x] += (u1 if abs(u1) < inf else zero) * f
    a2[x] += (u2 if abs(u2) < inf else zero) * f
    cnt[x] += np.int32(ok)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")  # inlined: its row views then cost nothing
def _add_offset(dj, m0, m1, m2, v0, v1, v2, c0, c1, c2, dlo, dhi, a0, a1, a2, cnt, nt, keep, okm) -> None:
    """One window offset over a row: neighbour arrays (depth, normal, irradiance) already
    shifted to line up with the centres'. Branch-free, so LLVM vectorizes it. ``keep``: also
    store the continuity test in ``okm`` (1 or 0) for :func:`_add_offset_lobe`."""
    for x in range(dj.shape[0]):
        dot = (m0[x] * c0[x] + m1[x] * c1[x]) + m2[x] * c2[x]
        ok = _continuous(dj[x], dlo[x], dhi[x], dot, nt)
        if keep:
            okm[x] = np.float32(ok)
        _add_if(ok, v0[x], v1[x], v2[x], a0, a1, a2, cnt, x)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_offset_guided(dj, m0, m1, m2, v0, v1, v2, gj, tj, c0, c1, c2, gc, tc, dlo, dhi, a0, a1, a2, cnt,
                       nt, keep, okm) -> None:
    """:func:`_add_offset` with the edge-stopping guide (``master.edge_stopping``): a continuous
    neighbour counts only where its earlier frames' mean ``gj`` is within ``tj + tc`` of the
    centre's ``gc`` (``okm`` keeps the continuity test alone: the lobes are not guided)."""
    for x in range(dj.shape[0]):
        dot = (m0[x] * c0[x] + m1[x] * c1[x]) + m2[x] * c2[x]
        cont = _continuous(dj[x], dlo[x], dhi[x], dot, nt)
        if keep:
            okm[x] = np.float32(cont)
        _add_if(cont & (abs(gj[x] - gc[x]) <= tj[x] + tc[x]), v0[x], v1[x], v2[x], a0, a1, a2, cnt, x)


@njit(cache=True, nogil=True, error_model="numpy")
def guide_cells(s1, s2, m, k_err, gm, gt) -> None:
    """The edge-stopping guide (``master.edge_stopping``) of ``m`` >= 2 frames with luminance sums
    ``s1`` and sums of squares ``s2`` (float64, any layout, 1-D views): per cell the mean and
    ``k_err`` standard errors of the mean (sqrt of the unbiased sample variance over m), float32
    ``gm``, ``gt`` of the same layout. Cells that hold no pixel (sums 0) get 0 and 0: misses, which
    the continuity test rejects before the guide's is read."""
    inv = 1.0 / m
    unbiased = m / (m - 1.0)
    for j in range(s1.shape[0]):
        mean = s1[j] * inv
        var = max(s2[j] * inv - mean * mean, 0.0) * unbiased
        gm[j] = np.float32(mean)
        gt[j] = np.float32(k_err * math.sqrt(var * inv))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _learn(i0, i1, i2, s1, s2) -> None:
    """Add each cell's irradiance luminance (non-finite: 0) and its square to the guide's sums."""
    for j in range(i0.shape[0]):
        v = (_LR * i0[j] + _LG * i1[j]) + _LB * i2[j]
        e = np.float64(v) if abs(v) < np.float32(np.inf) else 0.0
        s1[j] += e
        s2[j] += e * e


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_share(sh, sh2, k, j, e0, e1, e2) -> None:
    """Add a pixel's filter share (float64 RGB) and its luminance squared, unless non-finite."""
    e = (_LR * e0 + _LG * e1) + _LB * e2
    ok = abs(e) < np.inf  # False for NaN too; selects, not a branch (a branch here cost ~8 ms a 640x480 frame)
    sh[k, 0, j] += e0 if ok else 0.0
    sh[k, 1, j] += e1 if ok else 0.0
    sh[k, 2, j] += e2 if ok else 0.0
    sh2[k, j] += e * e if ok else 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_offset_lobe(okm, l0, l1, l2, b0, b1, b2, lcnt) -> None:
    """The split lobes' sums of one window offset (after :func:`_add_offset`'s, in a pass of its
    own: one loop over both vectorized ~7x worse), with the continuity test that pass kept in
    ``okm``: a continuous neighbour adds its lobe ``l*`` where it has one (l0 >= 0; one without —
    another material on the same plane — must not dim it)."""
    for x in range(l0.shape[0]):
        ok = (okm[x] > np.float32(0.0)) & (l0[x] >= np.float32(0.0))
        _add_if(ok, l0[x], l1[x], l2[x], b0, b1, b2, lcnt, x)


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


# Sub-image rows filtered together: each window offset is then one pass over ~4000 pixels, not
# 128 (a pass costs ~0.1 us of slicing and reference counts before its first pixel: at one row
# a pass that was 40% of the filter's time at 640x480, interleave 5), while the accumulators
# (6 x 4 bytes a pixel, 10 with lobes) stay within L2.
BLOCK_ROWS = 32


def plane_pad(lo: int, hi: int, n: int) -> int:
    """The border (in sub-image pixels) that holds every neighbour of a window with offsets
    ``-lo .. hi`` at interleave ``n``: a neighbour lies at most ceil(max(lo, hi) / n)
    sub-image pixels away."""
    return -(-max(lo, hi, 0) // n)


@njit(cache=True, nogil=True, error_model="numpy")
def gather_rows(vals_s, nrm_s, dep_s, n, pad, W, ya, yb, vals, nrm, depth) -> None:
    """Image rows ya .. yb of the frame kept as sub-images (interleave n): ``vals_s`` (n², 12,
    sh + 2 pad, sw + 2 pad), ``nrm_s`` (n², 3, ...), ``dep_s`` (n², ...) with a border of
    ``pad`` (see :func:`finish_sub`); image pixel (y, x) is pixel (y div n, x div n) of
    sub-image (y mod n)·n + x mod n. Written to row 0 .. yb - ya of ``vals`` (12, R, W),
    ``nrm`` (3, R, W), ``depth`` (R, W)."""
    for y in range(ya, yb):
        r = y - ya
        ky = y % n
        sy = y // n + pad
        for kx in range(n):
            k = ky * n + kx
            cols = (W - kx + n - 1) // n
            for b in range(12):
                src = vals_s[k, b, sy]
                dst = vals[b, r]
                for sx in range(cols):
                    dst[sx * n + kx] = src[sx + pad]
            for b in range(3):
                src = nrm_s[k, b, sy]
                dst = nrm[b, r]
                for sx in range(cols):
                    dst[sx * n + kx] = src[sx + pad]
            src = dep_s[k, sy]
            dst = depth[r]
            for sx in range(cols):
                dst[sx * n + kx] = src[sx + pad]


@njit(cache=True, nogil=True, error_model="numpy")
def finish_sub(vals_s, nrm_s, dep_s, SW, n, pad, H, W, sy0, sy1, use_filter, lo, hi, depth_threshold,
               normal_threshold, w, wl, lobes, guided, gm, gt, s1, s2, m, k_err, wm, wt, img, sh, sh2) -> None:
    """Image pixels of sub-image rows sy0 .. sy1 of every sub-image k of a frame kept per
    sub-image (interleave n): the discontinuity filter (as :func:`filter_rows`), the fading
    blend and the compose, written to ``img`` (H, W, 3) at (sy·n + k div n, sx·n + k mod n).
    n = 1 with one sub-image is a frame in image order.

    ``lobes`` (the frame has split lobes): each pixel with a lobe (lobe red >= 0) also averages
    the lobes of its continuous neighbours that have one, blends with its own weight ``wl``, and
    adds the result to its radiance: reflectance · irradiance + lobe + unfiltered. Without, the
    lobe planes are not read.

    ``guided``: the irradiance's neighbours pass the edge-stopping test of ``master.edge_stopping``
    too, with the earlier frames' mean ``gm`` and tolerance ``gt`` in the planes' layout
    (:func:`guide_cells`). ``s1``, ``s2`` (n², cells) float64 in the planes' layout, unless
    empty: the guide's sums, to which each pixel adds its raw irradiance luminance (non-finite:
    0) and its square; then, unless ``wm`` is empty or ``m`` (the frames in the sums with this
    one) < 2, it writes the guide of the sums (the next frame's ``gm``, ``gt`` with ``k_err``
    standard errors) to ``wm``, ``wt``: no pass of its own over the sums.

    ``sh`` (n², 3, cells), ``sh2`` (n², cells) float64 in the planes' layout, unless empty: the
    filter's share of each pixel — its radiance less the radiance of its own raw irradiance and
    lobe — is added to ``sh`` and its luminance squared to ``sh2`` (non-finite shares add 0), the
    sums ``master.filter_selection`` weighs the filter's bias with.

    The planes are flattened rows of SW = sw + 2 pad pixels with a border of ``pad``
    (:func:`plane_pad` of the window): ``vals_s`` (n², 12, (sh + 2 pad)·SW) reflectance,
    irradiance, unfiltered, lobe (x RGB), ``nrm_s`` (n², 3, ...), ``dep_s`` (n², ...); sub-image
    pixel (sy, sx) at (sy + pad)·SW + sx + pad. The border, and every cell outside a
    sub-image's own extent, holds a miss (depth +inf, zero values, NO_LOBE), so it is nobody's
    neighbour and adds +0 exactly as an outside neighbour did.

    In sub-image space the neighbour (oy, ox) of every pixel of sub-image k lies in one
    sub-image k' at a constant shift (dy, dx): in the flattened, bordered planes one constant
    index shift, so each window offset is one unit-stride pass (:func:`_add_offset`,
    vectorized) over a block of BLOCK_ROWS rows at once, border columns included (their sums
    are computed and never read). Same terms, same order as :func:`filter_rows` in image
    order: bit-identical."""
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    blend = use_filter and w < 1.0
    wf = np.float32(w)
    wr = np.float32(1.0 - w)
    lblend = use_filter and wl < 1.0
    lf = np.float32(wl)
    lr = np.float32(1.0 - wl)
    one = np.float32(1.0)
    cap = BLOCK_ROWS * SW
    acc = np.empty((3, cap), np.float32)
    cnt = np.empty(cap, np.int32)
    dlo = np.empty(cap, np.float32)
    dhi = np.empty(cap, np.float32)
    lac = np.empty((3, cap if lobes else 0), np.float32)
    lcnt = np.empty(cap if lobes else 0, np.int32)
    okm = np.empty(cap if lobes else 0, np.float32)  # an offset's continuity test, for the lobes' pass
    zero = np.float32(0.0)
    learn = s1.shape[0] > 0
    share = sh.shape[0] > 0
    plan = learn and wm.shape[0] > 0 and m >= 2  # write the next frame's guide
    for ya in range(sy0, sy1, BLOCK_ROWS):  # all k of a row block together: their image rows stay in cache
        yb = min(sy1, ya + BLOCK_ROWS)
        for k in range(n * n):
            ky = k // n
            kx = k % n
            sw = (W - kx + n - 1) // n
            yend = min(yb, (H - ky + n - 1) // n)
            if sw <= 0 or ya >= yend:
                continue
            i_s = (ya + pad) * SW + pad  # the block's first pixel .. one past its last
            i_e = (yend - 1 + pad) * SW + pad + sw
            L = i_e - i_s
            d0 = dep_s[k]
            i0, i1, i2 = vals_s[k, 3], vals_s[k, 4], vals_s[k, 5]
            a0, a1, a2 = acc[0, :L], acc[1, :L], acc[2, :L]
            q0, q1, q2 = vals_s[k, 9], vals_s[k, 10], vals_s[k, 11]
            if use_filter:
                for x in range(L):
                    dlo[x] = d0[i_s + x] * (one - t)
                    dhi[x] = d0[i_s + x] * (one + t)
                    a0[x] = i0[i_s + x]
                    a1[x] = i1[i_s + x]
                    a2[x] = i2[i_s + x]
                    cnt[x] = 0
                if lobes:
                    for x in range(L):
                        lac[0, x] = q0[i_s + x]
                        lac[1, x] = q1[i_s + x]
                        lac[2, x] = q2[i_s + x]
                        lcnt[x] = 0
                c0, c1, c2 = nrm_s[k, 0, i_s:i_e], nrm_s[k, 1, i_s:i_e], nrm_s[k, 2, i_s:i_e]
                for oy in range(-lo, hi + 1):
                    ty = ky + oy
                    kyp = ty % n
                    dy = ty // n
                    for ox in range(-lo, hi + 1):
                        if oy == 0 and ox == 0:
                            continue
                        tx = kx + ox
                        kp = kyp * n + tx % n
                        s = i_s + dy * SW + tx // n
                        e = s + L
                        if guided:
                            _add_offset_guided(dep_s[kp, s:e], nrm_s[kp, 0, s:e], nrm_s[kp, 1, s:e],
                                               nrm_s[kp, 2, s:e], vals_s[kp, 3, s:e], vals_s[kp, 4, s:e],
                                               vals_s[kp, 5, s:e], gm[kp, s:e], gt[kp, s:e], c0, c1, c2,
                                               gm[k, i_s:i_e], gt[k, i_s:i_e], dlo[:L], dhi[:L], a0, a1, a2,
                                               cnt[:L], nt, lobes, okm[:L])
                        else:
                            _add_offset(dep_s[kp, s:e], nrm_s[kp, 0, s:e], nrm_s[kp, 1, s:e], nrm_s[kp, 2, s:e],
                                        vals_s[kp, 3, s:e], vals_s[kp, 4, s:e], vals_s[kp, 5, s:e],
                                        c0, c1, c2, dlo[:L], dhi[:L], a0, a1, a2, cnt[:L], nt, lobes, okm[:L])
                        if lobes:
                            _add_offset_lobe(okm[:L], vals_s[kp, 9, s:e], vals_s[kp, 10, s:e], vals_s[kp, 11, s:e],
                                             lac[0, :L], lac[1, :L], lac[2, :L], lcnt[:L])
            if learn:  # the block's rows, border cells included (they hold zeros: their sums stay 0)
                _learn(i0[i_s:i_e], i1[i_s:i_e], i2[i_s:i_e], s1[k, i_s:i_e], s2[k, i_s:i_e])
                if plan:
                    guide_cells(s1[k, i_s:i_e], s2[k, i_s:i_e], m, k_err, wm[k, i_s:i_e], wt[k, i_s:i_e])
            r0, r1, r2 = vals_s[k, 0], vals_s[k, 1], vals_s[k, 2]
            u0, u1, u2 = vals_s[k, 6], vals_s[k, 7], vals_s[k, 8]
            for sy in range(ya, yend):
                y = sy * n + ky
                b = (sy - ya) * SW  # the row in the block's sums
                j0 = (sy + pad) * SW + pad  # the row in the planes
                for sx in range(sw):
                    j = j0 + sx
                    f0, f1, f2 = i0[j], i1[j], i2[j]
                    if use_filter and math.isfinite(d0[j]):
                        cf = np.float32(cnt[b + sx]) + one
                        f0 = a0[b + sx] / cf
                        f1 = a1[b + sx] / cf
                        f2 = a2[b + sx] / cf
                    if blend:
                        f0 = wf * f0 + wr * i0[j]
                        f1 = wf * f1 + wr * i1[j]
                        f2 = wf * f2 + wr * i2[j]
                    x = sx * n + kx
                    img[y, x, 0] = r0[j] * f0 + u0[j]
                    img[y, x, 1] = r1[j] * f1 + u1[j]
                    img[y, x, 2] = r2[j] * f2 + u2[j]
                    e0 = e1 = e2 = 0.0
                    if share:  # in float64: exactly 0 where the filter kept the pixel's own value
                        e0 = np.float64(r0[j]) * (np.float64(f0) - np.float64(i0[j]))
                        e1 = np.float64(r1[j]) * (np.float64(f1) - np.float64(i1[j]))
                        e2 = np.float64(r2[j]) * (np.float64(f2) - np.float64(i2[j]))
                    if lobes and q0[j] >= zero:
                        g0, g1, g2 = q0[j], q1[j], q2[j]
                        if use_filter and math.isfinite(d0[j]):
                            cf = np.float32(lcnt[b + sx]) + one
                            g0 = lac[0, b + sx] / cf
                            g1 = lac[1, b + sx] / cf
                            g2 = lac[2, b + sx] / cf
                        if lblend:
                            g0 = lf * g0 + lr * q0[j]
                            g1 = lf * g1 + lr * q1[j]
                            g2 = lf * g2 + lr * q2[j]
                        img[y, x, 0] += g0
                        img[y, x, 1] += g1
                        img[y, x, 2] += g2
                        if share:
                            e0 += np.float64(g0) - np.float64(q0[j])
                            e1 += np.float64(g1) - np.float64(q1[j])
                            e2 += np.float64(g2) - np.float64(q2[j])
                    if share:
                        _add_share(sh, sh2, k, j, e0, e1, e2)
