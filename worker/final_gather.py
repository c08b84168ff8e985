"""The final gather: the light that surfaces y one BSDF ray away from the end points x reflect
back toward them, for two estimators that both ask for it:

- the clamp compensation (Kollig & Keller 2004, "Illumination in the presence of weak
  singularities"; pbrt-v2's igi integrator): the clamp replaces 1/d² by 1/max(d², c) for
  surface VPLs, i.e. it drops the fraction (1 - d²/c) of the light a point y closer than √c
  sends to x. A BSDF-sampled ray from x limited to √c finds such points; the radiance leaving
  y toward x (VPLs and emitters at y, with y's own MIS ray) times (1 - d²/c) times the sample
  weight is exactly that share. y is lit by a clamped gather too, so its own near points are
  compensated in turn (levels below);
- the lensed chains (worker.indirect_caustics): the point where an end point's mirror/glass
  chain meets a non-specular surface — which follows a chain of its own in turn
  (:func:`lensed_levels`: light that crosses glass twice between diffuse bounces).

Every level's points are found first (a level's BSDF rays find the next level's near points),
then all of them are shaded in one batch with the end points themselves — one VPL gather, one
BSDF-direct and one photon lookup per tile instead of one each per level and estimator (at
320×240 a tile's five small batches were mostly per-call overhead) — and their light is carried
back level by level to the end points. Each point's estimate is the one a gather of its own
level alone would make; only which random numbers it draws differs.

y reflects light toward x as a VPL would: its microfacet lobes are regularized like the VPL
senders' (worker.regularization, ``lobe_alpha``), or a smooth plastic at y (α 0.01) turns one
caustic photon or VPL near its mirror direction into a spike of ~10³ times the pixel's light
that the discontinuity buffer spreads over a whole interleave block.
"""
from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry, Hits
from igi.common.kernels.ray_packets import hit_buffers
from igi.common.lights import VPL_SURFACE, LightSampler, to_local
from igi.common.scene import ROUGHDIELECTRIC_R, ROUGHDIELECTRIC_T, Scene, kind_in, reflecting

from .arrivals import Arrivals
from .caustics import PhotonSet, gather_photons
from .indirect_caustics import lensed_arrivals
from .kernels import final_gather_levels as flv
from .regularization import regularization_gain, regularized_senders, sender_rows
from .shading import BSDFRays, EndPoints, LightMIS, add_bsdf_direct, gather_vpls, trace_bsdf_rays
from .vpl import VPLSet

# In a crease most of y's own short rays meet a surface again, so from level 2 on (y's own
# compensation) a near hit goes on with probability 1/2 (Russian roulette, weight 2).
COMPENSATION_ROULETTE_LEVEL = 2
COMPENSATION_MAX_LEVEL = 3  # deeper levels hold ~0.1% of the light (furnace at a 0.2 clamp) for ~1/5 of the cost
# Mirror/glass chains followed behind an end point, its own included (lensed_levels).
LENSED_DEPTH = 4


def compensation_enabled(vpls: VPLSet, clamp_d2: float) -> bool:
    """Whether the clamp took anything: a positive clamp and surface VPLs to clamp (whether the
    set has any: worked out once per set, asked twice per tile)."""
    if clamp_d2 <= 0:
        return False
    surface = vpls.derived.get("has surface VPLs")
    if surface is None:
        surface = vpls.derived["has surface VPLs"] = bool(np.any(vpls.kind == VPL_SURFACE))
    return surface


