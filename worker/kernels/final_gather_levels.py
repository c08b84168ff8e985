"""The final gather's levels found in one call (worker.final_gather: its numpy loop runs, per
level, ``_as_end_points`` → ``trace_bsdf_rays`` → ``near_arrivals``): the points of each level
that reflect, their BSDF-sampled continuation rays traced to their closest hits, and the near
hits that make the next level's points — with the same draws from the tile's generator in the
same order, so the points, rays and hits are bit for bit the loop's. At 320×240 a tile's deeper
levels hold a few dozen points; the loop's ~40 numpy passes per level cost more than them.

Materials are read per material row of P (regularized as senders: worker.regularization); a
point on a material with bitmap textures gets a row of its own with its texels.

Around it, the two steps the final gather runs per tile in numpy before: :func:`near_points`,
the end points' own near hits (the first level's arrivals), and :func:`carry_level`, one
level's light carried back to its parents (``np.add.at``: ~1 µs a point).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.bounding_spheres import any_hit
from igi.common.kernels.ray_packets import closest_surfaces

from .bsdf_rays import sample_rays


@njit(cache=True, nogil=True, error_model="numpy")
def find_levels(P, reflects, atlas, closest, rng, center, eps, ulps, reach_all, emitter_c, emitter_r2, lens_c, lens_r2,
                clamp_d2, short, max_depth, roulette_level, max_level, first, points, prow, level_stop, rays, hits,
                ray_stop) -> int:
    """Every level's points from the ``first`` arrivals (position, ns, ng, material, uv, t,
    direction, segments, parent, factor, level: worker.arrivals.Arrivals' fields) into
    ``points`` (the same fields, then wo), level by level: a point is kept where its material
    row reflects (``reflects``: not mirror/glass, not NULL, not black); ``level_stop[i]`` ends level i.
    Each level's points with a segment left sample a ray (u1 then u2 drawn from ``rng``) into
    ``rays`` (row within its level, weight, pdf, delta, direction, origin; ``ray_stop``) traced
    into ``hits`` (common.kernels.ray_packets.hit_buffers), unbounded where it may reach an
    emitter (``reach_all``, or it meets an emitter sphere) or a mirror/glass object whose
    chain the point follows (it meets a sphere of ``lens_c``, ``lens_r2``; none: no chain),
    else ``short`` far for a point of compensation level > 0 and 0 far otherwise. Its near hits
    (closer than √clamp_d2, not a delta sample, a segment left; from ``roulette_level`` on each
    goes on with probability 1/2)
    are the next level's arrivals. A point reads its material's row of P (``prow[n]``), or, on
    a material with bitmap textures (``atlas``: common.bsdf.texture_atlas), a row of its own
    past the materials' (P holds room for every point) with the textures looked up at its uv.
    Returns the number of levels."""
    a_pos, a_ns, a_ng, a_mat, a_uv, a_t, a_d, a_seg, a_parent, a_factor, a_level = first
    p_pos, p_ns, p_ng, p_mat, p_uv, p_t, p_d, p_seg, p_parent, p_factor, p_level, p_wo = points
    r_row, r_w, r_pdf, r_delta, r_d, r_o = rays
    h_prim, h_u, h_v, h_t, h_valid, h_pos, h_ng, h_ns, h_uv, h_tt, h_mat, h_em, h_mesh, h_tfar = hits
    m = reflects.shape[0] - 1  # the NULL row
    radius = np.sqrt(clamp_d2)
    level_stop[0] = 0
    ray_stop[0] = 0
    # level 0: the first arrivals that reflect
    n = 0
    for i in range(a_parent.shape[0]):
        mat = a_mat[i]
        row = mat if 0 <= mat < m else m
        if not reflects[row]:
            continue
        _put(points, n, a_pos[i, 0], a_pos[i, 1], a_pos[i, 2], a_ns[i, 0], a_ns[i, 1], a_ns[i, 2], a_ng[i, 0],
             a_ng[i, 1], a_ng[i, 2], mat, a_uv[i, 0], a_uv[i, 1], a_t[i], a_d[i, 0], a_d[i, 1], a_d[i, 2], a_seg[i],
             a_parent[i], a_factor[i, 0], a_factor[i, 1], a_factor[i, 2], a_level[i])
        prow[n] = row
        n += 1
    # the level's rows of P in one call (kb.material_rows, in place): inlined per point, the
    # call counted the references of P's 17 arrays and the atlas' (docs/benchmarks.md, stop 46)
    kb.material_rows(P, prow[:n], m + 1, atlas, p_uv[:n], prow[:n])
    level = 0
    p0, p1, r0 = 0, n, 0
    while p1 > p0:
        level_stop[level + 1] = p1
        # the level's rays (trace_bsdf_rays): every point with a segment left
        src = np.empty(p1 - p0, np.int64)
        k = 0
        for i in range(p0, p1):
            if max_depth < 0 or p_seg[i] + 1 <= max_depth:
                src[k] = i - p0
                k += 1
        u1 = rng.random(k)
        u2 = rng.random((k, 2))
        # (np.bool_: a literal True would have sample_rays compiled once more, for Literal[bool])
        c = sample_rays(P, prow[p0:p1], src[:k], p_wo[p0:p1], p_ns[p0:p1], p_pos[p0:p1], p_ng[p0:p1], u1, u2,
                        np.bool_(True), center, eps, ulps, r_row[r0:], r_w[r0:], r_pdf[r0:], r_delta[r0:], r_d[r0:], r_o[r0:])
        r1 = r0 + c
        reach = np.ones(c, np.bool_)
        if not reach_all:
            any_hit(r_o[r0:r1], r_d[r0:r1], emitter_c, emitter_r2, reach)
            if lens_r2.shape[0] > 0:
                lens = np.empty(c, np.bool_)
                any_hit(r_o[r0:r1], r_d[r0:r1], lens_c, lens_r2, lens)
                for j in range(c):
                    reach[j] = reach[j] or lens[j]
        for j in range(c):
            i = p0 + r_row[r0 + j]
            h_tfar[r0 + j] = np.float32(3.0e38) if reach[j] else np.float32(short if p_level[i] > 0 else 0.0)
        closest_surfaces(closest, r_o[r0:r1], r_d[r0:r1], c,
                         (h_prim[r0:], h_u[r0:], h_v[r0:], h_t[r0:], h_valid[r0:], h_pos[r0:], h_ng[r0:], h_ns[r0:],
                          h_uv[r0:], h_tt[r0:], h_mat[r0:], h_em[r0:], h_mesh[r0:], h_tfar[r0:]))
        ray_stop[level + 1] = r1
        # the next level's arrivals (near_arrivals): near hits of compensated points
        rolled_any = False
        live = False
        for j in range(c):
            lv = p_level[p0 + r_row[r0 + j]]
            live = live or lv > 0
            rolled_any = rolled_any or lv >= roulette_level
        n = p1
        if live and c > 0:
            u = rng.random(c) if rolled_any else np.empty(0)
            for j in range(c):
                i = p0 + r_row[r0 + j]
                q = r0 + j
                near, share, child = _near_hit(h_valid[q], h_tt[q], r_delta[q], p_level[i], p_seg[i],
                                               u[j] if rolled_any else 1.0, radius, clamp_d2, max_depth,
                                               roulette_level, max_level)
                if not near:
                    continue
                mat = h_mat[q]
                row = mat if 0 <= mat < m else m
                if not reflects[row]:
                    continue
                t = h_tt[q]
                _put(points, n, h_pos[q, 0], h_pos[q, 1], h_pos[q, 2], h_ns[q, 0], h_ns[q, 1], h_ns[q, 2],
                     h_ng[q, 0], h_ng[q, 1], h_ng[q, 2], mat, h_uv[q, 0], h_uv[q, 1], t, r_d[q, 0], r_d[q, 1],
                     r_d[q, 2], p_seg[i] + 1, i - p0, r_w[q, 0] * share, r_w[q, 1] * share, r_w[q, 2] * share,
                     child)
                prow[n] = row
                n += 1
            kb.material_rows(P, prow[p1:n], m + 1 + p1, atlas, p_uv[p1:n], prow[p1:n])
        level += 1
        p0, p1, r0 = p1, n, r1
    return level


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _put(points, n, px, py, pz, nx, ny, nz, gx, gy, gz, mat, u, v, t, dx, dy, dz, seg, parent, f0, f1, f2, level):
    """Point n of ``points`` (find_levels' layout), its wo = -d in its shading frame."""
    p_pos, p_ns, p_ng, p_mat, p_uv, p_t, p_d, p_seg, p_parent, p_factor, p_level, p_wo = points
    p_pos[n, 0], p_pos[n, 1], p_pos[n, 2] = px, py, pz
    p_ns[n, 0], p_ns[n, 1], p_ns[n, 2] = nx, ny, nz
    p_ng[n, 0], p_ng[n, 1], p_ng[n, 2] = gx, gy, gz
    p_mat[n] = mat
    p_uv[n, 0], p_uv[n, 1] = u, v
    p_t[n] = t
    p_d[n, 0], p_d[n, 1], p_d[n, 2] = dx, dy, dz
    p_seg[n] = seg
    p_parent[n] = parent
    p_factor[n, 0], p_factor[n, 1], p_factor[n, 2] = f0, f1, f2
    p_level[n] = level
    p_wo[n, 0], p_wo[n, 1], p_wo[n, 2] = shading_frame.to_local(-dx, -dy, -dz, nx, ny, nz)


@njit(cache=True, nogil=True, error_model="numpy")
def near_points(rows, valid, t, delta, level, segments, u, radius, clamp_d2, max_depth, roulette_level,
                max_level, out_sel, out_share, out_child) -> int:
    """worker.final_gather.near_arrivals' choice: of the rays ``rows`` (end point per ray; its
    hit ``valid``, ``t``, ``delta`` sample, end point compensation ``level`` and ``segments``),
    those whose hit is nearer than ``radius`` (= √clamp_d2), not a delta sample, of a level > 0
    with a segment left; from ``roulette_level`` on each goes on where its uniform ``u`` < 1/2
    (``u`` one per ray, or empty when no level rolls). Writes each chosen ray, its share
    clip(1 - t²/clamp_d2, 0, 1) (/ 1/2 when rolled) and its child's level (level + 1, 0 past
    ``max_level``); returns how many."""
    rolled_any = u.shape[0] > 0
    n = 0
    for q in range(rows.shape[0]):
        near, share, child = _near_hit(valid[q], t[q], delta[q], level[rows[q]], segments[rows[q]],
                                       u[q] if rolled_any else 1.0, radius, clamp_d2, max_depth, roulette_level,
                                       max_level)
        if not near:
            continue
        out_sel[n] = q
        out_share[n] = share
        out_child[n] = child
        n += 1
    return n


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _near_hit(valid, t, delta, lv, seg, u, radius, clamp_d2, max_depth, roulette_level, max_level):
    """(near?, share, child's level) of a compensated point's traced ray: its hit nearer than
    ``radius`` (= √clamp_d2), not a delta sample, a level > 0, a segment left, and from
    ``roulette_level`` on its uniform ``u`` < 1/2 (u = 1 where no level of the batch rolls:
    no draw); share clip(1 - t²/clamp_d2, 0, 1) (/ 1/2 when rolled), child level + 1 (0 past
    ``max_level``)."""
    near = valid and t < radius and not delta and lv > 0
    if max_depth >= 0:
        near = near and seg + 2 <= max_depth
    rolled = lv >= roulette_level
    if rolled:
        near = near and u < 0.5
    share = min(max(1.0 - t * t / clamp_d2, 0.0), 1.0) / (0.5 if rolled else 1.0)
    return near, share, lv + 1 if lv < max_level else 0


@njit(cache=True, nogil=True, error_model="numpy")
def carry_level(start, parent_base, parent, factor, gain, albedo, irr) -> None:
    """The points rows start … start + len(parent) - 1 of ``albedo``/``irr`` send factor ×
    gain × albedo × irradiance, per unit of the parent's albedo (floored at 1e-6; 0 where not
    finite), to row parent_base + parent[q] of ``irr`` — in point order, as np.add.at adds.
    ``gain`` (n, 3), or no rows: 1."""
    use_gain = gain.shape[0] > 0
    for q in range(parent.shape[0]):
        i = start + q
        r = parent_base + parent[q]
        for c in range(3):
            radiance = albedo[i, c] * irr[i, c]
            if use_gain:
                radiance *= gain[q, c]
            v = factor[q, c] * radiance / max(albedo[r, c], 1e-6)
            irr[r, c] += v if np.isfinite(v) else 0.0
