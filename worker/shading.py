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

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.microfacet import lerp_gather
from igi.common.lights import (VPL_AREA, VPL_DIRECTIONAL, VPL_SPOT, VPL_SURFACE, LightSampler, luminance,
                               rays_meet_spheres, to_local, to_world)
from igi.common.scene import (DIFFUSE, NULL, PLASTIC, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHDIELECTRIC_R,
                              ROUGHDIELECTRIC_T, ROUGHPLASTIC, ROUGHPLASTIC_DIFFUSE, ROUGHPLASTIC_LOBE, SPECULAR_KINDS,
                              Scene, kind_in)

from .kernels import bsdf_direct as kbd
from .kernels import bsdf_rays as br
from .kernels import eye_paths as ek
from .kernels import specular_chain as sc
from .kernels import vpl_gather as vg
from .kernels import vpl_scoring as vs
from .regularization import regularization_gain, regularized_senders
from .vpl import VPLSet, concat_surface, subset_vpls

PAIR_CHUNK = 1 << 17  # (end point, VPL) pairs per kernel call: bounds memory, keeps Embree batches large


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
    # (E,) bool or None: the point takes emitter samples only — a smooth glossy lobe's light
    # sampling, MIS-weighted against the lobe's traced ray (its radiance stays unfiltered)
    direct_only: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.pixel)

    def subset(self, rows) -> "EndPoints":
        rows = bsdf.row_selector(rows, len(self))
        return EndPoints(*(None if v is None else (v.subset(rows) if f.name == "sp" else bsdf.take_rows(v, rows))
                           for f in _END_FIELDS for v in (getattr(self, f.name),)))

    @staticmethod
    def concat(parts: "list[EndPoints]") -> "EndPoints":
        """The end points of ``parts`` in order (``pixel`` as each part had it)."""
        out = {f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in _END_FIELDS
               if f.name not in ("sp", "direct_only")}
        out["sp"] = concat_surface([p.sp for p in parts])
        out["direct_only"] = None
        if any(p.direct_only is not None for p in parts):
            out["direct_only"] = np.concatenate([np.zeros(len(p), bool) if p.direct_only is None else p.direct_only
                                                 for p in parts])
        return EndPoints(**out)

    def vpl_depth_limit(self, max_depth: int) -> np.ndarray:
        """(E,) the deepest VPL each point may take: a VPL of light-path depth d lights a path
        of segments + 1 + d segments; 0 (emitter samples) for direct-only points."""
        big = np.iinfo(np.int64).max // 2
        lim = (max_depth - 1 - self.segments.astype(np.int64)) if max_depth >= 0 else np.full(len(self), big)
        if self.direct_only is not None:
            lim = np.where(self.direct_only, np.minimum(lim, 0), lim)
        return lim


_END_FIELDS = fields(EndPoints)


@dataclass
class EyeResult:
    end: EndPoints
    unfiltered: np.ndarray  # (P, 3)
    depth: np.ndarray  # (P,) distance to the main end point or first hit (inf: miss)
    normal: np.ndarray  # (P, 3)


def _allowed(segments: int, max_depth: int) -> bool:
    """May a path of ``segments`` segments contribute under Mitsuba's max_depth?"""
    return max_depth < 0 or int(segments) <= max_depth


@dataclass
class LightMIS:
    """The set's emitter sampling, for weighting emission that a sampled glossy-lobe ray hits
    against the lobe's own light samples (``direct_count`` emitter samples per set, the
    environment's guided pdf when the set has one)."""

    direct_count: int
    env_guide: object = None
    emitter_pmf: np.ndarray | None = None  # the samples' emitter choice (None: lights.pmf)


def trace_eye(scene: Scene, geom: Geometry, lights: LightSampler, origins: np.ndarray,
              dirs: np.ndarray, max_depth: int, specular_depth: int,
              rng: np.random.Generator, glossy_split_alpha: float = 0.0,
              light_mis: LightMIS | None = None) -> EyeResult:
    """``glossy_split_alpha``: rough conductors and plastics smoother than this are split at
    the first hit per BSDF component (paper §4): the plastic's diffuse layer is an end point
    (filtered irradiance), the glossy lobe is followed by one sampled ray like a mirror chain,
    so VPLs never light a near-specular lobe (no spikes, no interleaving pattern).

    ``light_mis``: the lobe also takes the set's emitter samples (a direct-only end point, its
    lobe evaluated per sample) and the emission its ray hits is MIS-weighted against them, so
    a small bright light seen in a smooth floor is not a firefly (without: the ray alone)."""
    p = len(origins)
    unf = np.zeros((p, 3))
    env = lights.environment()
    depth = np.full(p, np.inf)
    normal = np.zeros((p, 3))
    if max_depth == 0:
        empty = _end_points_empty()
        return EyeResult(empty, unf, depth, normal)
    compiled = _compiled_eye(scene, geom, lights, origins, dirs, max_depth, specular_depth, rng, glossy_split_alpha,
                             light_mis)
    if compiled is not None:
        return compiled
    hits = geom.intersect(origins, dirs)
    v = hits.valid
    idx, d = np.arange(p), dirs
    t_hit = hits.t  # (inf where a ray missed)
    depth[:] = t_hit
    pos, ns, ng = hits.position, hits.ns, hits.ng
    normal[:] = ns
    if not v.all():
        # Misses keep their rows (material -1: the NULL kind, so no end point or chain starts
        # there): one copy of the per-hit arrays less than dropping them first.
        miss = ~v
        unf[miss] += lights.environment_radiance(d[miss])
        normal[miss] = 0.0
    lit = np.flatnonzero(hits.emitter >= 0)  # emission seen directly (the rest would add 0)
    if len(lit):
        cos_front = -np.einsum("ij,ij->i", d[lit], ns[lit])
        unf[idx[lit]] += lights.emitted_radiance(hits.emitter[lit], cos_front)
    sp = bsdf.gather(scene.materials, hits.material, hits.uv)
    wi = to_local(-d, ns)
    delta = kind_in(sp.kind, SPECULAR_KINDS)
    nd_mask = ~delta & (sp.kind != NULL)
    lobe = np.zeros(0, np.int64)
    if specular_depth > 0 and _allowed(2, max_depth):
        sp, lobe, lobe_sp, nd_mask = _split_smooth(sp, nd_mask, glossy_split_alpha)
    if nd_mask.all():  # the common case: no copies of the per-hit arrays
        n_all = len(idx)
        ends = [EndPoints(idx, pos, ns, ng, wi, sp, np.ones((n_all, 3)), np.ones(n_all, np.int32),
                          np.ones(n_all, bool), t_hit)]
    else:
        nd = np.nonzero(nd_mask)[0]
        ends = [EndPoints(idx[nd], pos[nd], ns[nd], ng[nd], wi[nd], sp.subset(nd),
                          np.ones((len(nd), 3)), np.ones(len(nd), np.int32), np.ones(len(nd), bool),
                          t_hit[nd])]
    di = np.nonzero(delta)[0]
    # (pixel, origin, ng, direction, throughput, main, distance, lobe pdf or 0: no MIS) per batch
    branches: list[tuple] = []

    def branch(g: np.ndarray, wo_local: np.ndarray, weight: np.ndarray, main: np.ndarray,
               mis_pdf: np.ndarray | None = None) -> None:
        mis_pdf = np.zeros(len(g)) if mis_pdf is None else mis_pdf
        branches.append((idx[g], pos[g], ng[g], to_world(wo_local, ns[g]), weight, main, t_hit[g], mis_pdf))

    if len(lobe):
        # The glossy lobe: one sampled ray, its radiance unfiltered (the pixel's main end
        # point, if any, is the plastic's diffuse layer).
        wo, weight, pdf, lit, lobe_end = _sample_lobe(lobe_sp, wi[lobe], rng, light_mis)
        if lobe_end is not None:
            lr = lobe[lit]
            ends.append(_lobe_light_points(idx[lr], pos[lr], ns[lr], ng[lr], wi[lr], lobe_end,
                                           np.ones((len(lr), 3)), 1, t_hit[lr]))
        sel = np.nonzero(np.any(weight > 0, axis=1))[0]
        branch(lobe[sel], wo[sel], weight[sel], np.zeros(len(sel), bool), pdf[sel])
    chains = len(di) and specular_depth > 0 and _allowed(2, max_depth)
    # rough glass: its light-sample points (design note 48; kernels.eye_paths._glass_lobe)
    glass = np.zeros(len(di), bool)
    if chains and light_mis is not None and light_mis.direct_count > 0:
        glass = sp.kind[di] == ROUGHDIELECTRIC
        g = di[glass]
        ends.extend(_glass_light_points(idx[g], pos[g], ns[g], ng[g], wi[g], sp.subset(g), np.ones((len(g), 3)), 1,
                                        t_hit[g]))
    if chains:
        sp_d = sp.subset(di)
        # (a rough dielectric's microfacet normals, drawn only where there is one, as the kernel)
        u_m = rng.random((len(di), 2)) if (sp_d.kind == ROUGHDIELECTRIC).any() else None
        comps = bsdf.specular_components(sp_d, wi[di], mode="radiance", u2=u_m)
        lum = np.stack([np.where(c[2], luminance(c[1]), -1.0) for c in comps], axis=1)
        best = np.argmax(lum, axis=1)
        for ci, (wo, weight, ok) in enumerate(comps):
            sel = np.nonzero(ok & np.any(weight > 0, axis=1))[0]
            if len(sel):
                branch(di[sel], wo[sel], weight[sel], best[sel] == ci, _glass_mis(sp_d, wi[di], wo, sel, glass))
    if branches:
        cat = [np.concatenate(col) for col in zip(*branches)]
        ends.extend(_follow_chains(scene, geom, lights, *cat, unf, env, max_depth, specular_depth, rng,
                                   glossy_split_alpha, light_mis))
    end = _concat_ends(ends)
    # The first hits' end points (ends[0], all main) hold the depth and normal written above;
    # the chains' main end points replace their pixels' first hits.
    tail = slice(len(ends[0]), None)
    m = np.flatnonzero(end.main[tail]) + len(ends[0])
    depth[end.pixel[m]] = end.distance[m]
    normal[end.pixel[m]] = end.ns[m]
    return EyeResult(end, unf, depth, normal)