def near_arrivals(end: EndPoints, rays: BSDFRays, level: np.ndarray | int, clamp_d2: float, max_depth: int,
                  rng: np.random.Generator) -> Arrivals | None:
    """The points y that the traced continuation ``rays`` of ``end`` met closer than the clamp
    radius, for the end points of compensation ``level`` > 0 (per end point, or one for all):
    factor = BSDF weight × clamped share (1 - d²/c) / survival. Rows of a level at or past
    COMPENSATION_ROULETTE_LEVEL go on with probability 1/2. None when there are none."""
    ok, hits = rays.rows, rays.hits
    if len(ok) == 0:
        return None
    if np.ndim(level) == 0:
        rolled = int(level) >= COMPENSATION_ROULETTE_LEVEL
        level = np.full(len(end), int(level), np.int64)
    else:
        level = np.ascontiguousarray(level, np.int64)
        rolled = bool(np.any(level[ok] >= COMPENSATION_ROULETTE_LEVEL))
    u = rng.random(len(ok)) if rolled else np.empty(0)  # one uniform per ray once any level rolls
    sel, share, child = np.empty(len(ok), np.int64), np.empty(len(ok)), np.empty(len(ok), np.int64)
    n = flv.near_points(ok, hits.valid, hits.t, rays.delta, level, end.segments, u, float(np.sqrt(clamp_d2)),
                        float(clamp_d2), int(max_depth), COMPENSATION_ROULETTE_LEVEL, COMPENSATION_MAX_LEVEL, sel,
                        share, child)
    if n == 0:
        return None
    sel = sel[:n]
    return Arrivals(hits.position[sel], hits.ns[sel], hits.ng[sel], hits.material[sel], hits.uv[sel], hits.t[sel],
                    rays.direction[sel], end.segments[ok[sel]] + 1, ok[sel], rays.weight[sel] * share[:n, None],
                    child[:n])


@dataclass
class Levels:
    """What the final gather found behind the end points: every level's points y in order (as
    end points with unit throughput, lobes regularized as senders), their BSDF rays (rows into
    ``y``), and per level its size, its points' parent rows (in the level before; level 0's in
    the end points), weights toward them and regularization gains (None: no lobe widened)."""

    y: EndPoints
    rays: BSDFRays
    sizes: list[int]
    parents: list[np.ndarray]
    factors: list[np.ndarray]
    gains: list[np.ndarray | None]


def find_levels(scene: Scene, geom: Geometry, lights: LightSampler, first: Arrivals | None, vpls: VPLSet,
                clamp_d2: float, max_depth: int, rng: np.random.Generator, lobe_alpha: float = 0.0,
                targets: tuple[np.ndarray, np.ndarray] | None = None) -> Levels | None:
    """The points y of ``first`` that reflect, their continuation rays and, for compensated
    points, the near points those rays find, level by level (None: no point reflects). A
    level's rays serve its BSDF-direct light, the chains of the mirror/glass ``targets``
    (bounding spheres: the rays that may meet one are traced in full for :func:`lensed_levels`)
    and, when compensated, its near points; the others reach only emitters (those that provably
    reach none are traced 0 far). Compiled in one call
    (kernels.final_gather_levels: the same draws, points, rays and hits); level by level in
    numpy where the rays must pass through Geometry.intersect."""
    if first is None or len(first) == 0:
        return None
    compensate = compensation_enabled(vpls, clamp_d2)
    compiled = _compiled_levels(scene, geom, lights, first, compensate, clamp_d2, max_depth, rng, lobe_alpha, targets)
    if compiled is not None:
        return compiled if compiled.sizes else None
    ends, rays, arrivals, gains = [], [], [], []
    arr = first
    short = np.sqrt(clamp_d2) if compensate else 0.0
    while arr is not None and len(arr):
        arr, y, gain = _as_end_points(scene, arr, lobe_alpha)
        if len(arr) == 0:
            break
        lv = arr.level if compensate else np.zeros(len(arr), np.int64)
        y_rays = trace_bsdf_rays(geom, lights, y, max_depth, rng, np.where(lv > 0, short, 0.0), targets)
        ends.append(y)
        rays.append(y_rays)
        arrivals.append(arr)
        gains.append(gain)
        arr = near_arrivals(y, y_rays, lv, clamp_d2, max_depth, rng) if compensate and lv.any() else None
    if not ends:
        return None
    return Levels(EndPoints.concat(ends) if len(ends) > 1 else ends[0], concat_rays(rays, [len(y) for y in ends]),
                  [len(y) for y in ends], [a.parent for a in arrivals], [a.factor for a in arrivals], gains)


