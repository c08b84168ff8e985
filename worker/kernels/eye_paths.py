"""Eye paths (Wald et al. 2002 §4: one per pixel, split at the first hit, mirror and glass
chains followed), fused: the first hits from Embree's packets, what they see directly, their end
points, the split of mirror/glass hits into their delta components and the chains behind them
(:func:`_chains`), in one call per tile instead of ~40 numpy passes.

The math is the kernels' own (common.kernels.bsdf.specular, shading_frame, hit_surface), in the
order worker.shading.trace_eye's numpy form applies it, so the end points are bit-identical.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point
from igi.common.kernels.ray_packets import closest_surfaces, hit_buffers

from .specular_chain import delta_bounce

_WR, _WG, _WB = 0.212671, 0.715160, 0.072169  # common.lights.LUMINANCE_WEIGHTS (tested equal)


@njit(cache=True, nogil=True, error_model="numpy")
def trace_eye(P, kind, specular, null_kind, rng, closest, o, d, specular_depth, max_depth, eps, ulps, env,
              radiance, unf, depth, normal, ends):
    """The eye rays ``o``, ``d`` (one per pixel) through worker.shading.trace_eye where no smooth
    glossy lobe is split off: ``depth``, ``normal`` and ``unf`` (emission and, along misses,
    ``env`` seen directly) per pixel; the non-specular, non-NULL first hits (material-row tables
    ``kind``, ``specular``) as end points — pixel, position, ns, ng, wi, material, uv,
    throughput 1, segments 1, main, distance — in pixel order; then, where a chain may start,
    each mirror/glass hit's reflected and transmitted rays (all reflections first, then all
    transmissions; the brighter one the pixel's main) followed by :func:`_chains`, their end points
    after the first hits'. The main chain ends' distance and ns replace their pixels' depth and
    normal. Returns (end points written, rays traced)."""
    center = closest[1]
    p = o.shape[0]
    hits = hit_buffers(p)
    closest_surfaces(closest, o, d, p, hits)
    valid, hpos, hng, hns, huv, htt, hmat, hem = (hits[4], hits[5], hits[6], hits[7], hits[8], hits[9], hits[10],
                                                  hits[11])
    e_pix, e_pos, e_ns, e_ng, e_wi, e_mat, e_uv, e_thr, e_seg, e_main, e_dist = ends
    null_row = specular.shape[0] - 1
    no_emitter = radiance.shape[0] - 1
    wi = np.empty((p, 3))
    delta = np.empty(p, np.int64)
    n_delta = 0
    done = 0
    for i in range(p):
        depth[i] = htt[i]
        for a in range(3):
            normal[i, a] = hns[i, a]
        if not valid[i]:
            for a in range(3):
                unf[i, a] += env[a]
                normal[i, a] = 0.0
        e = hem[i]
        if e >= 0:  # emission seen directly, front side only
            cos_front = -(d[i, 0] * hns[i, 0] + d[i, 1] * hns[i, 1] + d[i, 2] * hns[i, 2])
            row = e if e < no_emitter else no_emitter
            for a in range(3):
                unf[i, a] += 0.0 if cos_front <= 0 else radiance[row, a]
        wi[i, 0], wi[i, 1], wi[i, 2] = shading_frame.to_local(-d[i, 0], -d[i, 1], -d[i, 2], hns[i, 0], hns[i, 1],
                                                              hns[i, 2])
        m = hmat[i]
        r = m if 0 <= m < null_row else null_row
        if specular[r]:
            delta[n_delta] = i
            n_delta += 1
        elif kind[r] != null_kind:
            e_pix[done] = i
            e_mat[done] = m
            e_seg[done] = 1
            e_main[done] = True
            e_dist[done] = htt[i]
            for a in range(3):
                e_pos[done, a] = hpos[i, a]
                e_ns[done, a] = hns[i, a]
                e_ng[done, a] = hng[i, a]
                e_wi[done, a] = wi[i, a]
                e_thr[done, a] = 1.0
            e_uv[done, 0] = huv[i, 0]
            e_uv[done, 1] = huv[i, 1]
            done += 1
    first = done
    if n_delta == 0 or specular_depth <= 0 or not (max_depth < 0 or 2 <= max_depth):
        return done, p
    # the delta components of each mirror/glass hit, both traced: reflections, then transmissions
    comp = np.empty((n_delta, 12))
    best = np.empty(n_delta, np.int64)
    for q in range(n_delta):
        i = delta[q]
        m = hmat[i]
        res = kb.specular(P, m if 0 <= m < null_row else null_row, wi[i, 0], wi[i, 1], wi[i, 2], True)
        for c in range(12):
            comp[q, c] = res[c]
        # np.argmax of (luminance where the component carries light, else -1): NaN wins, ties go first
        lum0 = comp[q, 3] * _WR + comp[q, 4] * _WG + comp[q, 5] * _WB if _carries(comp, q, 3) else -1.0
        lum1 = comp[q, 9] * _WR + comp[q, 10] * _WG + comp[q, 11] * _WB if _carries(comp, q, 9) else -1.0
        if lum0 != lum0:
            best[q] = 0
        elif lum1 != lum1 or lum1 > lum0:
            best[q] = 1
        else:
            best[q] = 0
    n = 2 * n_delta
    pix, bo, bd, thr = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    main, dist = np.empty(n, np.bool_), np.empty(n)
    b = 0
    for ci in range(2):
        at = 6 * ci
        for q in range(n_delta):
            if not _carries(comp, q, at + 3):
                continue
            i = delta[q]
            dx, dy, dz = shading_frame.to_world(comp[q, at], comp[q, at + 1], comp[q, at + 2], hns[i, 0], hns[i, 1],
                                                hns[i, 2])
            pix[b] = i
            bd[b, 0], bd[b, 1], bd[b, 2] = dx, dy, dz
            bo[b, 0], bo[b, 1], bo[b, 2] = offset_point(hpos[i, 0], hpos[i, 1], hpos[i, 2], hng[i, 0], hng[i, 1],
                                                        hng[i, 2], dx, dy, dz, center, eps, ulps)
            for a in range(3):
                thr[b, a] = comp[q, at + 3 + a]
            main[b] = best[q] == ci
            dist[b] = htt[i]
            b += 1
    if b == 0:
        return done, p
    chained, traced = _chains(P, kind, specular, null_kind, rng, closest, pix[:b], bo[:b], bd[:b], thr[:b],
                                 main[:b], dist[:b], specular_depth, max_depth, eps, ulps, env, radiance, unf,
                                 (e_pix[first:], e_pos[first:], e_ns[first:], e_ng[first:], e_wi[first:],
                                  e_mat[first:], e_uv[first:], e_thr[first:], e_seg[first:], e_main[first:],
                                  e_dist[first:]))
    done = first + chained
    for k in range(first, done):  # the chains' main end points replace their pixels' first hits
        if e_main[k]:
            depth[e_pix[k]] = e_dist[k]
            for a in range(3):
                normal[e_pix[k], a] = e_ns[k, a]
    return done, p + traced


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _carries(comp, q, at):
    """np.any(weight > 0) of the component weight comp[q, at:at + 3]."""
    return comp[q, at] > 0.0 or comp[q, at + 1] > 0.0 or comp[q, at + 2] > 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _chains(P, kind, specular, null_kind, rng, closest, pix, o, d, thr, main, dist, specular_depth, max_depth,
               eps, ulps, env, radiance, unf, ends):
    """The eye paths' mirror/glass chains past their first hit (worker.shading._follow_chains
    where no smooth glossy lobe is split off along them). Rays (pixel ``pix``,
    offset origin ``o``, direction ``d``, throughput, main flag, distance so far) reach their
    closest hits; emission on area emitters (``radiance`` per emitter, a last row of 0, front
    side only) and, under a sky, ``env`` along misses are added to their pixel's ``unf`` (misses
    first, then hits, as the numpy loop adds them); a non-specular, non-NULL hit (material row
    ``kind``/``specular`` tables) is an end point, written to ``ends`` (pixel, position, ns, ng,
    wi, material, uv, throughput, segments, main, distance: per bounce, in ray order); a
    specular one samples its BSDF (specular_chain.delta_bounce, any sample that carries light, u1 then
    u2 drawn from ``rng``) and goes on. The ray arrays are overwritten. Returns (end points
    written, rays traced)."""
    center = closest[1]
    n = pix.shape[0]
    src, bthr, bseg = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int64)
    bd, bo = np.empty((n, 3)), np.empty((n, 3))
    hits = hit_buffers(n)
    valid, hpos, hng, hns, huv, htt, hmat, hem = (hits[4], hits[5], hits[6], hits[7], hits[8], hits[9], hits[10],
                                                  hits[11])
    no_seg, prow, di = np.zeros(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    e_pix, e_pos, e_ns, e_ng, e_wi, e_mat, e_uv, e_thr, e_seg, e_main, e_dist = ends
    sky = env[0] != 0.0 or env[1] != 0.0 or env[2] != 0.0
    null_row = specular.shape[0] - 1
    no_emitter = radiance.shape[0] - 1
    live, done, traced = n, 0, 0
    for bounce in range(1, specular_depth + 1):
        if live == 0:
            break
        seg = bounce + 1  # segments of the path once this ray hits
        closest_surfaces(closest, o, d, live, hits)
        traced += live
        if max_depth < 0 or seg <= max_depth:
            if sky:
                for i in range(live):
                    if not valid[i]:
                        for a in range(3):
                            unf[pix[i], a] += thr[i, a] * env[a]
            for i in range(live):
                e = hem[i]
                if valid[i] and e >= 0:
                    cos_front = -(d[i, 0] * hns[i, 0] + d[i, 1] * hns[i, 1] + d[i, 2] * hns[i, 2])
                    row = e if e < no_emitter else no_emitter
                    for a in range(3):
                        le = 0.0 if cos_front <= 0 else radiance[row, a]
                        unf[pix[i], a] += thr[i, a] * le
        cnt = 0
        for i in range(live):
            dist[i] = dist[i] + htt[i]
            m = hmat[i]
            r = m if 0 <= m < null_row else null_row
            if specular[r]:
                di[cnt] = i
                prow[i] = r
                cnt += 1
            elif kind[r] != null_kind:
                e_pix[done] = pix[i]
                e_mat[done] = m
                e_seg[done] = seg
                e_main[done] = main[i]
                e_dist[done] = dist[i]
                e_wi[done, 0], e_wi[done, 1], e_wi[done, 2] = shading_frame.to_local(
                    -d[i, 0], -d[i, 1], -d[i, 2], hns[i, 0], hns[i, 1], hns[i, 2])
                for a in range(3):
                    e_pos[done, a] = hpos[i, a]
                    e_ns[done, a] = hns[i, a]
                    e_ng[done, a] = hng[i, a]
                    e_thr[done, a] = thr[i, a]
                e_uv[done, 0] = huv[i, 0]
                e_uv[done, 1] = huv[i, 1]
                done += 1
        if cnt == 0 or not (max_depth < 0 or seg + 1 <= max_depth):
            break
        u1 = rng.random(cnt)
        u2 = rng.random((cnt, 2))
        c = delta_bounce(P, prow, di[:cnt], hpos, hns, hng, d, thr, no_seg, u1, u2, -1, False, center, eps, ulps,
                         src, bthr, bseg, bd, bo)
        for j in range(c):  # (src[j] >= j: each ray read before its row is written)
            i = src[j]
            pix[j] = pix[i]
            main[j] = main[i]
            dist[j] = dist[i]
            for a in range(3):
                thr[j, a] = bthr[j, a]
                d[j, a] = bd[j, a]
                o[j, a] = bo[j, a]
        live = c
    return done, traced
