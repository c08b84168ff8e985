"""One bounce of the paths that leave the lights (instant radiosity's light walks, caustic
photons: Wald et al. 2002 §4, §4.1), fused: at each hit the BSDF is sampled in importance mode
with the path's own quasi-random numbers, the walk's Russian roulette applied past its bounce
limit, the flux multiplied, the next ray turned to world space and offset off the surface, and
the paths that still carry light listed — one pass instead of a dozen numpy passes per bounce.

The math is the kernels' own (common.kernels.bsdf.sample, shading_frame, hit_surface), applied
in the order of the numpy form it replaced, so the paths are bit-identical to it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point
from igi.common.kernels.ray_packets import closest_surfaces, hit_buffers
from igi.common.kernels.shading_normals import adjoint_correction, incident_ratio
from igi.common.kernels.splitmix import mix64, unit


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per path.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def continue_paths(P, prow, sel, rows, pos, ns, ng, bumped, d, o, flux, u, col, roulette, survival, bounce,
                   center, eps, ulps, out_rows) -> int:
    """For the hits ``j = sel[t]`` (surface parameters at ``P[.][prow[j]]``, position, normals)
    of paths ``r = rows[j]``: sample the BSDF at -d[r] with u[r, col : col + 3] (importance
    mode; on a hit whose normal a normal or bump map perturbed, ``bumped[j]``, its weight corrected
    for the shading normal: common.kernels.shading_normals); with ``roulette``, keep the path with probability q = clip(max weight, 0, 0.95)
    (uniform ``survival[r, bounce]``) and divide by q; flux[r] *= weight; d[r], o[r] = the new
    direction and the offset origin. Paths whose flux still carries light (positive in some
    channel, finite in all) are written to ``out_rows`` in order; returns how many."""
    c = 0
    for t in range(sel.shape[0]):
        j = sel[t]
        r = rows[j]
        nx, ny, nz = ns[j, 0], ns[j, 1], ns[j, 2]
        wix, wiy, wiz = shading_frame.to_local(-d[r, 0], -d[r, 1], -d[r, 2], nx, ny, nz)
        ox, oy, oz, w0, w1, w2, _p, _delta = kb.sample(P, prow[j], wix, wiy, wiz, u[r, col], u[r, col + 1],
                                                       u[r, col + 2], False)
        dx, dy, dz = shading_frame.to_world(ox, oy, oz, nx, ny, nz)
        if bumped[j]:
            a = adjoint_correction(-d[r, 0], -d[r, 1], -d[r, 2], dx, dy, dz, nx, ny, nz, ng[j, 0], ng[j, 1], ng[j, 2])
            w0, w1, w2 = w0 * a, w1 * a, w2 * a
        if roulette:
            q = np.maximum(np.maximum(w0, w1), w2)  # NaN propagates, as numpy's max
            if not math.isnan(q):
                q = min(max(q, 0.0), 0.95)
            if survival[r, bounce] < q:
                s = max(q, 1e-12)
                w0, w1, w2 = w0 / s, w1 / s, w2 / s
            else:
                w0, w1, w2 = 0.0, 0.0, 0.0
        f0 = flux[r, 0] * w0
        f1 = flux[r, 1] * w1
        f2 = flux[r, 2] * w2
        flux[r, 0], flux[r, 1], flux[r, 2] = f0, f1, f2
        d[r, 0], d[r, 1], d[r, 2] = dx, dy, dz
        o[r, 0], o[r, 1], o[r, 2] = offset_point(pos[j, 0], pos[j, 1], pos[j, 2], ng[j, 0], ng[j, 1], ng[j, 2],
                                                 dx, dy, dz, center, eps, ulps)
        if kb.carries(f0, f1, f2):
            out_rows[c] = r
            c += 1
    return c


@njit(cache=True, nogil=True, inline="always")
def _bumped(maps, material) -> bool:
    """Is ``material``'s shading normal perturbed by a normal or bump map (common.bump_mapping's
    table; empty: no map in the scene)? Only there do the light paths take the shading-normal
    corrections: an interpolated normal stands for the smooth surface its mesh approximates."""
    return 0 <= material < maps.shape[0] and maps[material, 0] > 0.0


@njit(cache=True, nogil=True, inline="always")
def _carrying(flux, alive) -> int:
    """The rows whose flux carries light (positive in some channel) into ``alive``; how many."""
    live = 0
    for r in range(flux.shape[0]):
        if flux[r, 0] > 0.0 or flux[r, 1] > 0.0 or flux[r, 2] > 0.0:
            alive[live] = r
            live += 1
    return live


@njit(cache=True, nogil=True, inline="always")
def _closest_hits(closest, o, d, alive, live, bo, bd, hits, rows) -> int:
    """The closest hits of the paths alive[:live] (rays o, d per row) into ``hits``, compacted
    to the valid ones in order, their rows in ``rows``; returns how many."""
    valid, hpos, hng, hns, huv, hmat = hits[4], hits[5], hits[6], hits[7], hits[8], hits[10]
    for t in range(live):
        r = alive[t]
        for a in range(3):
            bo[t, a] = o[r, a]
            bd[t, a] = d[r, a]
    closest_surfaces(closest, bo, bd, live, hits)
    c = 0  # compacted in place (c <= t)
    for t in range(live):
        if valid[t]:
            rows[c] = alive[t]
            hmat[c] = hmat[t]
            for a in range(2):
                huv[c, a] = huv[t, a]
            for a in range(3):
                hpos[c, a] = hpos[t, a]
                hns[c, a] = hns[t, a]
                hng[c, a] = hng[t, a]
            c += 1
    return c


_MIX_WALK = np.uint64(0x9E3779B97F4A7C15)
_MIX_BOUNCE = np.uint64(0xC2B2AE3D27D4EB4F)
_MIX_DIM = np.uint64(0x165667B19E3779F9)


@njit(cache=True, nogil=True, inline="always")
def walk_uniform(key, walk, bounce, dim):
    """A uniform in [0, 1) for number ``dim`` of bounce ``bounce`` of path ``walk`` (a light
    walk, a photon) of the set keyed ``key`` (two splitmix64 rounds): the same in every thread
    and process, drawn only when a path gets that far."""
    z = mix64(np.uint64(key) ^ (np.uint64(walk) * _MIX_WALK))
    return unit(mix64(z ^ (np.uint64(bounce) * _MIX_BOUNCE) ^ (np.uint64(dim + 1) * _MIX_DIM)))


@njit(cache=True, nogil=True)
def roulette_uniforms(keys, walks, first, dims_per_bounce, u_out, s_out) -> None:
    """The Russian-roulette walks' numbers past their quasi-random ones, as arrays (the numpy
    loop's; :func:`trace_walks` draws them as it goes): u_out[r, dims_per_bounce·(b - first) + c]
    = walk_uniform(keys[r], r % walks, b, c) for bounces b >= ``first``, s_out[r, b] the
    bounce's survival uniform (number ``dims_per_bounce``) for every b."""
    for r in range(keys.shape[0]):
        w = r % walks
        for b in range(s_out.shape[1]):
            s_out[r, b] = walk_uniform(keys[r], w, b, dims_per_bounce)
            if b >= first:
                for c in range(dims_per_bounce):
                    u_out[r, dims_per_bounce * (b - first) + c] = walk_uniform(keys[r], w, b, c)


