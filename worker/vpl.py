"""Virtual point lights P_k by instant radiosity (Keller 1997; Wald et al. 2002 §4, §5.1).

A set holds ``direct_vpls`` samples on the emitters (direct light) and the vertices of
quasi-random light walks of at most ``light_path_length`` bounces (indirect light), all
drawn from block k of one scrambled Sobol stream, so a set is a pure function of
(scene, seed, k, parameters).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.lights import VPL_SPOT, VPL_SURFACE, LightSampler, PointSamples, to_local
from igi.common.scene import Scene, reflecting
from igi.common.sobol_stream import SobolStream, stream_seed

from .light_paths import continue_paths, incident_ratios, roulette_numbers, set_key, trace_walks
from .portals import portal_walks

# Sobol dimensions: direct samples use 3 (emitter, 2 for the point); a walk uses 5 to leave
# the light and 3 per bounce (component + 2 for the direction).
DIRECT_DIMS = 3
WALK_DIMS_START = 5
WALK_DIMS_PER_BOUNCE = 3
# Stream layout (interleaved sampling, Keller & Heidrich 2001): the emitter samples and the
# walks each have a sequence of their own per frame seed, and set k takes its rows
# [k·n, (k+1)·n) of it, so the n² sets of a frame together are one Sobol prefix of n²·n points,
# stratified as a whole: the discontinuity buffer averages a pixel's light over the sets. (Blocks
# of a fixed 4096 rows put every set's first point in the same 1/4096 of the leading dimension:
# all sets of a frame chose the same emitter and started their walks alike.)
WALK_STREAM = "light walks"
ROULETTE_STREAM = "light walk roulette"  # the key of a set's walks past their length


@dataclass
class VPLSet:
    kind: np.ndarray  # (M,) int8, common.lights.VPL_*
    position: np.ndarray  # (M, 3)
    normal: np.ndarray  # (M, 3) shading normal (surface/area) or light direction
    ng: np.ndarray  # (M, 3) geometric normal (offsets for shadow rays)
    power: np.ndarray  # (M, 3) already divided by the number of samples of its kind
    depth: np.ndarray  # (M,) light-path segments from the emitter to the VPL (0 = on the emitter)
    wi_local: np.ndarray  # (M, 3) surface VPLs: incident direction in the VPL's shading frame
    surface: "bsdf.SurfacePoints | None"  # BSDF parameters of the surface VPLs (kind == VPL_SURFACE rows, in order)
    diffuse_only: bool = True  # every surface VPL is Lambertian: the fast path applies
    light_pdf: np.ndarray | None = None  # (M,) emitter samples' pdf (lights.PointSamples.pdf), 0 elsewhere
    direct_count: int = 0  # emitter samples per set (the MIS sample count)
    env_guide: object = None  # worker.env_guide.EnvGuide: the environment samples' direction pdf
    # (E,) the emitter choice of the emitter samples (worker.vpl_importance.view_emitter_pmf);
    # None: lights.pmf (by power). MIS against them must use the same.
    emitter_pmf: np.ndarray | None = None
    # Constants the gather derives from the set (shading.vpl_columns), kept with it: a set
    # serves every tile of its k and every compensation level (not copied by replace()).
    derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.kind)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.kind, self.position, self.normal, self.ng, self.power,
                                      self.depth, self.wi_local))


def _empty_set() -> VPLSet:
    z = np.zeros((0, 3))
    return VPLSet(np.zeros(0, np.int8), z, z, z, z, np.zeros(0, np.int32), z, None, True, np.zeros(0), 0)


def walk_count(indirect_vpls: int, max_length: int) -> int:
    """Walks per set: each walk leaves up to ``max_length`` vertices (one per bounce)."""
    if indirect_vpls <= 0:
        return 0
    return max(1, int(np.ceil(indirect_vpls / max_length)))


MAX_WALK = 64  # hard cap of Russian-roulette walks (a safety net; survival falls off long before)


def build_vpl_set(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, k: int,
                  direct_vpls: int, indirect_vpls: int, max_length: int,
                  roulette: bool = False, portals=None, emitter_pmf: np.ndarray | None = None) -> VPLSet:
    """The VPL set P_k for frame seed ``seed``.

    ``roulette``: walks go on past ``max_length`` with Russian roulette (survival = the
    throughput ratio of the bounce), so the set is unbiased for paths of any length.
    ``portals`` (worker.portals.Portals): walks from the sky start where it enters the view.
    ``emitter_pmf``: how the emitter samples choose their emitter (None: by power); the light
    walks always leave the emitters by power.
    """
    return build_vpl_sets(scene, geom, lights, seed, [k], direct_vpls, indirect_vpls, max_length, roulette,
                          portals, emitter_pmf)[0]


def build_vpl_sets(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, ks: Sequence[int],
                   direct_vpls: int, indirect_vpls: int, max_length: int,
                   roulette: bool = False, portals=None, emitter_pmf: np.ndarray | None = None) -> list[VPLSet]:
    """The sets P_k of every block k of ``ks``, as :func:`build_vpl_set` builds each alone (bit
    for bit: every random number is the set's own), with one emitter draw and one Embree batch
    per bounce for all of them — a set's build was mostly per-call overhead."""
    return sets_of(*build_vpl_rows(scene, geom, lights, seed, ks, direct_vpls, indirect_vpls, max_length, roulette,
                                   portals, emitter_pmf))


def sets_of(joined: VPLSet, rows: list[np.ndarray]) -> list[VPLSet]:
    """The sets of :func:`build_vpl_rows`: rows[i] of ``joined`` each."""
    return [subset_vpls(joined, r) if len(r) else _empty_set() for r in rows]


def build_vpl_rows(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, ks: Sequence[int],
                   direct_vpls: int, indirect_vpls: int, max_length: int, roulette: bool = False, portals=None,
                   emitter_pmf: np.ndarray | None = None) -> tuple[VPLSet, list[np.ndarray]]:
    """:func:`build_vpl_sets` as (all sets' VPLs in one set, each set's rows of it, ascending):
    set i is ``subset_vpls(joined, rows[i])``, and callers that want several sets' VPLs
    together take them in one copy."""
    if not lights.has_light:
        return _empty_set(), [np.zeros(0, np.int64) for _ in ks]
    nsets = len(ks)
    # Each set's rows of the emitter samples and of the walks' vertices, taken from the two
    # joined in one copy per set (subsets of each, then a join per set, copied everything twice).
    parts: list[VPLSet] = []
    rows: list[list[np.ndarray]] = [[] for _ in ks]
    if direct_vpls > 0:
        stream = SobolStream(seed)
        u = np.concatenate([stream.padded(k, direct_vpls, direct_vpls, DIRECT_DIMS) for k in ks])
        parts.append(emitter_vpls(scene, lights.sample_points(u, emitter_pmf), direct_vpls, emitter_pmf))
        for i in range(nsets):
            rows[i].append(np.arange(i * direct_vpls, (i + 1) * direct_vpls))
    walks = walk_count(indirect_vpls, max_length)
    if walks > 0 and max_length > 0:
        length = MAX_WALK if roulette else max_length
        dims = WALK_DIMS_START + WALK_DIMS_PER_BOUNCE * max_length
        stream = SobolStream(stream_seed(seed, WALK_STREAM))
        u = np.concatenate([stream.padded(k, walks, walks, dims) for k in ks])
        keys = None
        if roulette:
            # Bounces past max_length are rare: counter-based numbers of the set's key serve them,
            # drawn only when a walk gets there, and one more per bounce decides its roulette.
            base = stream_seed(seed, ROULETTE_STREAM)
            keys = np.repeat(np.array([set_key(base, k) for k in ks], np.uint64), walks)
        walked, owner = _light_walks(scene, geom, lights, u, walks, length, max_length if roulette else None, keys,
                                     portals)
        base = sum(len(p) for p in parts)
        parts.append(walked)
        for i, r in enumerate(_split(owner // walks, nsets)):
            rows[i].append(base + r)
    joined = concat_vpls(parts)
    return joined, [np.concatenate(r) if r and len(joined) else np.zeros(0, np.int64) for r in rows]


def _split(label: np.ndarray, n: int) -> list[np.ndarray]:
    """Rows of each label 0..n-1, each in ascending order."""
    order = np.argsort(label, kind="stable")
    stops = np.cumsum(np.bincount(label, minlength=n))
    return np.split(order, stops[:-1])


def emitter_vpls(scene: Scene, s: PointSamples, count: int, emitter_pmf: np.ndarray | None = None,
                 mis: bool = True) -> VPLSet:
    """The VPLs of ``count`` emitter samples ``s`` (their power averaged over ``count``; spots
    carry (_, beam, cutoff) degrees in wi_local). ``mis``: they take part in MIS against BSDF
    rays (light_pdf, direct_count); False: plain point lights (scoring, not rendering)."""
    m = len(s.kind)
    extra = np.zeros((m, 3))
    for j in np.nonzero(s.kind == VPL_SPOT)[0]:
        e = scene.emitters[s.emitter[j]]
        extra[j] = (0.0, e.beam_width, e.cutoff_angle)
    return VPLSet(s.kind, s.position, s.normal, s.normal.copy(), s.power / count, np.zeros(m, np.int32), extra,
                  None, True, s.pdf if mis else np.zeros(m), count if mis else 0, None, emitter_pmf)


def _light_walks(scene: Scene, geom: Geometry, lights: LightSampler, u: np.ndarray,
                 walks: int, max_length: int, roulette_after: int | None = None,
                 keys: np.ndarray | None = None, portals=None) -> tuple[VPLSet, np.ndarray]:
    """The vertices of the walks of rows u (flux / ``walks`` each) and the row that left each;
    past ``roulette_after`` bounces (u's), Russian roulette on the numbers of each row's set
    key ``keys[row]`` (kernels.light_paths.walk_uniform)."""
    rays = lights.emit_rays(u[:, :WALK_DIMS_START])
    if portals is not None:
        portal_walks(rays, u[:, :WALK_DIMS_START], lights, portals)
    flux = np.ascontiguousarray(rays.flux / walks, np.float64)
    d = np.ascontiguousarray(rays.direction, np.float64)  # (continue_paths updates d, o, flux in place)
    o = np.array(rays.origin, np.float64, order="C")
    is_surface = np.linalg.norm(rays.normal - rays.direction, axis=1) > 1e-9  # area: offset off the emitter
    if is_surface.any():
        o[is_surface] = geom.offset(o[is_surface], rays.normal[is_surface], d[is_surface])
    walked = trace_walks(scene.materials, geom, o, d, flux, u, max_length, roulette_after, keys, walks,
                         WALK_DIMS_START, WALK_DIMS_PER_BOUNCE)
    if walked is not None:  # compiled, in one call: the loop below's vertices bit for bit
        pos, ns, ng, pw, dp, wi, mat, uv, row = walked
        if len(row) == 0:
            return _empty_set(), np.zeros(0, np.int64)
        sp = bsdf.gather(scene.materials, mat, uv)
        return VPLSet(np.full(len(row), VPL_SURFACE, np.int8), pos, ns, ng, pw, dp, wi, sp,
                      bool(np.all(sp.kind == 0))), row
    survival = None
    if keys is not None:  # the numbers trace_walks draws as it goes, as arrays
        extra, survival = roulette_numbers(keys, walks, roulette_after, max_length, WALK_DIMS_PER_BOUNCE)
        u = np.concatenate([u, extra], axis=1)
    alive = np.nonzero(np.any(flux > 0, axis=1))[0]
    pos_l, ns_l, ng_l, pw_l, dp_l, wi_l, sp_l, row_l = [], [], [], [], [], [], [], []
    for bounce in range(max_length):
        if len(alive) == 0:
            break
        hits = geom.intersect(o[alive], d[alive])
        keep = hits.valid
        alive = alive[keep]
        if len(alive) == 0:
            break
        pos = hits.position[keep]
        ns = hits.ns[keep]
        ng = hits.ng[keep]
        mat = hits.material[keep]
        uv = hits.uv[keep]
        sp = bsdf.gather(scene.materials, mat, uv)
        bumped = geom.bumped(mat)
        wi = to_local(-d[alive], ns)
        nondelta = reflecting(scene.materials, sp.kind, mat)
        if nondelta.any():
            sel = np.nonzero(nondelta)[0]
            pos_l.append(pos[sel])
            ns_l.append(ns[sel])
            ng_l.append(ng[sel])
            pw_l.append(flux[alive[sel]] * incident_ratios(-d[alive[sel]], ns[sel], ng[sel], bumped[sel])[:, None])
            dp_l.append(np.full(len(sel), bounce + 1, np.int32))
            wi_l.append(wi[sel])
            sp_l.append(sp.subset(sel))
            row_l.append(alive[sel])
        if bounce + 1 >= max_length:
            break
        # Russian roulette past ``roulette_after`` bounces: survive with the bounce's
        # throughput ratio, survivors reweighted.
        roulette = roulette_after is not None and bounce + 1 >= roulette_after
        alive = continue_paths(sp, geom, np.arange(len(alive)), alive, pos, ns, ng, d, o, flux, u,
                               WALK_DIMS_START + WALK_DIMS_PER_BOUNCE * bounce, survival if roulette else None,
                               bounce, bumped)
    if not pos_l:
        return _empty_set(), np.zeros(0, np.int64)
    sp_all = concat_surface(sp_l)
    m = sum(len(p) for p in pos_l)
    return VPLSet(np.full(m, VPL_SURFACE, np.int8), np.concatenate(pos_l), np.concatenate(ns_l),
                  np.concatenate(ng_l), np.concatenate(pw_l), np.concatenate(dp_l),
                  np.concatenate(wi_l), sp_all, bool(np.all(sp_all.kind == 0))), np.concatenate(row_l)


def subset_vpls(vpls: VPLSet, rows: np.ndarray, power_scale: np.ndarray | None = None) -> VPLSet:
    """The VPLs ``rows`` (ascending), their powers optionally scaled per row of ``vpls``."""
    rows = np.asarray(rows, np.int64)
    power = vpls.power[rows] if power_scale is None else vpls.power[rows] * power_scale[rows][:, None]
    surface = None
    if vpls.surface is not None:
        # surface BSDF rows are the VPL_SURFACE rows in order: map the kept ones
        surf_rank = np.cumsum(vpls.kind == VPL_SURFACE) - 1
        kept = rows[vpls.kind[rows] == VPL_SURFACE]
        surface = vpls.surface.subset(surf_rank[kept]) if len(kept) else None
    lp = vpls.light_pdf[rows] if vpls.light_pdf is not None else None
    return VPLSet(vpls.kind[rows], vpls.position[rows], vpls.normal[rows], vpls.ng[rows], power,
                  vpls.depth[rows], vpls.wi_local[rows], surface,
                  bool(surface is None or np.all(surface.kind == 0)), lp, vpls.direct_count, vpls.env_guide,
                  vpls.emitter_pmf)


def concat_surface(sps: list) -> "bsdf.SurfacePoints":
    """Concatenate SurfacePoints batches (an optional field None in all: None)."""
    return bsdf.SurfacePoints.concat(sps)


def concat_vpls(parts: list[VPLSet]) -> VPLSet:
    """The VPLs of ``parts`` in order, as one set (light_pdf 0 where a part has none)."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return _empty_set()
    surf = [p.surface for p in parts if p.surface is not None]
    return VPLSet(
        np.concatenate([p.kind for p in parts]),
        np.concatenate([p.position for p in parts]),
        np.concatenate([p.normal for p in parts]),
        np.concatenate([p.ng for p in parts]),
        np.concatenate([p.power for p in parts]),
        np.concatenate([p.depth for p in parts]),
        np.concatenate([p.wi_local for p in parts]),
        concat_surface(surf) if surf else None,
        all(p.diffuse_only for p in parts),
        np.concatenate([p.light_pdf if p.light_pdf is not None else np.zeros(len(p)) for p in parts]),
        max(p.direct_count for p in parts),
        next((p.env_guide for p in parts if p.env_guide is not None), None),
        next((p.emitter_pmf for p in parts if p.emitter_pmf is not None), None),
    )
