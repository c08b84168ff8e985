"""One bounce of a mirror/glass chain, fused: the delta BSDF sampled at each chain vertex, the
rays that still carry light compacted, turned to world space and offset off their surface,
ready for Embree (worker.indirect_caustics follows its chains with it: per bounce a dozen numpy
passes over a few thousand rays, whose fixed costs outweighed the work).

The math is the kernels' own (common.kernels.bsdf.sample, common.kernels.shading_frame,
common.kernels.hit_surface.offset_point), in the order the numpy form applied it, so the rays
are bit-identical to it.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.kernels import environment_map as env_map

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point
from igi.common.kernels.ray_packets import closest_surfaces, hit_buffers


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per point.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def delta_bounce(P, prow, src, pos, ns, ng, d, thr, seg, u1, u2, max_depth, delta_only, center, eps, ulps,
                 out_src, out_thr, out_seg, out_d, out_o) -> int:
    """The chain vertices ``i = src[j]`` (on surfaces with parameters ``P[.][prow[i]]``, reached
    along ``d[i]`` with throughput ``thr[i]`` after ``seg[i]`` segments) each sample their BSDF
    with ``(u1[j], u2[j])``; the delta samples (any sample, ``delta_only`` False) that carry
    light (positive in some channel, finite in all) and stay within ``max_depth`` segments (< 0: no limit) are written, in order, to the
    outputs: i, throughput × weight, segments + 1, world direction, offset origin. Returns how
    many were written."""
    c = 0
    for j in range(src.shape[0]):
        i = src[j]
        nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
        wix, wiy, wiz = shading_frame.to_local(-d[i, 0], -d[i, 1], -d[i, 2], nx, ny, nz)
        ox, oy, oz, wr, wg, wb, _p, delta = kb.sample(P, prow[i], wix, wiy, wiz, u1[j], u2[j, 0], u2[j, 1], True)
        if delta_only and not delta:
            continue
        if not kb.carries(wr, wg, wb):
            continue
        s = seg[i] + 1
        if max_depth >= 0 and s > max_depth:
            continue
        dx, dy, dz = shading_frame.to_world(ox, oy, oz, nx, ny, nz)
        out_src[c] = i
        out_thr[c, 0] = thr[i, 0] * wr
        out_thr[c, 1] = thr[i, 1] * wg
        out_thr[c, 2] = thr[i, 2] * wb
        out_seg[c] = s
        out_d[c, 0] = dx
        out_d[c, 1] = dy
        out_d[c, 2] = dz
        out_o[c, 0], out_o[c, 1], out_o[c, 2] = offset_point(pos[i, 0], pos[i, 1], pos[i, 2], ng[i, 0], ng[i, 1],
                                                              ng[i, 2], dx, dy, dz, center, eps, ulps)
        c += 1
    return c


@njit(cache=True, nogil=True, error_model="numpy")
def follow_chains(P, specular, rng, closest, rows, pos, ns, ng, d, thr, seg, prow, specular_depth, max_depth,
                  eps, ulps, env, sky_map, out, ends):
    """Whole mirror/glass chains (worker.indirect_caustics), bounce after bounce in one call:
    each vertex samples its delta BSDF (:func:`delta_bounce`, u1 then u2 drawn from ``rng``
    per bounce, as the numpy loop draws them), the rays go to Embree in packets and their hits
    are reconstructed (``closest``: common.geometry.Geometry.closest_terms); a miss adds
    throughput × ``env`` (or the environment map ``sky_map``'s radiance along it, where the sky
    is one: common.kernels.environment_map) to its row of ``out`` (under a lit sky), a hit on a surface
    whose material row is not ``specular`` ends the chain and is written to ``ends`` (rows,
    throughput, segments, direction, position, ns, ng, material, uv, t: per bounce, in ray
    order), a specular one goes on. The chain state (``rows`` … ``prow``: the vertices of
    material rows ``prow`` of ``P``) is overwritten. Returns (chain ends written, rays traced)."""
    center = closest[1]
    n = rows.shape[0]
    src, bthr, bseg = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int64)
    bd, bo = np.empty((n, 3)), np.empty((n, 3))
    hits = hit_buffers(n)
    valid, hpos, hng, hns, huv, htt, hmat = hits[4], hits[5], hits[6], hits[7], hits[8], hits[9], hits[10]
    order = np.arange(n)
    e_rows, e_thr, e_seg, e_d, e_pos, e_ns, e_ng, e_mat, e_uv, e_t = ends
    sky = env[0] > 0.0 or env[1] > 0.0 or env[2] > 0.0
    mapped = sky_map[0].shape[0] > 0
    null_row = specular.shape[0] - 1
    live, done, traced = n, 0, 0
    for _ in range(specular_depth):
        u1 = rng.random(live)
        u2 = rng.random((live, 2))
        # (np.bool_, not a literal: a literal argument would compile delta_bounce once more, ~10 s cold)
        c = delta_bounce(P, prow, order[:live], pos, ns, ng, d, thr, seg, u1, u2, max_depth, np.bool_(True), center,
                         eps, ulps, src, bthr, bseg, bd, bo)
        if c == 0:
            break
        closest_surfaces(closest, bo, bd, c, hits)
        traced += c
        q = 0
        for i in range(c):
            r = rows[src[i]]
            if not valid[i]:
                if sky and mapped:
                    lr, lg, lb = env_map.radiance(sky_map, bd[i, 0], bd[i, 1], bd[i, 2])
                    out[r, 0] += bthr[i, 0] * lr
                    out[r, 1] += bthr[i, 1] * lg
                    out[r, 2] += bthr[i, 2] * lb
                elif sky:
                    for a in range(3):
                        out[r, a] += bthr[i, a] * env[a]
                continue
            m = hmat[i]
            if not specular[m if m >= 0 else specular.shape[0] + m]:
                e_rows[done] = r
                e_seg[done] = bseg[i]
                e_mat[done] = m
                e_t[done] = htt[i]
                for a in range(3):
                    e_thr[done, a] = bthr[i, a]
                    e_d[done, a] = bd[i, a]
                    e_pos[done, a] = hpos[i, a]
                    e_ns[done, a] = hns[i, a]
                    e_ng[done, a] = hng[i, a]
                e_uv[done, 0] = huv[i, 0]
                e_uv[done, 1] = huv[i, 1]
                done += 1
                continue
            # still on the chain: vertex q of the next bounce (q <= i <= src[i]: rows read ahead of the writes)
            rows[q] = r
            seg[q] = bseg[i]
            prow[q] = m if 0 <= m < null_row else null_row
            for a in range(3):
                thr[q, a] = bthr[i, a]
                d[q, a] = bd[i, a]
                pos[q, a] = hpos[i, a]
                ns[q, a] = hns[i, a]
                ng[q, a] = hng[i, a]
            q += 1
        live = q
        if live == 0:
            break
    return done, traced