@njit(cache=True, nogil=True, error_model="numpy")
def trace_photons(P, kind, specular, null_kind, closest, o, d, flux, u, max_bounces, emit_dims, bounce_dims, keys,
                  per_set, eps, ulps, out) -> tuple:
    """Caustic photons (worker.caustics) from their emission to where they are stored, in one
    call: the photons whose flux carries light go to Embree in packets (``closest``:
    common.geometry.Geometry.closest_terms), bounce by bounce; a photon that has bounced off a
    mirror or glass (material rows ``specular``) and hits another surface (kind not
    ``null_kind``) is stored — position, flux (on a normal- or bump-mapped surface × |wi·ns| / |wi·ng|:
    common.kernels.shading_normals),
    direction toward where it came from, ns, depth
    b + 1, its row — in ``out`` (in bounce order, then row order); one on a mirror or glass
    surface bounces on (:func:`continue_paths` with u[row, emit_dims + bounce_dims·b …] while u
    has them, then :func:`walk_uniform` of (keys[row], row % per_set)); any other ends. ``o``,
    ``d``, ``flux`` (float64, C order) are overwritten. Returns (photons stored, rays traced)."""
    center = closest[1]
    n = o.shape[0]
    out_p, out_w, out_d, out_n, out_dp, out_src = out
    alive, rows, sel, prow = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    bounced = np.zeros(n, np.bool_)
    bo, bd = np.empty((n, 3)), np.empty((n, 3))
    hits = hit_buffers(n)
    hpos, hng, hns, hmat = hits[5], hits[6], hits[7], hits[10]
    maps = closest[14][2]
    bumped = np.zeros(n, np.bool_)
    null_row = specular.shape[0] - 1
    quasi = (u.shape[1] - emit_dims) // bounce_dims  # bounces with numbers of u
    drawn = np.empty((n, bounce_dims))  # a bounce's numbers past those
    live = _carrying(flux, alive)
    stored, traced = 0, 0
    no_survival = np.zeros((0, 0))
    for b in range(max_bounces + 1):
        if live == 0:
            break
        c = _closest_hits(closest, o, d, alive, live, bo, bd, hits, rows)
        traced += live
        if c == 0:
            break
        spec = 0
        for j in range(c):
            m = hmat[j]
            row = m if 0 <= m < null_row else null_row
            r = rows[j]
            if specular[row]:
                sel[spec] = j
                prow[j] = row
                bumped[j] = _bumped(maps, m)
                spec += 1
            elif bounced[r] and kind[row] != null_kind:
                bump = _bumped(maps, m)
                k = incident_ratio(-d[r, 0], -d[r, 1], -d[r, 2], hns[j, 0], hns[j, 1], hns[j, 2],
                                   hng[j, 0], hng[j, 1], hng[j, 2]) if bump else 1.0
                for a in range(3):
                    out_p[stored, a] = hpos[j, a]
                    out_w[stored, a] = flux[r, a] * k if bump else flux[r, a]
                    out_d[stored, a] = -d[r, a]
                    out_n[stored, a] = hns[j, a]
                out_dp[stored] = b + 1
                out_src[stored] = r
                stored += 1
        # Only mirror/glass bounces continue: anything else is a caustic's end or not a caustic.
        if b == max_bounces or spec == 0:
            break
        for q in range(spec):
            bounced[rows[sel[q]]] = True
        # (typed values, not literals or a global array: either would compile continue_paths once more)
        if b < quasi:
            live = continue_paths(P, prow, sel[:spec], rows, hpos, hns, hng, bumped, d, o, flux, u,
                                  emit_dims + bounce_dims * b, np.bool_(False), no_survival, np.int64(0), center, eps,
                                  ulps, alive)
        else:
            for q in range(spec):
                r = rows[sel[q]]
                for c in range(bounce_dims):
                    drawn[r, c] = walk_uniform(keys[r], r % per_set, b, c)
            live = continue_paths(P, prow, sel[:spec], rows, hpos, hns, hng, bumped, d, o, flux, drawn, np.int64(0),
                                  np.bool_(False), no_survival, np.int64(0), center, eps, ulps, alive)
    return stored, traced