_NO_DENSITY = np.zeros(0)  # (an unguided sky: the kernel takes the environment's pdf)


def _compiled_eye(scene, geom, lights, origins, dirs, max_depth, specular_depth, rng, glossy_split_alpha,
                  light_mis) -> EyeResult | None:
    """:func:`trace_eye` in one compiled call (kernels.eye_paths.trace_eye: the same rays, draws,
    end points and per-pixel buffers as its numpy form), or None where that form must run: the
    rays must go through Geometry.intersect (closest_terms), or a mirror/glass or split smooth
    glossy material takes its specular or transmittance colour from a bitmap
    (common.bsdf.chain_materials)."""
    terms = geom.closest_terms()
    tables = bsdf.chain_materials(scene.materials, glossy_split_alpha) if terms is not None else None
    if tables is None:
        return None
    P, kind, specular, smooth, P_lobe = tables
    env = np.ascontiguousarray(lights.environment(), np.float64)
    split = bool(smooth.any())
    count = int(light_mis.direct_count) if light_mis is not None and light_mis.direct_count > 0 else 0
    sky = bool(np.any(env > 0))
    pmf = light_mis.emitter_pmf if light_mis is not None else None
    area_pdf = np.append(lights.area_pdf(np.arange(len(scene.emitters)), pmf), 0.0)
    # the sky's pdf along an escaping lobe ray (emitter_pdf): the environment's, or its guide's
    # pmf × q(ω) (q from the guide's histogram, per direction in the kernel)
    guide = light_mis.env_guide if sky and light_mis is not None else None
    if not sky:
        env_pdf = 0.0
    elif guide is not None:
        env_pdf = float(guide.pmf)
    elif lights.env_map is not None:  # the kernel takes the map's pdf per direction
        env_pdf = float((lights.pmf if pmf is None else pmf)[lights.env_index])
    else:
        env_pdf = float(lights.environment_pdf(pmf))
    density = np.ascontiguousarray(guide.density, np.float64) if guide is not None else _NO_DENSITY
    lobes = (split, smooth, P_lobe, count, area_pdf, env_pdf, density, lights.env_tables)
    p = len(origins)
    unf, depth, normal = np.zeros((p, 3)), np.empty(p), np.empty((p, 3))
    # room enough unless chains keep meeting smooth glossy surfaces (then: the numpy form); rough
    # glass adds a light-sample point a hit (a ball of it over every pixel: 4 end points a pixel,
    # more with its inner reflections)
    n = (6 if np.any(kind == ROUGHDIELECTRIC) else 3) * p
    ends = (np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty(n, np.int32), np.empty((n, 2)), np.empty((n, 3)), np.empty(n, np.int32), np.empty(n, bool),
            np.empty(n), np.empty(n, np.int8))
    _center, eps, ulps = geom.offset_terms()
    c = np.ascontiguousarray
    state = rng.bit_generator.state
    done, traced = ek.trace_eye(P, kind, specular, NULL, rng, terms, c(origins, np.float64), c(dirs, np.float64),
                                int(specular_depth), int(max_depth), eps, ulps, env, lights.area_radiance, lobes, unf,
                                depth, normal, ends)
    if done < 0:
        rng.bit_generator.state = state  # the numpy form draws them again
        return None
    geom.counters["intersect_rays"] += traced
    pix, pos, ns, ng, wi, mat, uv, thr, seg, main, dist, code = (a[:done] for a in ends)
    sp = bsdf.gather(scene.materials, mat, uv)
    direct_only = None
    if code.any():  # split smooth glossy hits: plastics' diffuse layers, the lobes' light-sample points
        lobe_lights = code == ek.LOBE_LIGHTS
        sp = bsdf.split_layer(sp, code == ek.LAYER)
        rp = lobe_lights & (sp.kind == ROUGHPLASTIC)
        if rp.any():
            sp = sp.replaced(kind=np.where(rp, ROUGHPLASTIC_LOBE, sp.kind).astype(sp.kind.dtype))
        glass = code == ek.GLASS_LIGHTS
        if glass.any():  # rough glass's light-sample points, through the lobe facing out
            sp = bsdf.glass_lobes(sp, bsdf.outward_lobe(wi), glass)
            lobe_lights = lobe_lights | glass
        direct_only = lobe_lights if lobe_lights.any() else None
    end = EndPoints(pix, pos, ns, ng, wi, sp, thr, seg, main, dist, direct_only)
    return EyeResult(end, unf, depth, normal)


def _sample_lobe(lobe_sp, wi, rng, light_mis):
    """One sampled ray of each smooth lobe: ``(wo, weight, pdf for MIS (0: none), the rows that
    take the set's emitter samples, their lobes' direct-only end-point BSDFs)``, the last None
    where none do. A smooth plastic's coat is a mirror: no MIS, no light samples."""
    wo, weight = bsdf.sample_lobe(lobe_sp, wi, rng.random((len(wi), 2)))
    if light_mis is None or light_mis.direct_count <= 0:
        return wo, weight, np.zeros(len(wi)), None, None
    lobe_end = bsdf.lobe_only(lobe_sp)
    pdf = bsdf.pdf(lobe_end, wi, wo)
    mirror = lobe_sp.kind == PLASTIC
    pdf[mirror] = 0.0
    lit = np.flatnonzero(~mirror)
    return wo, weight, pdf, lit, (lobe_end.subset(lit) if len(lit) else None)


def _lobe_light_points(pix, pos, ns, ng, wi, lobe_end, thr, segments: int, dist) -> EndPoints:
    """The end points through which split lobes take the set's emitter samples: direct-only,
    never the pixel's main end point (their radiance is unfiltered)."""
    n = len(pix)
    return EndPoints(pix, pos, ns, ng, wi, lobe_end, thr, np.full(n, segments, np.int32),
                     np.zeros(n, bool), dist, np.ones(n, bool))


def _mis_emission(lights, hits, valid, dirs, mis_pdf, light_mis) -> np.ndarray:
    """(n,) MIS weight of the emission (or environment, where not ``valid``) that rays with
    sampling pdf ``mis_pdf`` hit, against the set's emitter samples; 1 where mis_pdf is 0."""
    w = np.ones(len(dirs))
    if light_mis is None or not np.any(mis_pdf > 0):
        return w
    pl = emitter_pdf(lights, hits, valid, dirs, light_mis)
    m = mis_pdf > 0
    w[m] = mis_pdf[m] ** 2 / np.maximum(mis_pdf[m] ** 2 + pl[m] ** 2, 1e-300)
    return w


def emitter_pdf(lights: LightSampler, hits, valid: np.ndarray, dirs: np.ndarray,
                light_mis: LightMIS) -> np.ndarray:
    """(n,) solid-angle density with which the set's ``direct_count`` emitter samples pick what
    each ray hits: the emitter at a valid hit, the environment along a miss."""
    pl = np.zeros(len(dirs))
    if valid.any():
        cos_front = -np.einsum("ij,ij->i", dirs[valid], hits.ns[valid])
        pl[valid] = (lights.area_pdf(hits.emitter[valid], light_mis.emitter_pmf) * hits.t[valid] ** 2
                     / np.maximum(np.abs(cos_front), 1e-7))
    miss = ~valid
    if miss.any() and np.any(lights.environment() > 0):
        pl[miss] = sky_pdf(lights, light_mis, dirs[miss])
    return pl * light_mis.direct_count