def _room_after(f: np.ndarray, rows: int) -> np.ndarray:
    """``f`` with ``rows`` rows of room after it, left untouched (np.concatenate with an empty
    array copied every row of room: ~15 arrays of a tile's capacity, mostly never written)."""
    out = np.empty((len(f) + rows,) + f.shape[1:], f.dtype)
    out[:len(f)] = f
    return out


def _compiled_levels(scene: Scene, geom: Geometry, lights: LightSampler, first: Arrivals, compensate: bool,
                     clamp_d2: float, max_depth: int, rng: np.random.Generator, lobe_alpha: float,
                     targets: tuple[np.ndarray, np.ndarray] | None) -> Levels | None:
    """:func:`find_levels` in one compiled call (kernels.final_gather_levels.find_levels); None
    where its numpy loop must run: rays that must pass through Geometry.intersect (a benchmark
    timing or recording them)."""
    terms = geom.closest_terms()
    if terms is None:
        return None
    P, reflects = sender_rows(scene.materials, lobe_alpha)
    atlas = bsdf.texture_atlas(scene.materials)
    n0 = len(first)
    cap = n0 * (max(COMPENSATION_MAX_LEVEL, 1) + 1) + 1  # each level has at most the points of the one before
    if len(atlas[1]):  # a row of P per point for the texels of its own (the coat tables, 12 and 13, are shared)
        P = tuple(f if i in (12, 13) else _room_after(f, cap) for i, f in enumerate(P))
    points = (np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty(cap, np.int32),
              np.empty((cap, 2)), np.empty(cap), np.empty((cap, 3)), np.empty(cap, np.int64), np.empty(cap, np.int64),
              np.empty((cap, 3)), np.empty(cap, np.int64), np.empty((cap, 3)))
    rays = (np.empty(cap, np.int64), np.empty((cap, 3)), np.empty(cap), np.empty(cap, np.bool_), np.empty((cap, 3)),
            np.empty((cap, 3)))
    hits = hit_buffers(cap)
    level_stop, ray_stop = np.zeros(cap + 1, np.int64), np.zeros(cap + 1, np.int64)
    centres, radii = lights.emitter_spheres()
    reach_all = bool(np.any(lights.environment() > 0)) or len(radii) > 64
    c = np.ascontiguousarray
    level = first.level if compensate else np.zeros(n0, np.int64)
    arrivals = (c(first.position, np.float64), c(first.ns, np.float64), c(first.ng, np.float64),
                c(first.material, np.int32), c(first.uv, np.float64), c(first.t, np.float64),
                c(first.direction, np.float64), c(first.segments, np.int64), c(first.parent, np.int64),
                c(first.factor, np.float64), c(level, np.int64))
    lens_c, lens_r = _NO_TARGETS if targets is None else targets
    count = flv.find_levels(P, reflects, atlas, terms, rng, *geom.offset_terms(),
                            reach_all, c(centres, np.float64), c(np.asarray(radii, np.float64) ** 2),
                            c(lens_c, np.float64).reshape(-1, 3), c(np.asarray(lens_r, np.float64) ** 2),
                            float(clamp_d2), float(np.sqrt(clamp_d2)) if compensate else 0.0, int(max_depth),
                            np.int64(COMPENSATION_ROULETTE_LEVEL), np.int64(COMPENSATION_MAX_LEVEL), arrivals, points,
                            np.empty(cap, np.int64), level_stop, rays, hits, ray_stop)
    n, nr = int(level_stop[count]), int(ray_stop[count])
    geom.counters["intersect_rays"] += nr
    pos, ns, ng, mat, uv, t, _d, seg, parent, factor, _lv, wo = (a[:n] for a in points)
    orig = bsdf.gather(scene.materials, mat, uv)
    sp = regularized_senders(orig, lobe_alpha)
    gain = regularization_gain(orig, sp, wo) if sp is not orig and n else None
    stops = level_stop[:count + 1]
    sizes = [int(b - a) for a, b in zip(stops[:-1], stops[1:])]
    y = EndPoints(np.concatenate([np.arange(k) for k in sizes]) if sizes else np.zeros(0, np.int64), pos, ns, ng, wo,
                  sp, np.ones((n, 3)), seg, np.ones(n, bool), t)
    row, w, pdf, delta, d, _o = (a[:nr] for a in rays)
    _prim, _u, _v, _t, valid, hpos, hng, hns, huv, ht, hmat, hem, hmesh, _tfar = hits
    # rays' rows are their level's: offset to rows of y
    row = row + np.repeat(stops[:-1], np.diff(ray_stop[:count + 1]))
    found_rays = BSDFRays(row, w, pdf, delta, d, Hits(valid[:nr], ht[:nr], _prim[:nr], hpos[:nr], hng[:nr], hns[:nr],
                                                      huv[:nr], hmat[:nr], hem[:nr], hmesh[:nr]))
    per = [slice(int(a), int(b)) for a, b in zip(stops[:-1], stops[1:])]
    return Levels(y, found_rays, sizes, [parent[sl] for sl in per], [factor[sl] for sl in per],
                  [None if gain is None else gain[sl] for sl in per])


