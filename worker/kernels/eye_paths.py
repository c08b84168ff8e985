"""Eye paths (Wald et al. 2002 §4: one per pixel, split at the first hit, mirror and glass
chains followed), fused: the first hits from Embree's packets, what they see directly, their end
points, the split of mirror/glass hits into their delta components and of smooth glossy hits into
their diffuse layer and one sampled lobe ray, and the chains behind them (:func:`_chains`), in one
call per tile instead of ~40 numpy passes and a dozen more per bounce.

The math is the kernels' own (common.kernels.bsdf, shading_frame, hit_surface), in the order
worker.shading.trace_eye's numpy form applies it, drawing from its generator in the same order,
so the end points are bit-identical to it.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.bsdf import SPLIT_THROUGHPUT
from igi.common.kernels import bsdf as kb
from igi.common.kernels import environment_map as env_map
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point
from igi.common.kernels.ray_packets import closest_surfaces, hit_buffers
from igi.common.lights import LUMINANCE_WEIGHTS
from igi.common.scene import PLASTIC, ROUGHCONDUCTOR, ROUGHDIELECTRIC

from .environment_bins import guide_pdf
from .specular_chain import delta_bounce

_WR, _WG, _WB = LUMINANCE_WEIGHTS  # (frozen into the kernels as constants)
# An end point's relabelling (ends' last array): a split plastic's diffuse layer (a rough one
# ROUGHPLASTIC_DIFFUSE, a smooth one its coat zeroed: common.bsdf.split_layer), a split lobe's
# direct-only light-sample point (ROUGHPLASTIC_LOBE), or rough glass's through its lobe that
# faces the outside (common.bsdf.outward_lobe).
LAYER, LOBE_LIGHTS, GLASS_LIGHTS = 1, 2, 3


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _put_end(ends, k, pix, i, pos, ns, ng, wx, wy, wz, mat, uv, t0, t1, t2, seg, main, dist, code) -> None:
    """End point k (< the room of ``ends``: the caller checks) from row i of the hit arrays.
    Straight-line on purpose, no branch and no loop: inlined per end point, its arguments' 17
    arrays are reference-counted, and numba's refcount pruning drops those counts only within
    one basic block (an early return here left 34 atomic operations per end point)."""
    e_pix, e_pos, e_ns, e_ng, e_wi, e_mat, e_uv, e_thr, e_seg, e_main, e_dist, e_code = ends
    e_pix[k] = pix
    e_mat[k] = mat[i]
    e_seg[k] = seg
    e_main[k] = main
    e_dist[k] = dist
    e_code[k] = code
    e_pos[k, 0], e_pos[k, 1], e_pos[k, 2] = pos[i, 0], pos[i, 1], pos[i, 2]
    e_ns[k, 0], e_ns[k, 1], e_ns[k, 2] = ns[i, 0], ns[i, 1], ns[i, 2]
    e_ng[k, 0], e_ng[k, 1], e_ng[k, 2] = ng[i, 0], ng[i, 1], ng[i, 2]
    e_wi[k, 0], e_wi[k, 1], e_wi[k, 2] = wx, wy, wz
    e_thr[k, 0], e_thr[k, 1], e_thr[k, 2] = t0, t1, t2
    e_uv[k, 0], e_uv[k, 1] = uv[i, 0], uv[i, 1]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _carries_any(w0, w1, w2) -> bool:
    """np.any(weight > 0)."""
    return w0 > 0.0 or w1 > 0.0 or w2 > 0.0


# The per-hit BSDF calls below go through common.kernels.bsdf's array loops, one call per
# bounce: inlined per hit, each call counted the references of P's 17 arrays (atomic NRT
# increfs/decrefs LLVM could not prune past the kinds' branches), ~half the eye stage on a
# glossy scene (docs/benchmarks.md, stop 45); the loops are compiled without reference counts.


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _glass_lobe(kind, row) -> bool:
    """A hit on rough glass: a direct-only point (code GLASS_LIGHTS) through its lobe that faces
    the outside, where the emitters are (seen from outside its reflection, from inside its
    refraction out: common.bsdf.outward_lobe) takes the set's emitter samples, and the traced
    ray that leaves through that lobe their MIS weight (design note 48): emitters seen through
    frosted glass were met by chance only."""
    return kind[row] == ROUGHDIELECTRIC


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sample_lobes(P, P_lobe, with_pdf, row, wi, u, out_wo, out_w, out_pdf) -> None:
    """Each point's sampled lobe ray (kb.sample_lobe) and, ``with_pdf``, its lobe pdf under
    ``P_lobe`` (the MIS weight against the light samples; 0 for a smooth plastic's mirror, a
    delta no light sample can take); ``out_pdf`` stays as given otherwise."""
    kb.sample_lobe_many(P, row, wi, u, out_wo, out_w)
    if with_pdf:
        kb.eval_many(P_lobe, row, wi, out_wo, np.empty_like(out_wo), out_pdf)
        for q in range(row.shape[0]):
            if P[0][row[q]] == PLASTIC:
                out_pdf[q] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def trace_eye(P, kind, specular, null_kind, rng, closest, o, d, specular_depth, max_depth, eps, ulps, env,
              radiance, lobes, unf, depth, normal, ends):
    """The eye rays ``o``, ``d`` (one per pixel) through worker.shading.trace_eye: ``depth``,
    ``normal`` and ``unf`` (emission and, along misses, ``env`` seen directly) per pixel; the
    non-specular, non-NULL first hits (material-row tables ``kind``, ``specular``) as end points
    — pixel, position, ns, ng, wi, material, uv, throughput, segments, main, distance, code —
    in pixel order (a smooth glossy one, where a chain may start: a plastic's diffuse layer
    only, code LAYER; a conductor none); then the split lobes' light-sample points (code
    LOBE_LIGHTS), then rough glass's (:func:`_glass_lobe`, code GLASS_LIGHTS); then, where a
    chain may start, the lobes' sampled rays and each mirror/glass hit's reflected and
    transmitted rays (all reflections first, then all transmissions; the brighter one the
    pixel's main) followed by :func:`_chains`, their end points after.
    ``lobes``: (split smooth glossy hits?, smooth per material row, P with the plastics' kind
    their lobe's, light samples per set (0: the lobes take none, no MIS), area pdf per emitter
    (a last row of 0), the environment's pdf — its emitter-choice probability where guided or a
    map —, the environment guide's histogram density (empty: not guided; worker.env_guide, its
    mixture q(ω) per direction: kernels.environment_bins.guide_pdf) and the sky's environment
    map (common.kernels.environment_map; empty: a constant ``env``)). The main chain ends' distance and ns replace their
    pixels' depth and normal. Returns (end points written, rays traced); (-1, rays) where
    ``ends`` was too small."""
    center = closest[1]
    split, smooth, P_lobe, direct_count = lobes[0], lobes[1], lobes[2], lobes[3]
    sky_map = lobes[7]
    mapped = sky_map[0].shape[0] > 0
    p = o.shape[0]
    hits = hit_buffers(p)
    closest_surfaces(closest, o, d, p, hits)
    valid, hpos, hng, hns, huv, htt, hmat, hem = (hits[4], hits[5], hits[6], hits[7], hits[8], hits[9], hits[10],
                                                  hits[11])
    e_pix, e_main, e_dist, e_ns = ends[0], ends[9], ends[10], ends[2]
    room = e_pix.shape[0]
    null_row = specular.shape[0] - 1
    no_emitter = radiance.shape[0] - 1
    chains = specular_depth > 0 and (max_depth < 0 or 2 <= max_depth)
    split_here = split and chains
    wi = np.empty((p, 3))
    delta, lobe, prow = np.empty(p, np.int64), np.empty(p, np.int64), np.empty(p, np.int64)
    n_delta, n_lobe, done = 0, 0, 0
    for i in range(p):
        depth[i] = htt[i]
        for a in range(3):
            normal[i, a] = hns[i, a]
        if not valid[i]:
            if mapped:
                lr, lg, lb = env_map.radiance(sky_map, d[i, 0], d[i, 1], d[i, 2])
                unf[i, 0] += lr
                unf[i, 1] += lg
                unf[i, 2] += lb
            else:
                for a in range(3):
                    unf[i, a] += env[a]
            for a in range(3):
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
        prow[i] = r
        if specular[r]:
            delta[n_delta] = i
            n_delta += 1
            continue
        if kind[r] == null_kind:
            continue
        code = 0
        if split_here and smooth[r]:
            lobe[n_lobe] = i
            n_lobe += 1
            if kind[r] == ROUGHCONDUCTOR:  # all lobe: its sampled ray alone
                continue
            code = LAYER
        if done >= room:
            return -1, p
        _put_end(ends, done, i, i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv, 1.0, 1.0, 1.0, 1,
                 True, htt[i], code)
        done += 1
    # the split lobes: one sampled ray each (u2 drawn for all of them), their light-sample points
    lobe_wo, lobe_w, lobe_pdf = np.empty((n_lobe, 3)), np.empty((n_lobe, 3)), np.zeros(n_lobe)
    if n_lobe > 0:
        u = rng.random((n_lobe, 2))
        sel = lobe[:n_lobe]
        _sample_lobes(P, P_lobe, direct_count > 0, prow[sel], wi[sel], u, lobe_wo, lobe_w, lobe_pdf)
        if direct_count > 0:
            for q in range(n_lobe):
                i = lobe[q]
                if kind[prow[i]] == PLASTIC:  # a mirror takes no light samples
                    continue
                if done >= room:
                    return -1, p
                _put_end(ends, done, i, i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv, 1.0, 1.0,
                         1.0, 1, False, htt[i], LOBE_LIGHTS)
                done += 1
    # rough glass: its light-sample points (design note 48)
    glass_lights = chains and direct_count > 0
    if glass_lights:
        for q in range(n_delta):
            i = delta[q]
            if _glass_lobe(kind, prow[i]):
                if done >= room:
                    return -1, p
                _put_end(ends, done, i, i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv, 1.0, 1.0,
                         1.0, 1, False, htt[i], GLASS_LIGHTS)
                done += 1
    first = done
    if not chains or (n_delta == 0 and n_lobe == 0):
        return done, p
    # the delta components of each mirror/glass hit, both traced: reflections, then transmissions
    comp = np.empty((n_delta, 12))
    best = np.empty(n_delta, np.int64)
    sel = delta[:n_delta]
    # a rough dielectric's microfacet normals: drawn only where there is one (other scenes' streams unchanged)
    rough = False
    for q in range(n_delta):
        rough = rough or kind[prow[sel[q]]] == ROUGHDIELECTRIC
    u_m = rng.random((n_delta, 2)) if rough else np.full((n_delta, 2), 0.5)
    # (np.bool_: a literal True would have specular_many compiled once more, for Literal[bool])
    kb.specular_many(P, prow[sel], wi[sel], np.bool_(True), u_m, comp[:, 0:3], comp[:, 3:6], comp[:, 6:9],
                     comp[:, 9:12])
    for q in range(n_delta):
        # np.argmax of (luminance where the component carries light, else -1): NaN wins, ties go first
        lum0 = comp[q, 3] * _WR + comp[q, 4] * _WG + comp[q, 5] * _WB if _carries_any(
            comp[q, 3], comp[q, 4], comp[q, 5]) else -1.0
        lum1 = comp[q, 9] * _WR + comp[q, 10] * _WG + comp[q, 11] * _WB if _carries_any(
            comp[q, 9], comp[q, 10], comp[q, 11]) else -1.0
        if lum0 != lum0:
            best[q] = 0
        elif lum1 != lum1 or lum1 > lum0:
            best[q] = 1
        else:
            best[q] = 0
    n = n_lobe + 2 * n_delta
    pix, bo, bd, thr = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    main, dist, mis = np.empty(n, np.bool_), np.empty(n), np.empty(n)
    b = 0
    for c in range(-1, 2):  # the lobes' rays (their radiance unfiltered: never main), then both components
        for q in range(n_lobe if c < 0 else n_delta):
            if c < 0:
                i = lobe[q]
                lx, ly, lz = lobe_wo[q, 0], lobe_wo[q, 1], lobe_wo[q, 2]
                w0, w1, w2 = lobe_w[q, 0], lobe_w[q, 1], lobe_w[q, 2]
                is_main, pdf = False, lobe_pdf[q]
            else:
                i = delta[q]
                at = 6 * c
                lx, ly, lz = comp[q, at], comp[q, at + 1], comp[q, at + 2]
                w0, w1, w2 = comp[q, at + 3], comp[q, at + 4], comp[q, at + 5]
                is_main, pdf = best[q] == c, 0.0
                if glass_lights and lz > 0.0 and _glass_lobe(kind, prow[i]):
                    # leaving through the lobe its light samples take: weighed against them
                    pdf = kb.glass_lobe_pdf(P, prow[i], wi[i, 0], wi[i, 1], wi[i, 2], lx, ly, lz)
            if not _carries_any(w0, w1, w2):
                continue
            dx, dy, dz = shading_frame.to_world(lx, ly, lz, hns[i, 0], hns[i, 1], hns[i, 2])
            pix[b] = i
            bd[b, 0], bd[b, 1], bd[b, 2] = dx, dy, dz
            bo[b, 0], bo[b, 1], bo[b, 2] = offset_point(hpos[i, 0], hpos[i, 1], hpos[i, 2], hng[i, 0], hng[i, 1],
                                                        hng[i, 2], dx, dy, dz, center, eps, ulps)
            thr[b, 0], thr[b, 1], thr[b, 2] = w0, w1, w2
            main[b] = is_main
            dist[b] = htt[i]
            mis[b] = pdf
            b += 1
    if b == 0:
        return done, p
    chained, traced = _chains(P, kind, specular, null_kind, rng, closest, (pix, bo, bd, thr, main, dist, mis), b,
                              specular_depth, max_depth, eps, ulps, env, radiance, lobes, unf, ends, first)
    if chained < 0:
        return -1, p + traced
    done = chained
    for k in range(first, done):  # the chains' main end points replace their pixels' first hits
        if e_main[k]:
            depth[e_pix[k]] = e_dist[k]
            for a in range(3):
                normal[e_pix[k], a] = e_ns[k, a]
    return done, p + traced


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _emission_mis(direct_count, area_pdf, env_pdf, mis_pdf, valid, emitter, t, cos_front) -> float:
    """worker.shading._mis_emission's weight of emission met by a ray of sampling pdf
    ``mis_pdf`` (1 where 0) against the set's light samples: an area emitter's area pdf over
    t²/|cos| (a valid hit), the environment's pdf (a miss), × the light samples per set.
    (Not handed ``lobes`` whole: an inlined call per ray counted the references of its arrays.)"""
    if not mis_pdf > 0.0:
        return 1.0
    if valid:
        pl = area_pdf[emitter] * t ** 2 / max(abs(cos_front), 1e-7) if emitter >= 0 else 0.0
    else:
        pl = env_pdf
    pl = pl * direct_count
    return mis_pdf ** 2 / max(mis_pdf ** 2 + pl ** 2, 1e-300)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _chains(P, kind, specular, null_kind, rng, closest, rays, live, specular_depth, max_depth, eps, ulps, env,
            radiance, lobes, unf, ends, done):
    """The eye paths' mirror/glass chains past their first hit (worker.shading._follow_chains).
    ``rays`` (pixel, offset origin, direction, throughput, main flag, distance so far, lobe pdf
    for MIS or 0), the first ``live`` of them, reach their closest hits; emission on area
    emitters (``radiance`` per emitter, a last row of 0, front side only) and, under a sky,
    ``env`` along misses are added to their pixel's ``unf`` (misses first, then hits, as the
    numpy loop adds them; a lobe ray's MIS-weighted); a non-specular, non-NULL hit is an end
    point, written to ``ends`` from ``done`` on (per bounce, in ray order; a smooth glossy one as
    trace_eye's first hits, its lobe's light-sample points after the bounce's end points); a
    specular one samples its BSDF (specular_chain.delta_bounce, any sample that carries light,
    u1 then u2 drawn from ``rng``), then the smooth glossy ones their lobe (u2), and the rays go
    on: the delta samples', then the lobes'. Returns (ends written in all, rays traced); -1 for
    the first where ``ends`` was too small."""
    center = closest[1]
    split, smooth, P_lobe, direct_count, area_pdf, env_pdf, env_density, sky_map = lobes
    guided = env_density.shape[0] > 0
    mapped = sky_map[0].shape[0] > 0
    cur = rays
    n = cur[0].shape[0]
    nxt = (np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.bool_),
           np.empty(n), np.empty(n))
    src, bthr, bseg = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int64)
    bd, bo = np.empty((n, 3)), np.empty((n, 3))
    hits = hit_buffers(n)
    valid, hpos, hng, hns, huv, htt, hmat, hem = (hits[4], hits[5], hits[6], hits[7], hits[8], hits[9], hits[10],
                                                  hits[11])
    room = ends[0].shape[0]
    no_seg, prow, di, lobe = np.zeros(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    lobe_main = np.empty(n, np.bool_)
    wi = np.empty((n, 3))
    sky = env[0] != 0.0 or env[1] != 0.0 or env[2] != 0.0
    null_row = specular.shape[0] - 1
    no_emitter = radiance.shape[0] - 1
    traced = 0
    for bounce in range(1, specular_depth + 1):
        if live == 0:
            break
        pix, o, d, thr, main, dist, mis = cur
        seg = bounce + 1  # segments of the path once this ray hits
        closest_surfaces(closest, o, d, live, hits)
        traced += live
        if max_depth < 0 or seg <= max_depth:
            if sky:
                for i in range(live):
                    if not valid[i]:
                        # a guided sky's pdf along the ray (worker.shading.emitter_pdf: pmf × q(ω))
                        # (a map's: pmf × its pdf; a constant sky's env_pdf is already pmf / 4π)
                        if guided:
                            pe = env_pdf * guide_pdf(env_density, sky_map, d[i, 0], d[i, 1], d[i, 2])
                        elif mapped:
                            pe = env_pdf * env_map.pdf(sky_map, d[i, 0], d[i, 1], d[i, 2])
                        else:
                            pe = env_pdf
                        w = _emission_mis(direct_count, area_pdf, pe, mis[i], False, -1, htt[i], 0.0)
                        if mapped:
                            lr, lg, lb = env_map.radiance(sky_map, d[i, 0], d[i, 1], d[i, 2])
                            unf[pix[i], 0] += thr[i, 0] * lr * w
                            unf[pix[i], 1] += thr[i, 1] * lg * w
                            unf[pix[i], 2] += thr[i, 2] * lb * w
                        else:
                            for a in range(3):
                                unf[pix[i], a] += thr[i, a] * env[a] * w
            for i in range(live):
                e = hem[i]
                if valid[i] and e >= 0:
                    cos_front = -(d[i, 0] * hns[i, 0] + d[i, 1] * hns[i, 1] + d[i, 2] * hns[i, 2])
                    w = _emission_mis(direct_count, area_pdf, env_pdf, mis[i], True, e, htt[i], cos_front)
                    row = e if e < no_emitter else no_emitter
                    for a in range(3):
                        le = 0.0 if cos_front <= 0 else radiance[row, a]
                        unf[pix[i], a] += thr[i, a] * le * w
        n_di, n_lobe = 0, 0
        for i in range(live):
            dist[i] = dist[i] + htt[i]
            wi[i, 0], wi[i, 1], wi[i, 2] = shading_frame.to_local(-d[i, 0], -d[i, 1], -d[i, 2], hns[i, 0], hns[i, 1],
                                                                  hns[i, 2])
            m = hmat[i]
            r = m if 0 <= m < null_row else null_row
            if specular[r]:
                di[n_di] = i
                prow[i] = r
                n_di += 1
                continue
            if kind[r] == null_kind:
                continue
            code = 0
            # (common.bsdf.split_eligible: a dim path ends at a smooth plastic unsplit)
            if split and smooth[r] and (kind[r] != PLASTIC
                                        or thr[i, 0] * _WR + thr[i, 1] * _WG + thr[i, 2] * _WB >= SPLIT_THROUGHPUT):
                lobe[n_lobe] = i
                prow[i] = r
                lobe_main[n_lobe] = main[i] and kind[r] == ROUGHCONDUCTOR  # a plastic's layer keeps the main end
                n_lobe += 1
                if kind[r] == ROUGHCONDUCTOR:
                    continue
                code = LAYER
            if done >= room:
                return -1, traced
            _put_end(ends, done, pix[i], i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv, thr[i, 0],
                     thr[i, 1], thr[i, 2], seg, main[i], dist[i], code)
            done += 1
        if (n_di == 0 and n_lobe == 0) or not (max_depth < 0 or seg + 1 <= max_depth):
            break
        glass_lights = direct_count > 0
        if glass_lights:  # rough glass's light-sample points (design note 48), before the lobes'
            for q in range(n_di):
                i = di[q]
                if _glass_lobe(kind, prow[i]):
                    if done >= room:
                        return -1, traced
                    _put_end(ends, done, pix[i], i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv,
                             thr[i, 0], thr[i, 1], thr[i, 2], seg, False, dist[i], GLASS_LIGHTS)
                    done += 1
        u1 = rng.random(n_di)
        u2 = rng.random((n_di, 2))
        # (np.int64/np.bool_: a literal argument would compile delta_bounce once more, ~10 s cold)
        c = delta_bounce(P, prow, di[:n_di], hpos, hns, hng, d, thr, no_seg, u1, u2, np.int64(-1), np.bool_(False),
                         center, eps, ulps, src, bthr, bseg, bd, bo)
        npix, no, nd, nthr, nmain, ndist, nmis = nxt
        for j in range(c):
            i = src[j]
            npix[j] = pix[i]
            nmain[j] = main[i]
            ndist[j] = dist[i]
            nmis[j] = 0.0
            if glass_lights and _glass_lobe(kind, prow[i]):
                ox, oy, oz = shading_frame.to_local(bd[j, 0], bd[j, 1], bd[j, 2], hns[i, 0], hns[i, 1], hns[i, 2])
                if oz > 0.0:  # leaving through the lobe its light samples take: weighed against them
                    nmis[j] = kb.glass_lobe_pdf(P, prow[i], wi[i, 0], wi[i, 1], wi[i, 2], ox, oy, oz)
            for a in range(3):
                nthr[j, a] = bthr[j, a]
                nd[j, a] = bd[j, a]
                no[j, a] = bo[j, a]
        if n_lobe > 0:
            u = rng.random((n_lobe, 2))
            l_wo, l_w, l_pdf = np.empty((n_lobe, 3)), np.empty((n_lobe, 3)), np.zeros(n_lobe)
            sel = lobe[:n_lobe]
            _sample_lobes(P, P_lobe, direct_count > 0, prow[sel], wi[sel], u, l_wo, l_w, l_pdf)
            for q in range(n_lobe):
                i = lobe[q]
                w0, w1, w2 = l_w[q, 0], l_w[q, 1], l_w[q, 2]
                if direct_count > 0 and kind[prow[i]] != PLASTIC:  # (a mirror takes no light samples)
                    if done >= room:
                        return -1, traced
                    _put_end(ends, done, pix[i], i, hpos, hns, hng, wi[i, 0], wi[i, 1], wi[i, 2], hmat, huv,
                             thr[i, 0], thr[i, 1], thr[i, 2], seg, False, dist[i], LOBE_LIGHTS)
                    done += 1
                if not kb.carries(w0, w1, w2):
                    continue
                dx, dy, dz = shading_frame.to_world(l_wo[q, 0], l_wo[q, 1], l_wo[q, 2], hns[i, 0], hns[i, 1], hns[i, 2])
                npix[c] = pix[i]
                nmain[c] = lobe_main[q]
                ndist[c] = dist[i]
                nmis[c] = l_pdf[q]
                nthr[c, 0], nthr[c, 1], nthr[c, 2] = thr[i, 0] * w0, thr[i, 1] * w1, thr[i, 2] * w2
                nd[c, 0], nd[c, 1], nd[c, 2] = dx, dy, dz
                no[c, 0], no[c, 1], no[c, 2] = offset_point(hpos[i, 0], hpos[i, 1], hpos[i, 2], hng[i, 0], hng[i, 1],
                                                            hng[i, 2], dx, dy, dz, center, eps, ulps)
                c += 1
        cur, nxt = nxt, cur
        live = c
    return done, traced