def sky_pdf(lights: LightSampler, light_mis: LightMIS, dirs: np.ndarray) -> np.ndarray | float:
    """Density with which one of the set's emitter samples picks the sky along unit ``dirs``:
    its guide's pmf × q(ω) where the set's sky samples are guided, else the environment's pdf
    (the compiled eye paths take the same two: worker.shading._compiled_eye)."""
    g = light_mis.env_guide
    return g.pmf * g.pdf(dirs) if g is not None else lights.environment_pdfs(dirs, light_mis.emitter_pmf)


def _follow_chains(scene, geom, lights, pix, pos, ng, dirs, thr, main, dist, mis_pdf, unf, env,
                   max_depth, specular_depth, rng, glossy_split_alpha=0.0,
                   light_mis: LightMIS | None = None) -> list[EndPoints]:
    out = []
    sky = bool(np.any(env != 0))  # (asked once: np.any costs ~8 µs, and this loop runs per bounce and tile)
    for bounce in range(1, specular_depth + 1):
        if len(pix) == 0:
            break
        seg = bounce + 1  # segments of the path once this ray hits
        if bounce == 1:  # (later bounces' origins come offset from delta_bounce)
            o = geom.offset(pos, ng, dirs)
        hits = geom.intersect(o, dirs)
        v = hits.valid
        if _allowed(seg, max_depth):
            # Only rays that meet an emitter, or leave the scene under a sky, see light (misses
            # first, then hits: each pixel's sum in the order it always had).
            lit = np.flatnonzero(v & (hits.emitter >= 0))
            if sky:
                lit = np.concatenate([np.flatnonzero(~v), lit])
            if len(lit):
                lh, lv, ld = hits.rows(lit), v[lit], dirs[lit]
                w_mis = _mis_emission(lights, lh, lv, ld, mis_pdf[lit], light_mis)
                le = np.zeros((len(lit), 3))
                le[~lv] = lights.environment_radiance(ld[~lv])
                if lv.any():
                    le[lv] = lights.emitted_radiance(lh.emitter[lv], -np.einsum("ij,ij->i", ld[lv], lh.ns[lv]))
                np.add.at(unf, pix[lit], thr[lit] * le * w_mis[:, None])
        # Misses keep their rows (material -1: the NULL kind ends them below), one copy of the
        # per-ray and per-hit arrays less per bounce than dropping them here.
        dist = dist + hits.t
        hpos, hns, hng = hits.position, hits.ns, hits.ng
        sp = bsdf.gather(scene.materials, hits.material, hits.uv)
        wi = to_local(-dirs, hns)
        delta = kind_in(sp.kind, SPECULAR_KINDS)
        nd_mask = ~delta & (sp.kind != NULL)
        # Smooth glossy surfaces along a chain are split as at the first hit: a plastic's diffuse
        # layer ends the path (VPL-lit), the lobe continues the chain by one sampled ray.
        sp, lobe, lobe_sp, nd_mask = _split_smooth(sp, nd_mask, glossy_split_alpha, bsdf.split_eligible(sp.kind, thr))
        nd = np.nonzero(nd_mask)[0]
        if len(nd):
            out.append(EndPoints(pix[nd], hpos[nd], hns[nd], hng[nd], wi[nd], sp.subset(nd), thr[nd],
                                 np.full(len(nd), seg, np.int32), main[nd], dist[nd]))
        di = np.nonzero(delta)[0]
        if (len(di) == 0 and len(lobe) == 0) or not _allowed(seg + 1, max_depth):
            break
        glass = np.zeros(len(sp), bool)
        if light_mis is not None and light_mis.direct_count > 0:  # rough glass's light-sample points
            glass[di] = sp.kind[di] == ROUGHDIELECTRIC
            g = np.flatnonzero(glass)
            out.extend(_glass_light_points(pix[g], hpos[g], hns[g], hng[g], wi[g], sp.subset(g), thr[g], seg, dist[g]))
        # the delta vertices' rays in one compiled pass; the split lobes' (rare) after them
        src, thr_d, _seg, dirs_d, o_d = delta_bounce(scene.materials, geom, di, hpos, hns, hng, dirs, thr, None,
                                                     hits.material, hits.uv, -1, rng, delta_only=False)
        mis_d = np.zeros(len(src))
        if glass.any():
            mis_d = _glass_mis(sp.subset(src), wi[src], to_local(dirs_d, hns[src]), np.arange(len(src)), glass[src])
        if len(lobe):
            lobe_main = main[lobe] & ~nd_mask[lobe]  # a plastic's layer keeps the pixel's main end point
            wo_l, weight_l, pdf_l, lit, lobe_end = _sample_lobe(lobe_sp, wi[lobe], rng, light_mis)
            if lobe_end is not None:
                lr = lobe[lit]
                out.append(_lobe_light_points(pix[lr], hpos[lr], hns[lr], hng[lr], wi[lr], lobe_end,
                                              thr[lr], seg, dist[lr]))
            kl = np.flatnonzero(bsdf.carrying(weight_l))
            src_l = lobe[kl]
            dirs_l = to_world(wo_l[kl], hns[src_l])
            main = np.concatenate([main[src], lobe_main[kl]])
            mis_pdf = np.concatenate([mis_d, pdf_l[kl]])
            thr = np.concatenate([thr_d, thr[src_l] * weight_l[kl]])
            o = np.concatenate([o_d, geom.offset(hpos[src_l], hng[src_l], dirs_l)])
            dirs = np.concatenate([dirs_d, dirs_l])
            src = np.concatenate([src, src_l])
        else:
            main, mis_pdf, thr, o, dirs = main[src], mis_d, thr_d, o_d, dirs_d
        pix, dist = pix[src], dist[src]
    return out


def _glass_light_points(pix, pos, ns, ng, wi, sp, thr, segments: int, dist) -> list[EndPoints]:
    """Rough glass hits' light-sample points (kernels.eye_paths._glass_lobe): each through its
    lobe that faces the outside (bsdf.outward_lobe)."""
    if len(pix) == 0:
        return []
    return [_lobe_light_points(pix, pos, ns, ng, wi, bsdf.glass_lobes(sp, bsdf.outward_lobe(wi)), thr, segments,
                               dist)]


def _glass_mis(sp: "bsdf.SurfacePoints", wi: np.ndarray, wo: np.ndarray, sel: np.ndarray,
               glass: np.ndarray) -> np.ndarray:
    """The MIS pdf of the rays ``sel`` sampled at points ``sp`` (local ``wi``, ``wo``): where a
    rough glass point takes light samples (``glass``) and the ray leaves through the lobe they
    take (wo's z > 0: bsdf.outward_lobe), that lobe's pdf; 0 (no MIS) elsewhere."""
    mis = np.zeros(len(sel))
    lit = np.flatnonzero(glass[sel] & (wo[sel, 2] > 0))
    if len(lit):
        q = sel[lit]
        mis[lit] = bsdf.pdf(bsdf.glass_lobes(sp.subset(q), bsdf.outward_lobe(wi[q])), wi[q], wo[q])
    return mis


def delta_bounce(materials: list, geom: Geometry, src: np.ndarray, pos: np.ndarray, ns: np.ndarray, ng: np.ndarray,
                 d: np.ndarray, thr: np.ndarray, seg: np.ndarray | None, mat: np.ndarray, uv: np.ndarray,
                 max_depth: int, rng: np.random.Generator, delta_only: bool = True) -> tuple:
    """One bounce of mirror/glass chains (worker.kernels.specular_chain): the vertices ``src``
    of the per-vertex arrays (position, normals, arrival direction ``d``, throughput, segments,
    material, uv) sample their BSDF with ``rng`` (u1 for all, then u2); the delta samples that
    carry light within ``max_depth`` come back as the next rays, in order:
    ``(src, throughput, segments, directions, offset origins)``. ``seg`` None: not counted
    (segments come back 1). ``delta_only`` False: a non-delta sample that carries light is kept
    too (chains sample only pure delta kinds, whose samples are all delta or failed)."""
    n = len(src)
    u1, u2 = rng.random(n), rng.random((n, 2))
    P, prow = bsdf.packed_rows(bsdf.gather(materials, mat, uv))
    if seg is None:
        seg = np.zeros(len(pos), np.int64)
    out_src, out_seg = np.empty(n, np.int64), np.empty(n, np.int64)
    out_thr, out_d, out_o = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    a = np.ascontiguousarray
    c = sc.delta_bounce(P, prow, a(src, np.int64), a(pos, np.float64), a(ns, np.float64), a(ng, np.float64),
                        a(d, np.float64), a(thr, np.float64), a(seg, np.int64), u1, u2, int(max_depth),
                        bool(delta_only), *geom.offset_terms(), out_src, out_thr, out_seg, out_d, out_o)
    return out_src[:c], out_thr[:c], out_seg[:c], out_d[:c], out_o[:c]