@njit(cache=True, nogil=True, error_model="numpy")
def trace_walks(P, reflects, atlas, closest, o, d, flux, u, max_length, roulette_after, keys, walks, dims_start,
                dims_per_bounce, eps, ulps, out) -> tuple:
    """Instant radiosity's light walks (worker.vpl._light_walks) from emission to their end, in
    one call: the walks whose flux carries light go to Embree in packets (``closest``:
    common.geometry.Geometry.closest_terms) bounce by bounce; every hit on a material row that
    ``reflects`` (not mirror/glass, not NULL, not black) leaves a VPL — position, ns, ng, the walk's flux
    (on a normal- or bump-mapped surface × |wi·ns| / |wi·ng|: common.kernels.shading_normals),
    depth b + 1, wi in its shading frame, material, uv, the walk's row — in ``out`` (bounce
    order, then row order); each hit continues (:func:`continue_paths`, u[row, dims_start +
    dims_per_bounce·b …] while u has them, then :func:`walk_uniform` of (keys[row], row % walks);
    Russian roulette from bounce ``roulette_after`` - 1 on, on walk_uniform number
    ``dims_per_bounce``; none when it is negative) until ``max_length`` bounces. A hit reads its material's row
    of P, or on a material with bitmap textures (``atlas``: common.bsdf.texture_atlas) a row of
    its own past the materials' (P holds room for a bounce's hits) with its texels. ``o``,
    ``d``, ``flux`` (float64, C order) are overwritten. Returns (VPLs, rays traced); (-1, rays)
    where ``out`` was too small."""
    center = closest[1]
    n = o.shape[0]
    out_p, out_n, out_g, out_w, out_dp, out_wi, out_mat, out_uv, out_src = out
    cap = out_dp.shape[0]
    alive, rows, sel, prow = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    bo, bd = np.empty((n, 3)), np.empty((n, 3))
    hits = hit_buffers(n)
    hpos, hng, hns, huv, hmat = hits[5], hits[6], hits[7], hits[8], hits[10]
    maps = closest[14][2]
    bumped = np.zeros(n, np.bool_)
    m = reflects.shape[0] - 1  # the NULL row
    quasi = (u.shape[1] - dims_start) // dims_per_bounce  # bounces with numbers of u
    drawn = np.empty((n, dims_per_bounce))  # a bounce's numbers past those
    survival = np.empty((n, 1))
    live = _carrying(flux, alive)
    stored, traced = 0, 0
    for b in range(max_length):
        if live == 0:
            break
        c = _closest_hits(closest, o, d, alive, live, bo, bd, hits, rows)
        traced += live
        if c == 0:
            break
        for j in range(c):
            mat = hmat[j]
            row = mat if 0 <= mat < m else m
            prow[j] = kb.material_row(P, row, m + 1 + j, atlas, huv[j, 0], huv[j, 1])
            sel[j] = j
            bumped[j] = _bumped(maps, mat)
            if not reflects[row]:
                continue
            if stored == cap:
                return -1, traced
            r = rows[j]
            k = incident_ratio(-d[r, 0], -d[r, 1], -d[r, 2], hns[j, 0], hns[j, 1], hns[j, 2],
                               hng[j, 0], hng[j, 1], hng[j, 2]) if bumped[j] else 1.0
            for a in range(3):
                out_p[stored, a] = hpos[j, a]
                out_n[stored, a] = hns[j, a]
                out_g[stored, a] = hng[j, a]
                out_w[stored, a] = flux[r, a] * k if bumped[j] else flux[r, a]
            out_wi[stored, 0], out_wi[stored, 1], out_wi[stored, 2] = shading_frame.to_local(
                -d[r, 0], -d[r, 1], -d[r, 2], hns[j, 0], hns[j, 1], hns[j, 2])
            out_dp[stored] = b + 1
            out_mat[stored] = mat
            out_uv[stored, 0], out_uv[stored, 1] = huv[j, 0], huv[j, 1]
            out_src[stored] = r
            stored += 1
        if b + 1 >= max_length:
            break
        roulette = roulette_after >= 0 and b + 1 >= roulette_after
        if roulette or b >= quasi:
            for j in range(c):
                r = rows[j]
                survival[r, 0] = walk_uniform(keys[r], r % walks, b, dims_per_bounce) if roulette else 0.0
                if b >= quasi:
                    for q in range(dims_per_bounce):
                        drawn[r, q] = walk_uniform(keys[r], r % walks, b, q)
        if b < quasi:
            live = continue_paths(P, prow, sel[:c], rows, hpos, hns, hng, bumped, d, o, flux, u,
                                  dims_start + dims_per_bounce * b, np.bool_(roulette), survival, np.int64(0), center,
                                  eps, ulps, alive)
        else:
            live = continue_paths(P, prow, sel[:c], rows, hpos, hns, hng, bumped, d, o, flux, drawn, np.int64(0),
                                  np.bool_(roulette), survival, np.int64(0), center, eps, ulps, alive)
    return stored, traced
