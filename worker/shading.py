"""Eye paths and their irradiance from a VPL set (Wald et al. 2002 §4).

One eye path per pixel. At the first hit the path is split per BSDF component of a mirror or
glass surface; each branch follows its mirror/glass chain (one randomly chosen component per
later bounce) to the first non-specular surface, the *end point*. The branch with the largest
weight is the pixel's main end point: its reflectance, depth, normal and irradiance go into the
buffers the discontinuity buffer filters. Every other branch's radiance goes into the
unfiltered buffer together with emitters seen along the way.

Path lengths follow Mitsuba's ``max_depth`` (segments): emission seen after s specular bounces
is s+1 segments; light from a VPL of light-path depth d at an end point reached after s
specular bounces is s + 2 + d segments.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common import bsdf
from common.geometry import Geometry
from common.lights import (VPL_AREA, VPL_DIRECTIONAL, VPL_POINT, VPL_SPOT, VPL_SURFACE,
                           LightSampler, luminance, spot_falloff, to_local, to_world)
from common.scene import DIFFUSE, NULL, SPECULAR_KINDS, Scene

from .vpl import VPLSet, concat_surface

PAIR_CHUNK = 1 << 18  # (end point, VPL) pairs evaluated per batch: bounds memory, keeps Embree batches large


@dataclass
class EndPoints:
    pixel: np.ndarray  # (E,) index of the tile pixel
    position: np.ndarray
    ns: np.ndarray
    ng: np.ndarray
    wi: np.ndarray  # (E, 3) towards the previous vertex, local shading frame
    sp: "bsdf.SurfacePoints"
    throughput: np.ndarray  # (E, 3)
    segments: np.ndarray  # (E,) eye segments to reach the point (1 + specular bounces)
    main: np.ndarray  # (E,) bool
    distance: np.ndarray  # (E,) eye-path length to the point

    def __len__(self) -> int:
        return len(self.pixel)


@dataclass
class EyeResult:
    end: EndPoints
    unfiltered: np.ndarray  # (P, 3)
    depth: np.ndarray  # (P,) distance to the main end point or first hit (inf: miss)
    normal: np.ndarray  # (P, 3)


def _allowed(segments: np.ndarray | int, max_depth: int) -> np.ndarray | bool:
    return True if max_depth < 0 else np.asarray(segments) <= max_depth


def trace_eye(scene: Scene, geom: Geometry, lights: LightSampler, origins: np.ndarray,
              dirs: np.ndarray, max_depth: int, specular_depth: int,
              rng: np.random.Generator) -> EyeResult:
    p = len(origins)
    unf = np.zeros((p, 3))
    env = lights.environment()
    depth = np.full(p, np.inf)
    normal = np.zeros((p, 3))
    if max_depth == 0:
        empty = _end_points_empty()
        return EyeResult(empty, unf, depth, normal)
    hits = geom.intersect(origins, dirs)
    v = hits.valid
    unf[~v] += env
    depth[v] = hits.t[v]
    normal[v] = hits.ns[v]
    idx = np.nonzero(v)[0]
    pos, ns, ng = hits.position[v], hits.ns[v], hits.ng[v]
    d = dirs[v]
    cos_front = -np.einsum("ij,ij->i", d, ns)
    unf[idx] += lights.emitted_radiance(hits.emitter[v], cos_front)
    sp = bsdf.gather(scene.materials, hits.material[v], hits.uv[v])
    wi = to_local(-d, ns)
    delta = np.isin(sp.kind, SPECULAR_KINDS)
    nd = np.nonzero(~delta & (sp.kind != NULL))[0]
    ends = [EndPoints(idx[nd], pos[nd], ns[nd], ng[nd], wi[nd], sp.subset(nd),
                      np.ones((len(nd), 3)), np.ones(len(nd), np.int32), np.ones(len(nd), bool),
                      hits.t[v][nd])]
    di = np.nonzero(delta)[0]
    if len(di) and specular_depth > 0 and _allowed(2, max_depth) is not False:
        sp_d = sp.subset(di)
        comps = bsdf.specular_components(sp_d, wi[di], mode="radiance")
        lum = np.stack([np.where(c[2], luminance(c[1]), -1.0) for c in comps], axis=1)
        best = np.argmax(lum, axis=1)
        c_pix, c_pos, c_ng, c_dir, c_thr, c_main, c_dist = [], [], [], [], [], [], []
        for ci, (wo, weight, ok) in enumerate(comps):
            sel = np.nonzero(ok & np.any(weight > 0, axis=1))[0]
            if len(sel) == 0:
                continue
            g = di[sel]
            c_pix.append(idx[g])
            c_pos.append(pos[g])
            c_ng.append(ng[g])
            c_dir.append(to_world(wo[sel], ns[g]))
            c_thr.append(weight[sel])
            c_main.append(best[sel] == ci)
            c_dist.append(hits.t[v][g])
        if c_pix:
            ends.extend(_follow_chains(scene, geom, lights, np.concatenate(c_pix), np.concatenate(c_pos),
                                       np.concatenate(c_ng), np.concatenate(c_dir), np.concatenate(c_thr),
                                       np.concatenate(c_main), np.concatenate(c_dist), unf, env,
                                       max_depth, specular_depth, rng))
    end = _concat_ends(ends)
    m = end.main
    depth[end.pixel[m]] = end.distance[m]
    normal[end.pixel[m]] = end.ns[m]
    return EyeResult(end, unf, depth, normal)


def _follow_chains(scene, geom, lights, pix, pos, ng, dirs, thr, main, dist, unf, env,
                   max_depth, specular_depth, rng) -> list[EndPoints]:
    out = []
    for bounce in range(1, specular_depth + 1):
        if len(pix) == 0:
            break
        seg = bounce + 1  # segments of the path once this ray hits
        o = geom.offset(pos, ng, dirs)
        hits = geom.intersect(o, dirs)
        v = hits.valid
        if _allowed(seg, max_depth) is not False:
            np.add.at(unf, pix[~v], thr[~v] * env)
        pix, thr, main, dirs = pix[v], thr[v], main[v], dirs[v]
        dist = dist[v] + hits.t[v]
        hpos, hns, hng = hits.position[v], hits.ns[v], hits.ng[v]
        if len(pix) == 0:
            break
        if _allowed(seg, max_depth) is not False:
            cos_front = -np.einsum("ij,ij->i", dirs, hns)
            np.add.at(unf, pix, thr * lights.emitted_radiance(hits.emitter[v], cos_front))
        sp = bsdf.gather(scene.materials, hits.material[v], hits.uv[v])
        wi = to_local(-dirs, hns)
        delta = np.isin(sp.kind, SPECULAR_KINDS)
        nd = np.nonzero(~delta & (sp.kind != NULL))[0]
        if len(nd):
            out.append(EndPoints(pix[nd], hpos[nd], hns[nd], hng[nd], wi[nd], sp.subset(nd), thr[nd],
                                 np.full(len(nd), seg, np.int32), main[nd], dist[nd]))
        di = np.nonzero(delta)[0]
        if len(di) == 0 or not (_allowed(seg + 1, max_depth) is not False):
            break
        n = len(di)
        wo, weight, _pdf, _dl = bsdf.sample(sp.subset(di), wi[di], rng.random(n), rng.random((n, 2)),
                                            mode="radiance")
        keep = np.any(weight > 0, axis=1) & np.all(np.isfinite(weight), axis=1)
        di = di[keep]
        pix, thr, main, dist = pix[di], thr[di] * weight[keep], main[di], dist[di]
        dirs = to_world(wo[keep], hns[di])
        pos, ng = hpos[di], hng[di]
    return out


def _end_points_empty() -> EndPoints:
    z = np.zeros((0, 3))
    return EndPoints(np.zeros(0, np.int64), z, z, z, z, bsdf.gather([], np.zeros(0, np.int32), None),
                     z, np.zeros(0, np.int32), np.zeros(0, bool), np.zeros(0))


def _concat_ends(ends: list[EndPoints]) -> EndPoints:
    ends = [e for e in ends if len(e)]
    if not ends:
        return _end_points_empty()
    return EndPoints(
        np.concatenate([e.pixel for e in ends]), np.concatenate([e.position for e in ends]),
        np.concatenate([e.ns for e in ends]), np.concatenate([e.ng for e in ends]),
        np.concatenate([e.wi for e in ends]), concat_surface([e.sp for e in ends]),
        np.concatenate([e.throughput for e in ends]), np.concatenate([e.segments for e in ends]),
        np.concatenate([e.main for e in ends]), np.concatenate([e.distance for e in ends]))


def gather_vpls(geom: Geometry, end: EndPoints, vpls: VPLSet, clamp_d2: float,
                max_depth: int) -> tuple[np.ndarray, np.ndarray]:
    """Light from the VPL set at each end point, split as (albedo, irradiance).

    Radiance toward the eye = albedo · irradiance. For Lambertian end points the albedo is the
    diffuse reflectance and irradiance is E/π; for glossy ones the radiance is evaluated with
    the full BSDF and divided by the BSDF's albedo (a smooth demodulation), so the image-space
    filter blurs lighting, never texture.
    """
    e = len(end)
    albedo = bsdf.albedo(end.sp, end.wi) if e else np.zeros((0, 3))
    irr = np.zeros((e, 3))
    m = len(vpls)
    if e == 0 or m == 0:
        return albedo, irr
    lam = end.sp.kind == DIFFUSE
    # One-sided surfaces only receive on the side the eye sees; twosided ones on either.
    side = np.where(end.wi[:, 2] >= 0, 1.0, -1.0)
    front_ok = end.sp.twosided | (end.wi[:, 2] > 0)
    surf_rows = np.nonzero(vpls.kind == VPL_SURFACE)[0]
    surf_index = np.full(m, -1)
    surf_index[surf_rows] = np.arange(len(surf_rows))
    chunk = max(1, PAIR_CHUNK // m)
    for s in range(0, e, chunk):
        sl = slice(s, min(e, s + chunk))
        irr[sl] = _gather_chunk(geom, end, sl, vpls, surf_index, lam[sl], side[sl], front_ok[sl],
                                clamp_d2, max_depth, albedo[sl])
    return albedo, irr


def _gather_chunk(geom, end, sl, vpls, surf_index, lam, side, front_ok, clamp_d2, max_depth, albedo):
    x = end.position[sl]
    ns = end.ns[sl]
    ng = end.ng[sl]
    n = len(x)
    m = len(vpls)
    kind = vpls.kind
    # Pair arrays: end point i (rows) x VPL j (columns), flattened row-major.
    directional = kind == VPL_DIRECTIONAL
    dvec = vpls.position[None, :, :] - x[:, None, :]
    dvec[:, directional] = -vpls.normal[directional][None, :, :]
    d2 = np.einsum("ijk,ijk->ij", dvec, dvec)
    dist = np.sqrt(d2)
    w = dvec / np.maximum(dist, 1e-300)[:, :, None]
    d2 = np.where(directional[None, :], 1.0, d2)
    # Emission of each VPL toward x (radiant intensity; irradiance for directional).
    emit = np.broadcast_to(vpls.power[None, :, :], (n, m, 3)).copy()
    cos_y = -np.einsum("ijk,jk->ij", w, vpls.normal)
    area = kind == VPL_AREA
    emit[:, area] *= np.maximum(cos_y[:, area], 0.0)[:, :, None]
    spot = kind == VPL_SPOT
    if spot.any():
        emit[:, spot] *= _spot_factor(cos_y[:, spot], vpls, spot)[:, :, None]
    surf = kind == VPL_SURFACE
    if surf.any():
        sj = np.nonzero(surf)[0]
        ssp = vpls.surface
        wo_y = -w[:, sj].reshape(-1, 3)
        ny = np.repeat(vpls.normal[sj][None], n, axis=0).reshape(-1, 3)
        wo_local = to_local(wo_y, ny)
        rep = np.tile(surf_index[sj], n)
        sp_pairs = ssp.subset(rep)
        wi_pairs = vpls.wi_local[sj][np.tile(np.arange(len(sj)), n)]
        f_y = bsdf.eval(sp_pairs, wi_pairs, wo_local, mode="importance").reshape(n, len(sj), 3)
        g = 1.0 / np.maximum(d2[:, sj], clamp_d2)
        emit[:, sj] *= f_y * g[:, :, None]
    # 1/d² for the point-like emitter samples (clamping direct light would bias it).
    pt = area | spot | (kind == VPL_POINT)
    emit[:, pt] /= np.maximum(d2[:, pt], 1e-30)[:, :, None]
    if max_depth >= 0:
        seg = end.segments[sl][:, None] + 1 + vpls.depth[None, :]
        emit *= (seg <= max_depth)[:, :, None]
    # Receiver term at x.
    cos_x = np.einsum("ijk,ik->ij", w, ns) * side[:, None]
    recv = np.zeros((n, m, 3))
    li = np.nonzero(lam & front_ok)[0]
    if len(li):
        # Lambertian: irradiance/π per unit albedo.
        recv[li] = np.maximum(cos_x[li], 0.0)[:, :, None] / np.pi
    gi = np.nonzero(~lam)[0]
    if len(gi):
        wo_x = w[gi].reshape(-1, 3)
        nx = np.repeat(ns[gi], m, axis=0)
        wi_x = np.repeat(end.wi[sl][gi], m, axis=0)
        spx = end.sp.subset(np.repeat(np.arange(sl.start, sl.stop)[gi], m))
        fx = bsdf.eval(spx, wi_x, to_local(wo_x, nx), mode="radiance").reshape(len(gi), m, 3)
        a = np.maximum(albedo[gi], 1e-6)
        recv[gi] = fx / a[:, None, :]
    contrib = emit * recv
    live = np.any(contrib > 0, axis=2) & np.all(np.isfinite(contrib), axis=2)
    ii, jj = np.nonzero(live)
    if len(ii):
        ox = geom.offset(x[ii], ng[ii], w[ii, jj])
        ypos = vpls.position[jj]
        toy = ypos - ox
        # Targets on surfaces are pulled back off their surface toward x.
        on_surface = (kind[jj] == VPL_SURFACE) | (kind[jj] == VPL_AREA)
        ly = np.linalg.norm(toy, axis=1)
        dirn = toy / np.maximum(ly, 1e-300)[:, None]
        tmax = np.where(on_surface, ly - 2 * geom.eps - 8 * np.finfo(np.float32).eps * np.abs(ypos - geom.center).max(axis=1),
                        ly * (1 - 1e-6))
        dj = directional[jj]
        dirn[dj] = w[ii[dj], jj[dj]]
        tmax[dj] = np.inf
        blocked = geom.occluded(ox, dirn, np.maximum(tmax, 0.0))
        live[ii[blocked], jj[blocked]] = False
    contrib *= live[:, :, None]
    return np.nan_to_num(contrib.sum(axis=1), nan=0.0, posinf=0.0, neginf=0.0)


def _spot_factor(cos_y, vpls, spot_mask):
    """Falloff of spot VPLs: cos_y is the cosine to the spot axis (stored in the normal)."""
    # Spot VPLs carry (unused, beam_width, cutoff_angle) in degrees in their wi_local slot.
    params = vpls.wi_local[spot_mask]
    out = np.empty_like(cos_y)
    for j in range(cos_y.shape[1]):
        out[:, j] = spot_falloff(cos_y[:, j], params[j, 2], params[j, 1])
    return out