def _split_smooth(sp, nd_mask: np.ndarray, alpha: float, eligible: np.ndarray | None = None):
    """The per-component split of smooth glossy hits (bsdf.split_smooth: rough conductors and
    plastics smoother than ``alpha``, smooth plastics): ``(sp with the plastics reduced to their
    diffuse layer (bsdf.split_layer), lobe rows, their whole BSDFs for sampling the lobe, end-point
    mask without the conductors)``; ``eligible`` (along chains: bsdf.split_eligible) the rows that
    may split."""
    none = np.zeros(0, np.int64)
    if alpha <= 0:
        return sp, none, None, nd_mask
    smooth = bsdf.split_smooth(sp.kind, sp.alpha, alpha)
    if eligible is not None:
        smooth &= eligible
    if not smooth.any():
        return sp, none, None, nd_mask
    lobe = np.nonzero(smooth)[0]
    lobe_sp = sp.subset(lobe)  # the whole BSDF, for sampling the lobe
    return bsdf.split_layer(sp, smooth), lobe, lobe_sp, nd_mask & ~(smooth & (sp.kind == ROUGHCONDUCTOR))


def _end_points_empty() -> EndPoints:
    z = np.zeros((0, 3))
    return EndPoints(np.zeros(0, np.int64), z, z, z, z, bsdf.gather([], np.zeros(0, np.int32), None),
                     z, np.zeros(0, np.int32), np.zeros(0, bool), np.zeros(0))


def _concat_ends(ends: list[EndPoints]) -> EndPoints:
    ends = [e for e in ends if len(e)]
    if not ends:
        return _end_points_empty()
    if len(ends) == 1 and ends[0].direct_only is None:
        return ends[0]
    direct = None
    if any(e.direct_only is not None for e in ends):
        direct = np.concatenate([np.zeros(len(e), bool) if e.direct_only is None else e.direct_only
                                 for e in ends])
    return EndPoints(
        np.concatenate([e.pixel for e in ends]), np.concatenate([e.position for e in ends]),
        np.concatenate([e.ns for e in ends]), np.concatenate([e.ng for e in ends]),
        np.concatenate([e.wi for e in ends]), concat_surface([e.sp for e in ends]),
        np.concatenate([e.throughput for e in ends]), np.concatenate([e.segments for e in ends]),
        np.concatenate([e.main for e in ends]), np.concatenate([e.distance for e in ends]), direct)


def lobe_light_count(vpls: VPLSet, samples: int) -> int:
    """How many of the set's emitter samples a split lobe's direct-only end point takes: the
    first ``samples`` (0: all). All of them where the set's emitter samples are not its first
    ``direct_count`` VPLs (then no subset is drawn)."""
    n = int(vpls.direct_count)
    if samples <= 0 or samples >= n or not np.array_equal(np.nonzero(vpls.depth == 0)[0], np.arange(n)):
        return n
    return int(samples)


def _lobe_light_set(vpls: VPLSet, count: int) -> VPLSet:
    """The first ``count`` emitter samples of the set as a set of their own (powers × N/count,
    direct_count = count): an unbiased estimate from fewer samples whose MIS weights use the
    samples actually taken."""
    scale = np.full(len(vpls), vpls.direct_count / count)
    return replace(subset_vpls(vpls, np.arange(count), scale), direct_count=count)