def _as_end_points(scene: Scene, arr: Arrivals, lobe_alpha: float) -> tuple[Arrivals, EndPoints, np.ndarray | None]:
    """The points of ``arr`` that reflect (common.scene.reflecting: not mirror/glass, not NULL,
    not black), as end points with their lobes regularized as senders, and the regularization's
    gain (None: no lobe widened)."""
    orig = bsdf.gather(scene.materials, arr.material, arr.uv)
    sp = regularized_senders(orig, lobe_alpha)
    widened = sp is not orig
    nd = np.nonzero(reflecting(scene.materials, sp.kind, arr.material))[0]
    if len(nd) < len(arr):
        arr, sp = arr.rows(nd), sp.subset(nd)
    n = len(arr)
    wo = to_local(-arr.direction, arr.ns)
    gain = regularization_gain(orig.subset(nd), sp, wo) if widened and n else None
    return arr, EndPoints(np.arange(n), arr.position, arr.ns, arr.ng, wo, sp, np.ones((n, 3)), arr.segments,
                          np.ones(n, bool), arr.t), gain


def concat_rays(parts: list[BSDFRays], sizes: list[int]) -> BSDFRays:
    """The rays of ``parts`` in order, part i's rows offset by the ``sizes`` of the parts before."""
    if len(parts) == 1:
        return parts[0]
    base = np.cumsum([0] + list(sizes[:-1]))
    return BSDFRays(np.concatenate([r.rows + b for r, b in zip(parts, base)]),
                    *(np.concatenate([getattr(r, f) for r in parts]) for f in ("weight", "pdf", "delta", "direction")),
                    Hits.concat([r.hits for r in parts]))


def _alone(end: EndPoints) -> np.ndarray:
    """End points that take their shadow roulette alone, not with their pixel's: rough glass's
    light-sample points (design note 48). The roulette guesses their lobes flat (f ~ 1, tens of
    times the light they pass), which would make the pixel's other points look faint and thin
    their shadow rays up to MAX_BOOST times."""
    return kind_in(end.sp.kind, (ROUGHDIELECTRIC_R, ROUGHDIELECTRIC_T))