def gather_vpls(geom: Geometry, end: EndPoints, vpls: VPLSet, clamp_d2: float,
                max_depth: int, force_general: bool = False,
                lobe_alpha: float = 0.0, shadow_roulette: float = 0.0,
                seed: int = 0, lobe_lights: int = 0, pixel: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Light from the VPL set at each end point, split as (albedo, irradiance).

    Radiance toward the eye = albedo · irradiance. For Lambertian end points the albedo is the
    diffuse reflectance and irradiance is E/π; for glossy ones the radiance is evaluated with
    the full BSDF and divided by the BSDF's albedo (a smooth demodulation), so the image-space
    filter blurs lighting, never texture. ``lobe_alpha``: glossy VPLs radiate through lobes at
    least this rough (:func:`regularized_senders`). ``shadow_roulette`` > 0: Russian roulette
    on the shadow rays of small pairs (kernels.vpl_gather.roulette_row), drawn from ``seed``.
    ``lobe_lights``: the emitter samples the direct-only end points take (:func:`lobe_light_count`;
    0: all of the set's; trace_eye's LightMIS must name the same count). ``pixel`` (E,): the
    pixel each end point lights (-1: none of those given): the shadow roulette weighs a pixel's
    end points together (:func:`_pixel_boost`) — within each of the two gathers when the
    direct-only points take fewer emitter samples than the set has (then a lobe's point is alone).
    """
    e = len(end)
    if 0 < lobe_lights < vpls.direct_count and end.direct_only is not None and end.direct_only.any():
        own = np.nonzero(~end.direct_only)[0]
        lobe = np.nonzero(end.direct_only)[0]
        kw = dict(force_general=force_general, lobe_alpha=lobe_alpha, shadow_roulette=shadow_roulette)
        a1, i1 = gather_vpls(geom, end.subset(own), vpls, clamp_d2, max_depth, seed=seed,
                             pixel=None if pixel is None else pixel[own], **kw)
        a2, i2 = gather_vpls(geom, end.subset(lobe), _lobe_light_set(vpls, lobe_lights), clamp_d2, max_depth,
                             seed=seed + 1, pixel=None if pixel is None else pixel[lobe], **kw)
        albedo, irr = np.empty((e, 3)), np.empty((e, 3))
        albedo[own], irr[own], albedo[lobe], irr[lobe] = a1, i1, a2, i2
        return albedo, irr
    albedo = bsdf.albedo(end.sp, end.wi).astype(np.float64) if e else np.zeros((0, 3))
    irr = np.zeros((e, 3))
    m = len(vpls)
    if e == 0 or m == 0:
        return albedo, irr
    cols = vpl_columns(vpls, geom, clamp_d2, force_general, lobe_alpha)
    roulette = (float(shadow_roulette), int(seed)) if shadow_roulette > 0 else None
    receivers = _Receivers(end, albedo)
    if not _gather_packets(geom, end, cols, max_depth, roulette, receivers, irr, pixel):
        _gather_pairs(geom, end, vpls, cols, max_depth, receivers, roulette, irr, pixel)
    return albedo, irr


_NO_ROWS = np.zeros(0, bool)


def _gather_pairs(geom: Geometry, end: EndPoints, vpls: VPLSet, cols: "_VPLColumns", max_depth: int,
                  receivers: "_Receivers", roulette: tuple | None, irr: np.ndarray,
                  pixel: np.ndarray | None = None) -> None:
    """The gather's irradiance into ``irr`` through pair lists (kernels.vpl_gather steps 1-3
    apart), PAIR_CHUNK pairs at a time: where the shadow rays must pass through
    Geometry.occluded_local (see :func:`_gather_packets`)."""
    e = len(end)
    boost = _pixel_boost(geom, end, cols, max_depth, receivers, roulette, pixel)
    for sl in _chunks(e, len(vpls)):
        pi, pj, w, blocked, factor, inner = _unoccluded_pairs(geom, end, sl, vpls, cols, max_depth, receivers,
                                                              roulette, boost=boost[sl] if len(boost) else boost)
        vg.accumulate(sl.stop - sl.start, pi, pj, w, blocked, cols.color, factor,
                      inner if len(cols.planes) else _NO_ROWS, irr[sl])


def _gather_packets(geom: Geometry, end: EndPoints, cols: "_VPLColumns", max_depth: int, roulette: tuple | None,
                    receivers: "_Receivers", irr: np.ndarray, pixel: np.ndarray | None = None) -> bool:
    """The gather fused with its shadow rays (kernels.vpl_gather.gather_packets) into ``irr``,
    with the per-pair BSDF factors of glossy receivers and senders where there are any; False
    where the shadow BVH is not queried in packets from compiled code (no C API, or a
    benchmark timing or recording the rays): nothing done then."""
    scene = geom.packet_handle()
    if scene is None:
        return False
    x, ns, ng, side, off, row, tables, row_tab, inv_tavg = _receivers(geom, end, slice(0, len(end)))
    factors = None
    if cols.glossy.any() or np.any(row == vg.ROW_GLOSSY):
        P_end, end_row = receivers.packed
        P_vpl = cols.P if cols.P is not None else P_end  # (typing only: no glossy column reads it)
        factors = (P_end, end_row, receivers.wi, receivers.ns, receivers.albedo, cols.glossy, P_vpl, cols.p_row,
                   cols.vwi, cols.vframes)
    n, m = len(x), len(cols.depth)
    lobes = _lobes(row, receivers, slice(0, n), roulette)
    boost = _pixel_boost(geom, end, cols, max_depth, receivers, roulette, pixel,
                         (x, ns, ng, side, off, row, tables, row_tab, inv_tavg), lobes)
    geom.counters["occluded_rays"] += vg.gather_packets(
        scene, geom.interior_bvh()[0].handle, x, ns, ng, off, side, row, end.vpl_depth_limit(max_depth), cols.pos,
        cols.normal, cols.directional, cols.min_d2, cols.cos_y_factor, cols.side, cols.spot_cutoff, cols.spot_beam,
        cols.depth, cols.mis, cols.light_pdf, cols.area, cols.direct_count, np.float32(2 * geom.eps), tables, row_tab,
        inv_tavg,
        np.zeros(n, np.int64), np.full(n, m, np.int64), cols.lum, float(roulette[0]) if roulette else 0.0,
        int(roulette[1]) if roulette else 0, 0, lobes, boost, cols.planes, cols.col_out, cols.color, irr, factors)
    return True


# A row's threshold at most this many times its own mean. The guess of a row's share is
# unshadowed and direct only: where a faint-looking end point carries more of its pixel's light
# than guessed (its main end point in shadow, or lit indirectly), the variance added to that
# light stays ≤ fraction · MAX_BOOST / pairs.
MAX_BOOST = 8.0


def _pixel_boost(geom: Geometry, end: EndPoints, cols: "_VPLColumns", max_depth: int, receivers: "_Receivers",
                 roulette: tuple | None, pixel: np.ndarray | None, rows: tuple | None = None,
                 lobes: np.ndarray | None = None) -> np.ndarray:
    """Each row's roulette boost (kernels.vpl_gather.roulette_row): its pixel's guessed light over
    its own, between 1 and MAX_BOOST — so a pixel's end points are thinned against the pixel's
    light, as one end point's pairs are against its own. A split surface gives a pixel several
    end points (a glass's two branches, a plastic's layer, lobe and the lobe ray's next surface:
    4.6 a pixel on Bitterli's staircase), each gathering every VPL; a faint one (a 4% reflection)
    keeps ~1/8 of its rays, each kept ray counting 1/p. Unbiased (the boost depends on no draw).

    The guess: the row's unshadowed light from the set's emitter samples, weighed as the roulette
    weighs them (kernels.vpl_gather.row_totals over those columns only: a few of a set's), times
    its weight toward the eye (throughput × albedo; a glossy row's guess carries its BSDF) — a dim
    reflection of a bright window is not taken for a faint end point. Only the rows of pixels with
    more than one; a row with no direct light guessed keeps its own roulette. No boost
    (vpl_gather.NO_BOOST) without a roulette or ``pixel``."""
    if roulette is None or pixel is None or len(pixel) == 0:
        return vg.NO_BOOST
    grouped = np.flatnonzero(pixel >= 0)
    if len(grouped) == 0:
        return vg.NO_BOOST
    counts = np.bincount(pixel[grouped])
    shared = grouped[counts[pixel[grouped]] >= 2]  # a pixel of one row keeps its roulette
    direct = cols.direct_columns()
    if len(shared) == 0 or len(direct[0]) == 0:
        return vg.NO_BOOST
    n, k = len(end), len(shared)
    x, ns, ng, side, off, row, tables, row_tab, inv_tavg = rows if rows is not None else _receivers(
        geom, end, slice(0, n))
    if lobes is None:
        lobes = _lobes(row, receivers, slice(0, n), roulette)
    totals = np.zeros(k)
    vg.row_totals(x[shared], ns[shared], ng[shared], off[shared], side[shared], row[shared],
                  end.vpl_depth_limit(max_depth)[shared], *direct[:-1], cols.direct_count, tables, row_tab[shared],
                  inv_tavg[shared], np.zeros(k, np.int64), np.full(k, len(direct[0]), np.int64), direct[-1],
                  lobes[shared] if len(lobes) else lobes, totals)
    glossy = (row[shared] == vg.ROW_GLOSSY)[:, None]
    light = totals * luminance(end.throughput[shared] * np.where(glossy, 1.0, receivers.albedo[shared]))
    light = np.where(np.isfinite(light) & (light > 0), light, 0.0)
    pixel_light = np.bincount(pixel[shared], weights=light, minlength=len(counts))
    lit = light > 0
    boost = np.ones(n, np.float32)
    boost[shared[lit]] = np.clip(pixel_light[pixel[shared[lit]]] / light[lit], 1.0, MAX_BOOST)
    return boost


def _lobes(row: np.ndarray, receivers: "_Receivers", sl: slice, roulette: tuple | None) -> np.ndarray:
    """The chunk's glossy rows' lobes, which shape the shadow roulette's guesses of their pairs'
    light (kernels.vpl_gather.lobe_rows): none without a roulette or a glossy row."""
    if roulette is None or not np.any(row == vg.ROW_GLOSSY):
        return vg.NO_LOBES
    P, end_row = receivers.packed
    out = np.empty((len(row), vg.LOBE_FIELDS), np.float32)
    vg.lobe_rows(P, end_row[sl], row, receivers.wi[sl], receivers.ns[sl], out)
    return out


def _chunks(e: int, m: int):
    """Slices of the e end points, PAIR_CHUNK (end point, VPL) pairs at a time."""
    chunk = max(1, PAIR_CHUNK // m)
    for s in range(0, e, chunk):
        yield slice(s, min(e, s + chunk))


def _range_chunks(lo: np.ndarray, hi: np.ndarray):
    """Slices of consecutive rows of about PAIR_CHUNK pairs, row i pairing with columns
    [lo[i], hi[i]): each run of rows with one range (one VPL set) is cut as :func:`_chunks` cuts
    it alone, then neighbouring pieces are joined while they fit — so a set's pairs meet the
    same chunks, and draw the same samples, alone or in a batch."""
    cuts = np.flatnonzero((np.diff(lo) != 0) | (np.diff(hi) != 0)) + 1
    bounds = [0, *cuts.tolist(), len(lo)]
    start, pairs = 0, 0
    for a, b in zip(bounds[:-1], bounds[1:]):
        m = int(hi[a] - lo[a])
        for sl in _chunks(b - a, max(m, 1)):
            n = (sl.stop - sl.start) * m
            if pairs and pairs + n > PAIR_CHUNK:
                yield slice(start, a + sl.start)
                start, pairs = a + sl.start, 0
            pairs += n
    if start < len(lo):
        yield slice(start, len(lo))


def contribution_per_vpl(geom: Geometry, end: EndPoints, vpls: VPLSet, clamp_d2: float,
                         max_depth: int, lobe_alpha: float = 0.0, rng: np.random.Generator | None = None,
                         visibility_samples: int = 0, col_range: tuple[np.ndarray, np.ndarray] | None = None,
                         column_u: np.ndarray | None = None) -> np.ndarray:
    """(M,) luminance each VPL sends toward the eye through the end points (radiance ×
    path throughput, summed over end points): the importance of a VPL to this view.

    ``visibility_samples`` > 0 (with ``rng`` or ``column_u``): an unbiased estimate from that
    many of each VPL's pairs, drawn in proportion to their unshadowed Lambertian terms
    (systematic sampling, one uniform per VPL: ``column_u``, or drawn from ``rng``): only the
    drawn pairs get a shadow ray and a BSDF evaluation, a fixed cost per VPL instead of one
    per end point. ``col_range`` (lo, hi) per end point: it scores only VPLs [lo, hi) (the
    candidates of several sets in one call, each against its own camera points)."""
    e, m = len(end), len(vpls)
    out = np.zeros(m)
    if e == 0 or m == 0:
        return out
    albedo = bsdf.albedo(end.sp, end.wi).astype(np.float64)
    cols = vpl_columns(vpls, geom, clamp_d2, lobe_alpha=lobe_alpha)
    receivers = _Receivers(end, albedo)
    sampled = visibility_samples > 0 and (rng is not None or column_u is not None)
    if sampled and column_u is None:
        column_u = rng.random(m)
    if col_range is None:
        col_range = (np.zeros(e, np.int64), np.full(e, m, np.int64))
    # (sampled or not, about PAIR_CHUNK pairs a call: the scoring's draws ran ~10% slower a set
    # with 16 sets per call, their scratch out of cache)
    for sl in _range_chunks(*col_range):
        eye_weight = albedo[sl] * end.throughput[sl]
        if not sampled:
            pi, pj, w, blocked, factor, _inner = _unoccluded_pairs(geom, end, sl, vpls, cols, max_depth, receivers,
                                                                   col_range=col_range)
            out += np.bincount(pj, weights=_pair_luminance(cols, eye_weight, pi, pj, w, blocked, factor),
                               minlength=m)
            continue
        # Only the drawn pairs are traced: their rays are made once they are drawn.
        pi, pj, w, pl, plain, draw_j, share, inv, row, (x, ng, off) = _scored_draws(
            geom, end, sl, vpls, cols, max_depth, col_range, eye_weight, visibility_samples, column_u)
        if len(draw_j) == 0:
            continue
        o, d, t = np.empty((len(pi), 3), np.float32), np.empty((len(pi), 3), np.float32), np.empty(len(pi), np.float32)
        vg.pair_rays(x, ng, off, cols.pos, cols.normal, cols.directional, np.float32(2 * geom.eps), pi, pj, o, d, t)
        blocked = geom.occluded_local(o, d, t)
        factor = _bsdf_factors(sl, cols, row, pi, pj, pl, d, blocked, receivers)
        full = _pair_luminance(cols, eye_weight, pi, pj, w, blocked, factor)
        ratio = np.divide(full, plain, out=np.zeros(len(pi)), where=plain > 0)
        out += np.bincount(draw_j, weights=share * ratio[inv], minlength=m)
    return out


def _pair_luminance(cols: "_VPLColumns", eye_weight: np.ndarray, pi: np.ndarray, pj: np.ndarray, w: np.ndarray,
                    blocked: np.ndarray | None = None, factor: np.ndarray | None = None) -> np.ndarray:
    """Luminance toward the eye of each pair (end point's albedo × throughput ``eye_weight``;
    0 where blocked or not finite; None: unshadowed, no BSDF factors)."""
    out = np.empty(len(pi))
    vs.pair_luminance(pi, pj, w, np.zeros(0, bool) if blocked is None else blocked,
                      np.zeros((0, 3)) if factor is None else factor, cols.color, eye_weight, out)
    return out


def _scored_draws(geom: Geometry, end: EndPoints, sl: slice, vpls: VPLSet, cols: "_VPLColumns", max_depth: int,
                  col_range: tuple, eye_weight: np.ndarray, samples: int, column_u: np.ndarray) -> tuple:
    """The chunk's draws for the scoring (kernels.vpl_scoring.scored_draws): ``samples`` pairs
    per VPL drawn in proportion to their unshadowed luminance toward the eye, with no pair
    list. Returns (row, column, weight, glossy light pdf, unshadowed luminance) of each distinct
    pair drawn; each draw's column, share W_j/samples and distinct pair; the rows' kinds; and
    the rows' (x, ng, offset) for the drawn pairs' shadow rays."""
    x, ns, ng, side, off, row, tables, row_tab, inv_tavg = _receivers(geom, end, sl)
    lo, hi = col_range[0][sl], col_range[1][sl]
    c0, c1 = vs.column_window(lo, hi, len(vpls))
    w = slice(c0, c1)  # the chunk's columns only: a batch of sets has thousands
    draws = (c1 - c0) * samples
    u_i, u_j = np.empty(draws, np.int64), np.empty(draws, np.int64)
    u_w, u_pl, u_plain = np.empty(draws, np.float32), np.empty(draws, np.float32), np.empty(draws)
    draw_j, share, inv = np.empty(draws, np.int64), np.empty(draws), np.empty(draws, np.int64)
    nd, nu = vs.scored_draws(x, ns, ng, off, side, row, end.vpl_depth_limit(max_depth)[sl],
                             cols.pos[w], cols.normal[w], cols.directional[w], cols.min_d2[w], cols.cos_y_factor[w],
                             cols.side[w], cols.spot_cutoff[w], cols.spot_beam[w], cols.depth[w], cols.mis[w],
                             cols.light_pdf[w], cols.area[w], cols.direct_count, tables, row_tab, inv_tavg,
                             lo - c0, hi - c0, cols.lum[w], cols.color[w], np.ascontiguousarray(eye_weight, np.float64),
                             samples, np.ascontiguousarray(column_u[w], np.float64), draw_j, share, inv, u_i, u_j,
                             u_w, u_pl, u_plain)
    return (u_i[:nu], u_j[:nu] + c0, u_w[:nu], u_pl[:nu], u_plain[:nu], draw_j[:nd] + c0, share[:nd], inv[:nd], row,
            (x, ng, off))


class _Receivers:
    """The end points' BSDFs for the compiled per-pair evaluation, packed once per gather and
    only when a pair needs them (Lambertian scenes never do)."""

    def __init__(self, end: EndPoints, albedo: np.ndarray):
        self.end, self.albedo_in = end, albedo

    @cached_property
    def packed(self) -> tuple:
        """(P, row): the end points' packed BSDFs, end point e at row ``row[e]``."""
        return bsdf.packed_rows(self.end.sp)

    @cached_property
    def wi(self) -> np.ndarray:
        return np.ascontiguousarray(self.end.wi, dtype=np.float64)

    @cached_property
    def ns(self) -> np.ndarray:
        return np.ascontiguousarray(self.end.ns, dtype=np.float64)

    @cached_property
    def albedo(self) -> np.ndarray:
        return np.ascontiguousarray(self.albedo_in, dtype=np.float64)


def vpl_columns(vpls: VPLSet, geom: Geometry, clamp_d2: float, force_general: bool = False,
                lobe_alpha: float = 0.0) -> "_VPLColumns":
    """The set's per-VPL gather constants, computed once per set and settings (vpls.derived):
    the glossy senders' regularization gain and packed BSDFs cost ~0.5 ms a call, and a set
    serves every tile of its k and each compensation level. Read-only once made, and made only
    once the set is final (its builders change a set in place before any gather reads it)."""
    # (the culling planes too: the columns' inside/outside flags are the geometry's)
    key = ("columns", tuple(np.asarray(geom.center, np.float64).tolist()), geom.interior_bvh()[1].tobytes(),
           float(clamp_d2), bool(force_general), float(lobe_alpha))
    cols = vpls.derived.get(key)
    if cols is None:
        cols = vpls.derived[key] = _VPLColumns(vpls, geom, clamp_d2, force_general, lobe_alpha)
    return cols


def _bumped_rows(sp, geom: Geometry) -> np.ndarray:
    """Per surface VPL (its BSDF points ``sp``): on a normal- or bump-mapped material?"""
    rows = sp.material_rows()
    if rows is None or not geom.bumped_materials.any():
        return np.zeros(len(sp), bool)
    return geom.bumped(rows)


class _VPLColumns:
    """Per-VPL constants of the gather as flat kernel arrays (made by :func:`vpl_columns`)."""

    def __init__(self, vpls: VPLSet, geom: Geometry, clamp_d2: float, force_general: bool = False,
                 lobe_alpha: float = 0.0):
        kind = vpls.kind
        m = len(kind)
        f32 = np.float32
        self.directional = kind == VPL_DIRECTIONAL
        self.area = kind == VPL_AREA
        spot = kind == VPL_SPOT
        surface = kind == VPL_SURFACE
        self.pos = np.ascontiguousarray(vpls.position - geom.center, dtype=f32)
        self.normal = np.array(vpls.normal, dtype=f32)  # (a copy: Lambertian rows take ng below)
        color = vpls.power.astype(np.float64).copy()
        self.glossy = np.zeros(m, bool)
        self.surf_rows = np.nonzero(surface)[0]
        self.P = None  # the surface VPLs' packed BSDFs (glossy senders, regularized)
        p_row = None  # surface VPL s's row in P
        # Surface VPLs: Lambertian ones fold rho/π into their colour and radiate on the side
        # their light arrived from; the others need their BSDF per pair.
        self.side = np.ones(m, f32)
        if len(self.surf_rows):
            sp = vpls.surface
            # force_general: every surface VPL through the full BSDF (the plan-off baseline).
            lam = (sp.kind == DIFFUSE) & (not force_general)
            rows = self.surf_rows
            self.side[rows] = np.where(vpls.wi_local[rows, 2] >= 0, 1.0, -1.0)
            color[rows[lam]] *= sp.diffuse[lam].astype(np.float32) / np.float32(np.pi)  # ρ/π as it always rounded
            # On a normal- or bump-mapped surface a Lambertian VPL's cos θ toward a receiver is
            # the one of its true surface (the area its light leaves), not of its perturbed
            # normal (common.kernels.shading_normals); elsewhere the interpolated normal stands
            # for the smooth surface its mesh approximates
            bumped = _bumped_rows(sp, geom)  # (per surface VPL; the glossy ones' frames below too)
            mapped = rows[lam & bumped]
            self.normal[mapped] = vpls.ng[mapped]
            if len(mapped):  # (and radiates on the side of its true surface its light came from)
                wi = to_world(vpls.wi_local[mapped], vpls.normal[mapped])
                self.side[mapped] = np.where(np.sum(wi * vpls.ng[mapped], axis=1) >= 0, 1.0, -1.0)
            self.glossy[rows[~lam]] = True
            if not lam.all():
                reg = regularized_senders(sp, lobe_alpha)
                self.P, p_row = bsdf.packed_rows(reg)
                if reg is not sp:
                    color[rows] *= regularization_gain(sp, reg, vpls.wi_local[rows])
        # glossy columns' BSDF rows in P (their surface VPLs in order), -1 elsewhere
        self.vpl_row = np.full(m, -1, np.int64)
        self.vpl_row[self.surf_rows] = np.arange(len(self.surf_rows))
        # glossy columns' rows in P (its rows need not be the surface VPLs' order), -1 elsewhere
        self.p_row = self.vpl_row if p_row is None else np.where(self.vpl_row >= 0, p_row[self.vpl_row], -1)
        self.vwi = np.ascontiguousarray(vpls.wi_local, dtype=np.float64)
        # a glossy VPL's BSDF frame (shading normal) and the surface its light leaves (ng on a
        # normal- or bump-mapped surface, else the shading normal: no correction)
        leaves = vpls.normal.copy()
        if len(self.surf_rows):
            b = self.surf_rows[bumped]
            leaves[b] = vpls.ng[b]
        self.vframes = np.ascontiguousarray(np.concatenate([vpls.normal, leaves], axis=1), dtype=np.float64)
        self.color = np.ascontiguousarray(color)
        # The shadow roulette's light per unit pair weight; a glossy sender's is a guess: a
        # Lambertian VPL of its albedo.
        self.lum = luminance(color)
        gl = np.nonzero(self.glossy)[0]
        if len(gl):
            self.lum[gl] = luminance(vpls.power[gl] * bsdf.albedo(vpls.surface.subset(self.vpl_row[gl]),
                                                                  vpls.wi_local[gl]) / np.pi)
        # Spots carry (_, beam, cutoff) degrees in wi_local; cutoff < 0 marks "not a spot".
        self.spot_cutoff = np.where(spot, vpls.wi_local[:, 2], -1.0).astype(np.float64)
        self.spot_beam = np.where(spot, vpls.wi_local[:, 1], 0.0).astype(np.float64)
        lp = vpls.light_pdf if vpls.light_pdf is not None else np.zeros(m)
        self.light_pdf = lp.astype(f32)
        # Emitter samples with a non-delta pdf take part in MIS (area lights, environment).
        self.mis = (lp > 0) & (self.area | self.directional) & (vpls.direct_count > 0)
        # Columns whose emission has a cos θ_y factor (area emitters, Lambertian surface VPLs).
        self.cos_y_factor = self.area | (surface & ~self.glossy)
        # Lower bound of the squared distance: the clamp for surface VPLs only (clamping
        # emitter samples would bias direct light); directional columns have d² = 1.
        self.min_d2 = np.where(surface, f32(clamp_d2), f32(1e-30)).astype(f32)
        self.depth = vpls.depth.astype(np.int64)
        self.direct_count = int(vpls.direct_count)
        # Shadow-ray culling (common.hull_culling): the supporting planes and the prefix count
        # of columns a ray may leave their inner side toward (directional ones, lights beyond
        # the geometry).
        self.planes = geom.interior_bvh()[1]
        outside = self.directional | np.any(~(self.pos @ self.planes[:, :3].T + self.planes[:, 3] <= 0), axis=1)
        self.col_out = np.concatenate([[0], np.cumsum(outside)]).astype(np.int64)
        self._direct = None

    def direct_columns(self) -> tuple:
        """The emitter samples' columns as kernels.vpl_gather.row_totals takes them (pos …
        area, then lum), made once per set: what :func:`_pixel_boost` weighs."""
        if self._direct is None:
            take = np.flatnonzero(self.depth == 0)
            self._direct = tuple(np.ascontiguousarray(v[take]) for v in (
                self.pos, self.normal, self.directional, self.min_d2, self.cos_y_factor, self.side, self.spot_cutoff,
                self.spot_beam, self.depth, self.mis, self.light_pdf, self.area, self.lum))
        return self._direct


def _unoccluded_pairs(geom: Geometry, end: EndPoints, sl: slice, vpls: VPLSet, cols: _VPLColumns,
                      max_depth: int, receivers: _Receivers, roulette: tuple | None = None,
                      col_range: tuple | None = None, boost: np.ndarray = vg.NO_BOOST) -> tuple:
    """The chunk's live (end point, VPL) pairs after Embree's occlusion test: (row, column,
    scalar weight, blocked, per-pair RGB factor or an empty (0, 3) array, traced on the inner
    BVH (Geometry.interior_bvh)). ``roulette``:
    (fraction, seed) of the shadow rays' Russian roulette, None for none."""
    pi, pj, w, row, pl, o, d, t, inner = _pair_rays(geom, end, sl, vpls, cols, max_depth, col_range, roulette,
                                                    receivers, boost)
    blocked = geom.occluded_local(o, d, t, inner) if len(pi) else np.zeros(0, bool)
    factor = _bsdf_factors(sl, cols, row, pi, pj, pl, d, blocked, receivers)
    return pi, pj, w, blocked, factor, inner


def _shadow_origins(geom: Geometry, end: EndPoints, sl: slice) -> tuple:
    """The chunk's end points as the gather kernels take them, float32 in Embree's centred
    frame: (x, ns, ng, side of the eye ±1, offset length along ng toward that side)."""
    # Live pairs lie on the side of the surface the eye sees (cos_x > 0, reflective BSDFs),
    # so one offset origin per end point serves all its shadow rays.
    f32, a = np.float32, np.ascontiguousarray
    n = len(end.position[sl])
    x, ns, ng = np.empty((n, 3), f32), np.empty((n, 3), f32), np.empty((n, 3), f32)
    side, off = np.empty(n, f32), np.empty(n, f32)
    center, eps, ulps = geom.offset_terms()
    vg.shadow_origins(a(end.position[sl], np.float64), a(end.ns[sl], np.float64), a(end.ng[sl], np.float64),
                      a(end.wi[sl], np.float64), center, eps, ulps, x, ns, ng, side, off)
    return x, ns, ng, side, off


def _receivers(geom: Geometry, end: EndPoints, sl: slice) -> tuple:
    """The chunk's end points as the pair kernels take them: :func:`_shadow_origins`, then the
    receiver kind per row (kernels.vpl_gather.ROW_*) and the plastic layers' coat tables
    (tables, row's table, 1/t_avg per row)."""
    x, ns, ng, side, off = _shadow_origins(geom, end, sl)
    n = len(x)
    kind = end.sp.kind[sl]
    wi = np.ascontiguousarray(end.wi[sl], np.float64)
    row = np.empty(n, np.int8)
    # Glossy kinds reflect only: seen from behind a one-sided one, f = 0 (rough glass's lobes: below).
    layers = vg.receiver_rows(np.ascontiguousarray(kind), np.ascontiguousarray(end.sp.twosided[sl]), wi, DIFFUSE,
                              NULL, ROUGHPLASTIC_DIFFUSE, row)
    glass = np.flatnonzero((kind == ROUGHDIELECTRIC_R) | (kind == ROUGHDIELECTRIC_T))
    if len(glass):  # rough glass's lobes light it from their side (its refraction: the far one)
        row[glass] = vg.ROW_GLOSSY
        through = glass[kind[glass] == ROUGHDIELECTRIC_T]
        side[through] = -side[through]
        off[through] = -off[through]
    tables, row_tab, inv_tavg = np.ones((1, 2)), np.zeros(n, np.int64), np.ones(n)
    if layers:
        wz = wi[:, 2]
        layer = np.nonzero((kind == ROUGHPLASTIC_DIFFUSE) & (end.sp.twosided[sl] | (wz > 0)))[0]
        # The diffuse layer is Lambertian up to a scalar t(cos)/t_avg: no per-pair BSDF call.
        row[layer] = vg.ROW_LAYER
        tables, rt, t_avg = bsdf.coat_transmittance(end.sp.subset(sl.start + layer))
        row_tab[layer] = rt
        # albedo() took the coat's t(cos θ_i) at |cos θ_i| ≥ 0.05: undo that at grazing incidence
        ci = np.abs(wz[layer])
        t_ratio = lerp_gather(tables, rt, np.clip(ci, 0, 1)) / np.maximum(
            lerp_gather(tables, rt, np.clip(ci, 0.05, 1)), 1e-12)
        inv_tavg[layer] = t_ratio / np.maximum(t_avg, 1e-12)
    return x, ns, ng, side, off, row, tables, row_tab, inv_tavg


def _pair_rays(geom: Geometry, end: EndPoints, sl: slice, vpls: VPLSet, cols: _VPLColumns,
               max_depth: int, col_range: tuple | None = None, roulette: tuple | None = None,
               receivers: _Receivers | None = None, boost: np.ndarray = vg.NO_BOOST) -> tuple:
    """The chunk's live (end point, VPL) pairs and their shadow rays, untraced: (row, column,
    scalar weight, receiver row kind, light pdf, origins, directions, tfar, whether the ray may
    skip the supporting planes' triangles (Geometry.interior_bvh)) — the rays in the
    centred float32 frame for Embree. ``col_range`` (lo, hi) per end point: its VPLs (None:
    all). ``roulette`` (fraction, seed): the shadow rays' Russian roulette, applied per row as
    the pairs are written (kernels.vpl_gather.roulette_row; glossy rows' guesses by their lobes,
    of ``receivers``' packed BSDFs, packed here when not given)."""
    f32 = np.float32
    x, ns, ng, side, off, row, tables, row_tab, inv_tavg = _receivers(geom, end, sl)
    n, m = len(x), len(vpls)
    if col_range is None:
        lo, hi, cap = np.zeros(n, np.int64), np.full(n, m, np.int64), n * m
    else:
        lo, hi = col_range[0][sl], col_range[1][sl]
        cap = int((hi - lo).sum())
    pi = np.empty(cap, np.int64)
    pj = np.empty(cap, np.int64)
    w = np.empty(cap, f32)
    pl = np.empty(cap, f32)
    o = np.empty((cap, 3), f32)
    d = np.empty((cap, 3), f32)
    t = np.empty(cap, f32)
    inner = np.empty(cap, bool)
    k = vg.pair_weights(x, ns, ng, off, side, row, end.vpl_depth_limit(max_depth)[sl],
                        cols.pos, cols.normal, cols.directional, cols.min_d2, cols.cos_y_factor,
                        cols.side, cols.spot_cutoff, cols.spot_beam, cols.depth, cols.mis,
                        cols.light_pdf, cols.area, cols.direct_count, f32(2 * geom.eps),
                        tables, row_tab, inv_tavg, lo, hi, cols.lum,
                        float(roulette[0]) if roulette else 0.0, int(roulette[1]) if roulette else 0, sl.start,
                        _lobes(row, receivers or _Receivers(end, None), sl, roulette), boost, cols.planes, cols.col_out,
                        pi, pj, w, pl, o, d, t, inner)
    return pi[:k], pj[:k], w[:k], row, pl[:k], o[:k], d[:k], t[:k], inner[:k]


def _bsdf_factors(sl: slice, cols: _VPLColumns, row: np.ndarray, pi: np.ndarray, pj: np.ndarray,
                  pl: np.ndarray, d: np.ndarray, blocked: np.ndarray, receivers: _Receivers) -> np.ndarray:
    """Per-pair RGB factors for the unoccluded pairs with a non-Lambertian end: the receiver's
    f_x(wi, ω)/albedo and its MIS weight against emitter samples, and a glossy VPL's
    f_y(ω_in, y→x) in place of its Lambertian colour (compiled: vpl_gather.pair_factors).
    Empty (0, 3) when no pair needs one."""
    if not (np.any(row == vg.ROW_GLOSSY) or cols.glossy.any()):
        return np.zeros((0, 3))
    factor = np.empty((len(pi), 3))
    P_end, end_row = receivers.packed
    P_vpl = cols.P if cols.P is not None else P_end  # (typing only: no glossy column reads it)
    if not vg.pair_factors(pi, pj, d, pl, blocked, row, sl.start, P_end, end_row, receivers.wi, receivers.ns,
                           receivers.albedo, cols.glossy, P_vpl, cols.p_row, cols.vwi, cols.vframes, factor):
        return np.zeros((0, 3))
    return factor


@dataclass
class BSDFRays:
    """One BSDF-sampled ray per end point of ``rows``, traced to its closest hit: the continuation
    ray a path tracer would take. BSDF-direct lighting reads the emission it reaches and the clamp
    compensation the surface it hits within the clamp radius, so one sample, one set of world
    rays and one Embree batch serve both (both estimators stay unbiased; they are merely
    correlated through the shared direction)."""

    rows: np.ndarray  # (n,) end-point rows
    weight: np.ndarray  # (n, 3) f cos / pdf
    pdf: np.ndarray  # (n,) solid-angle pdf (delta: the component's probability)
    delta: np.ndarray  # (n,) bool
    direction: np.ndarray  # (n, 3) world space
    hits: object  # common.geometry.Hits of the n rays

    def subset(self, idx: np.ndarray) -> "BSDFRays":
        """The rays ``idx`` (an index array), in that order."""
        return BSDFRays(self.rows.take(idx), self.weight.take(idx, axis=0), self.pdf.take(idx), self.delta.take(idx),
                        self.direction.take(idx, axis=0), self.hits.rows(idx))

    def lit(self, env: np.ndarray) -> np.ndarray:
        """The rays that reach an emitter, or leave the scene under a lit sky ``env``: the only
        ones that carry BSDF-direct light (:func:`bsdf_direct`)."""
        seen = self.hits.valid & (self.hits.emitter >= 0)
        if np.any(env > 0):
            seen |= ~self.hits.valid
        return np.flatnonzero(seen)


def trace_bsdf_rays(geom: Geometry, lights: LightSampler, end: EndPoints, max_depth: int,
                    rng: np.random.Generator, short: float | np.ndarray,
                    targets: tuple[np.ndarray, np.ndarray] | None = None) -> BSDFRays:
    """The continuation rays of every end point that may still add a segment (not the split
    lobes' direct-only points: a lobe's own traced ray is its BSDF sample). Rays that provably
    reach no emitter and none of the ``targets`` spheres (centres, radii: the mirror/glass
    objects whose chains are gathered) are traced only ``short`` far (one length, or one per
    end point: the clamp radius where the compensation reads them, else 0)."""
    e = len(end)
    ok = end.segments + 1 <= max_depth if max_depth >= 0 else np.ones(e, bool)
    if end.direct_only is not None:
        ok &= ~end.direct_only
    ok = np.nonzero(ok)[0]
    n = len(ok)
    u1, u2 = rng.random(n), rng.random((n, 2))
    P, prow = bsdf.packed_rows(end.sp)
    out_ok = np.empty(n, np.int64)
    weight, d, o = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    pdf_b, delta = np.empty(n), np.empty(n, bool)
    a = np.ascontiguousarray
    c = br.sample_rays(P, prow, ok, a(end.wi, np.float64), a(end.ns, np.float64), a(end.position, np.float64),
                       a(end.ng, np.float64), u1, u2, True, *geom.offset_terms(), out_ok, weight, pdf_b, delta, d, o)
    ok, weight, pdf_b, delta, d, o = out_ok[:c], weight[:c], pdf_b[:c], delta[:c], d[:c], o[:c]
    reach = lights.may_reach_emitter(o, d)
    if targets is not None and len(targets[1]) and not reach.all():
        reach |= rays_meet_spheres(o, d, *targets)
    tmax = np.where(reach, np.inf, short if np.ndim(short) == 0 else np.asarray(short)[ok])
    return BSDFRays(ok, weight, pdf_b, delta, d, geom.intersect(o, d, tmax=tmax))


def bsdf_direct(scene: Scene, geom: Geometry, lights: LightSampler, end: EndPoints,
                albedo: np.ndarray, direct_count: int, max_depth: int,
                rng: np.random.Generator, env_guide=None, rays: BSDFRays | None = None,
                emitter_pmf: np.ndarray | None = None) -> np.ndarray:
    """Emission reached by one BSDF-sampled ray per end point, MIS-weighted against the
    emitter samples (per unit albedo, so it joins the filtered irradiance). ``env_guide``: the
    set's environment-direction pdf (worker.env_guide), when its samples were guided;
    ``emitter_pmf``: the set's emitter choice (VPLSet.emitter_pmf).
    ``rays``: the end points' traced continuation rays (:func:`trace_bsdf_rays`), shared with
    the clamp compensation; None: sampled and traced here (only those that may reach a light)."""
    out = np.zeros((len(end), 3))
    if len(end) == 0 or not lights.has_light:
        return out
    if rays is None:
        # Rays that provably reach no emitter carry nothing here: traced 0 far.
        rays = trace_bsdf_rays(geom, lights, end, max_depth, rng, short=0.0)
    add_bsdf_direct(lights, [(rays, 0)], albedo, LightMIS(direct_count, env_guide, emitter_pmf), out)
    return out


def add_bsdf_direct(lights: LightSampler, ray_sets: Sequence[tuple[BSDFRays, int]], albedo: np.ndarray,
                    light_mis: LightMIS, irr: np.ndarray) -> None:
    """:func:`bsdf_direct`'s light added to ``irr`` in place (compiled: kernels.bsdf_direct):
    each ``(rays, base)`` of ``ray_sets`` lights rows ``base + rays.rows`` of ``irr`` (the end
    points' albedo at the same rows of ``albedo``) — several batches' rays with no copy into
    one."""
    env = np.ascontiguousarray(lights.environment(), np.float64)
    sky = bool(np.any(env > 0))
    area_pdf = np.append(lights.area_pdf(np.arange(len(lights.scene.emitters)), light_mis.emitter_pmf), 0.0)
    alb = np.ascontiguousarray(albedo, np.float64)
    for rays, base in ray_sets:
        h = rays.hits
        env_pl = np.zeros(0)
        if sky:  # the sky's pdf along the misses, as emitter_pdf takes it
            miss = ~h.valid
            env_pl = np.zeros(len(miss))
            if miss.any():
                env_pl[miss] = sky_pdf(lights, light_mis, rays.direction[miss])
        kbd.add_emission(rays.rows, int(base), rays.weight, rays.pdf, rays.delta, rays.direction, h.valid, h.t, h.ns,
                         h.emitter, lights.area_radiance, area_pdf, env, lights.env_tables, sky, env_pl,
                         float(light_mis.direct_count), alb, irr)