def final_gather(scene: Scene, geom: Geometry, lights: LightSampler, end: EndPoints, rays: BSDFRays,
                 first: Arrivals | None, vpls: VPLSet, clamp_d2: float, max_depth: int, rng: np.random.Generator,
                 lobe_alpha: float = 0.0, photons: PhotonSet | None = None, shadow_roulette: float = 0.0,
                 force_general: bool = False, lobe_lights: int = 0,
                 stage: Callable[[str], AbstractContextManager] = lambda _name: nullcontext(),
                 lensed: Arrivals | None = None, specular_depth: int = 0,
                 targets: tuple[np.ndarray, np.ndarray] | None = None,
                 sky_map: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The light at the end points ``end``, split as (albedo, irradiance) as gather_vpls splits
    it: the VPL set's (gather_vpls; ``force_general``, ``lobe_lights``, ``shadow_roulette`` as
    there), BSDF-direct light along their traced continuation ``rays`` (trace_bsdf_rays), the
    caustic ``photons``, and Σ factor × L_y over the points y of ``first`` and ``lensed``
    (Arrivals: parent = end point row), L_y the radiance y reflects back along its ray — the
    VPL set's light and the emitter samples at y with y's own MIS-weighted BSDF ray, the
    caustic photons there (L S+ D: the light walks behind the VPLs pass through glass, so the
    VPLs stand for it too), for a point of compensation level > 0 the compensation of its own
    clamp (its near points, recursively: :func:`find_levels`) and, for the ends of the end
    points' mirror/glass chains (``lensed``), given the mirror/glass ``targets`` and a positive
    ``specular_depth``, what reaches y through a chain of its own (:func:`lensed_levels`, seeing
    the sky of ``sky_map``: worker.indirect_caustics.lensed_arrivals); y's emission is not
    included. The end points and every level's y are shaded in one batch.
    ``stage``: a context manager per named step (Renderer's stage timer)."""
    with stage("final gather points"):
        batches, skies = [], []
        found = find_levels(scene, geom, lights, first, vpls, clamp_d2, max_depth, rng, lobe_alpha)
        base = len(end)
        if found is not None:
            batches.append((found, base))
            base += len(found.y)
        if lensed is not None and len(lensed):
            chains = targets is not None and len(targets[1]) > 0 and specular_depth > 0
            more, skies = lensed_levels(scene, geom, lights, lensed, base, vpls, clamp_d2, max_depth, rng, lobe_alpha,
                                        specular_depth, targets if chains else None, sky_map)
            batches += more
        points, ray_sets = end, [(rays, 0)]
        if batches:
            points = EndPoints.concat([end, *(b.y for b, _ in batches)])
            ray_sets += [(b.rays, start) for b, start in batches]  # a batch's rays light its rows start on
    with stage("VPL gather"):
        # the eye's end points share a roulette per pixel; the points beyond them go alone
        pixel = np.full(len(points), -1, np.int64)
        pixel[:len(end)] = np.where(_alone(end), -1, end.pixel)
        albedo, irr = gather_vpls(geom, points, vpls, clamp_d2, max_depth, force_general=force_general,
                                  lobe_alpha=lobe_alpha, shadow_roulette=shadow_roulette,
                                  seed=int(rng.integers(1 << 62)), lobe_lights=lobe_lights, pixel=pixel)
    with stage("BSDF direct"):
        if lights.has_light:
            mis = LightMIS(vpls.direct_count, vpls.env_guide, vpls.emitter_pmf)
            add_bsdf_direct(lights, ray_sets, albedo, mis, irr)
    if photons is not None and len(photons):
        with stage("photon gather"):
            irr += gather_photons(points, photons, albedo, max_depth)
    for start, sky in skies:
        add_sky(irr, albedo, sky, start)
    if batches:
        carry_batches(batches, albedo, irr)
    e = len(end)
    return albedo[:e], irr[:e]


def lensed_levels(scene: Scene, geom: Geometry, lights: LightSampler, lensed: Arrivals, base: int, vpls: VPLSet,
                  clamp_d2: float, max_depth: int, rng: np.random.Generator, lobe_alpha: float, specular_depth: int,
                  targets: tuple[np.ndarray, np.ndarray] | None, sky_map: tuple | None = None
                  ) -> tuple[list[tuple[Levels, int]], list[tuple[int, np.ndarray]]]:
    """Chains of chains. The end of an end point's mirror/glass chain, y, whose own BSDF ray
    meets a mirror or glass surface follows that chain too (worker.indirect_caustics.
    lensed_arrivals) to a point y', whose light (gathered like y's, its own chain in turn)
    reaches y: D S+ D S+ D … paths, which no VPL (its shadow rays stop at glass) and no caustic
    photon (it starts at an emitter) carries — a floor under water lit by the floor itself
    through the surface's total internal reflection, the walls above the water lit by that
    floor. Up to LENSED_DEPTH chains behind an end point (its own, worker.indirect_caustics, is
    the first); from the second on a chain goes on with probability min(1, its largest weight)
    (Russian roulette, weight / probability). None ``targets`` (the mirror/glass objects'
    bounding spheres): the end points' chains only. The points are shaded as rows ``base`` on.
    Returns ([(levels, first row)] per chain depth, [(first row, (n, 3) the environment's
    radiance toward each point of a depth's levels through its chains)])."""
    batches, skies = [], []
    arrivals = lensed
    for depth in range(1, LENSED_DEPTH + 1):
        last = targets is None or depth == LENSED_DEPTH
        found = find_levels(scene, geom, lights, arrivals, vpls, clamp_d2, max_depth, rng, lobe_alpha,
                            None if last else targets)
        if found is None:
            break
        batches.append((found, base))
        if last:
            break
        sky, ends = lensed_arrivals(scene, geom, lights, found.y, found.rays, max_depth, specular_depth, rng,
                                    sky_map)
        if np.any(sky):
            skies.append((base, sky))
        if ends is None:
            break
        q = np.minimum(np.max(ends.factor, axis=1), 1.0)
        keep = np.flatnonzero(rng.random(len(ends)) < q)
        if len(keep) == 0:
            break
        arrivals = ends.rows(keep)
        arrivals.factor = arrivals.factor / q[keep, None]
        arrivals.parent = arrivals.parent + base  # rows of the points shaded, not of the depth's levels
        base += len(found.y)
    return batches, skies


def carry_batches(batches: list[tuple[Levels, int]], albedo: np.ndarray, irr: np.ndarray) -> None:
    """Add each level's light to its parents' irradiance, in place. ``batches``: [(levels, first
    row)] (:func:`find_levels`' Levels; rows from ``first row`` on of ``albedo``/``irr``, the
    end points before them): a batch's first level sends its light to rows of the end points or
    of an earlier batch (its parents are rows of the points shaded), its level i ≥ 1 to its
    level i - 1. Each point sends factor × gain × albedo × irradiance per unit of its parent's
    albedo (summed in point order, as np.add.at sums; compiled: kernels.final_gather_levels.
    carry_level). Levels go newest first: a parent is always older than its children, so a
    point's light is complete (its own near points' and chains' in) when it is sent on."""
    levels = []  # (first row, parents' base row, parents, factors, gains)
    for found, base in batches:
        stops = base + np.cumsum([0, *found.sizes])
        for i in range(len(found.sizes)):
            levels.append((int(stops[i]), 0 if i == 0 else int(stops[i - 1]), found.parents[i], found.factors[i],
                           found.gains[i]))
    for start, parent_base, parent, factor, g in reversed(levels):
        flv.carry_level(start, parent_base, np.ascontiguousarray(parent, np.int64),
                        np.ascontiguousarray(factor, np.float64), _NO_GAIN if g is None else g, albedo, irr)


def add_sky(irr: np.ndarray, albedo: np.ndarray, sky: np.ndarray, start: int = 0) -> None:
    """The environment's radiance seen through points' mirror/glass chains (``sky``, (n, 3),
    already weighted toward them) added to rows ``start`` … of ``irr``, per unit of albedo
    (as the gather splits light); not finite: nothing."""
    rows = slice(start, start + len(sky))
    irr[rows] += bsdf.finite_or_zero(sky / np.maximum(albedo[rows], 1e-6))


_NO_GAIN = np.zeros((0, 3))
_NO_TARGETS = (np.zeros((0, 3)), np.zeros(0))
