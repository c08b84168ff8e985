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
  chain meets a non-specular surface.

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
from igi.common.lights import VPL_SURFACE, LightSampler, to_local
from igi.common.scene import NULL, SPECULAR_KINDS, Scene, kind_in

from .caustics import PhotonSet, gather_photons
from .regularization import regularization_gain, regularized_senders
from .shading import BSDFRays, EndPoints, bsdf_direct, gather_vpls, trace_bsdf_rays
from .vpl import VPLSet

# In a crease most of y's own short rays meet a surface again, so from level 2 on (y's own
# compensation) a near hit goes on with probability 1/2 (Russian roulette, weight 2).
COMPENSATION_ROULETTE_LEVEL = 2
COMPENSATION_MAX_LEVEL = 3  # deeper levels hold ~0.1% of the light (furnace at a 0.2 clamp) for ~1/5 of the cost


@dataclass
class Arrivals:
    """Surface points y reached by rays, each sending its light back to a receiver: the
    receiver's row ``parent`` gets ``factor`` × the radiance y reflects along -``direction``."""

    position: np.ndarray  # (n, 3)
    ns: np.ndarray  # (n, 3)
    ng: np.ndarray  # (n, 3)
    material: np.ndarray  # (n,) material index (negative: none)
    uv: np.ndarray  # (n, 2)
    t: np.ndarray  # (n,) ray length to y
    direction: np.ndarray  # (n, 3) world direction of the ray that reached y
    segments: np.ndarray  # (n,) eye segments once y is reached
    parent: np.ndarray  # (n,) receiver row
    factor: np.ndarray  # (n, 3) sample weight toward the receiver
    level: np.ndarray  # (n,) compensation level of y (0: y's own clamped light is not compensated)

    def __len__(self) -> int:
        return len(self.parent)

    @staticmethod
    def concat(parts: "list[Arrivals | None]") -> "Arrivals | None":
        """The arrivals of ``parts`` in order (None: there are none)."""
        parts = [p for p in parts if p is not None and len(p)]
        if len(parts) <= 1:
            return parts[0] if parts else None
        return Arrivals(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))

    def rows(self, idx: np.ndarray) -> "Arrivals":
        return Arrivals(*(getattr(self, f).take(idx, axis=0) for f in _FIELDS))


_FIELDS = tuple(Arrivals.__dataclass_fields__)


def compensation_enabled(vpls: VPLSet, clamp_d2: float) -> bool:
    """Whether the clamp took anything: a positive clamp and surface VPLs to clamp."""
    return clamp_d2 > 0 and bool(np.any(vpls.kind == VPL_SURFACE))


def near_arrivals(end: EndPoints, rays: BSDFRays, level: np.ndarray | int, clamp_d2: float, max_depth: int,
                  rng: np.random.Generator) -> Arrivals | None:
    """The points y that the traced continuation ``rays`` of ``end`` met closer than the clamp
    radius, for the end points of compensation ``level`` > 0 (per end point, or one for all):
    factor = BSDF weight × clamped share (1 - d²/c) / survival. Rows of a level at or past
    COMPENSATION_ROULETTE_LEVEL go on with probability 1/2. None when there are none."""
    ok, hits = rays.rows, rays.hits
    if len(ok) == 0:
        return None
    lv = np.broadcast_to(np.asarray(level, np.int64), (len(end),))[ok]
    near = hits.valid & (hits.t < np.sqrt(clamp_d2)) & ~rays.delta & (lv > 0)  # a delta sample meets no clamped VPL
    if max_depth >= 0:
        near &= end.segments[ok] + 2 <= max_depth
    rolled = lv >= COMPENSATION_ROULETTE_LEVEL
    if rolled.any():
        near &= ~rolled | (rng.random(len(near)) < 0.5)
    sel = np.nonzero(near)[0]
    if len(sel) == 0:
        return None
    t = hits.t[sel]
    share = np.clip(1.0 - t * t / clamp_d2, 0.0, 1.0) / np.where(rolled[sel], 0.5, 1.0)
    child = np.where(lv[sel] < COMPENSATION_MAX_LEVEL, lv[sel] + 1, 0)
    return Arrivals(hits.position[sel], hits.ns[sel], hits.ng[sel], hits.material[sel], hits.uv[sel], t,
                    rays.direction[sel], end.segments[ok[sel]] + 1, ok[sel], rays.weight[sel] * share[:, None], child)


@dataclass
class _Level:
    points: Arrivals | None  # the level's non-specular points (None: the end points themselves)
    end: EndPoints  # the same as end points (unit throughput) for the BSDF rays
    rays: BSDFRays
    gain: np.ndarray | None  # (n, 3) regularization gain of the widened lobes (None: none widened)


def _as_end_points(scene: Scene, arr: Arrivals, lobe_alpha: float) -> tuple[Arrivals, EndPoints, np.ndarray | None]:
    """The points of ``arr`` that reflect (not mirror/glass, not NULL), as end points with their
    lobes regularized as senders, and the regularization's gain (None: no lobe widened)."""
    orig = bsdf.gather(scene.materials, arr.material, arr.uv)
    sp = regularized_senders(orig, lobe_alpha)
    nd = np.nonzero(~kind_in(sp.kind, SPECULAR_KINDS) & (sp.kind != NULL))[0]
    if len(nd) < len(arr):
        arr, sp = arr.rows(nd), sp.subset(nd)
    n = len(arr)
    wo = to_local(-arr.direction, arr.ns)
    gain = regularization_gain(orig.subset(nd), sp, wo) if sp is not orig and n else None
    return arr, EndPoints(np.arange(n), arr.position, arr.ns, arr.ng, wo, sp, np.ones((n, 3)), arr.segments,
                          np.ones(n, bool), arr.t), gain


def _concat_rays(levels: list[_Level]) -> BSDFRays:
    base = np.cumsum([0] + [len(lv.end) for lv in levels[:-1]])
    return BSDFRays(np.concatenate([lv.rays.rows + b for lv, b in zip(levels, base)]),
                    *(np.concatenate([getattr(lv.rays, f) for lv in levels]) for f in ("weight", "pdf", "delta",
                                                                                          "direction")),
                    Hits.concat([lv.rays.hits for lv in levels]))


def final_gather(scene: Scene, geom: Geometry, lights: LightSampler, end: EndPoints, rays: BSDFRays,
                 first: Arrivals | None, vpls: VPLSet, clamp_d2: float, max_depth: int, rng: np.random.Generator,
                 lobe_alpha: float = 0.0, photons: PhotonSet | None = None, shadow_roulette: float = 0.0,
                 force_general: bool = False, lobe_lights: int = 0,
                 stage: Callable[[str], AbstractContextManager] = lambda _name: nullcontext(),
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The light at the end points ``end``, split as (albedo, irradiance) as gather_vpls splits
    it: the VPL set's (gather_vpls; ``force_general``, ``lobe_lights``, ``shadow_roulette`` as
    there), BSDF-direct light along their traced continuation ``rays`` (trace_bsdf_rays), the
    caustic ``photons``, and Σ factor × L_y over the points y of ``first`` (Arrivals: parent =
    end point row), L_y the radiance y reflects back along its ray — the VPL set's light and the
    emitter samples at y with y's own MIS-weighted BSDF ray, the caustic photons there (L S+ D:
    the light walks behind the VPLs pass through glass, so the VPLs stand for it too), and for
    a point of compensation level > 0 the compensation of its own clamp (its near points,
    recursively); y's emission is not included. The end points and every level's y are
    shaded in one batch. ``stage``: a context manager per named step (Renderer's stage timer)."""
    levels: list[_Level] = [_Level(None, end, rays, None)]
    with stage("final gather points"):
        arr = first
        compensate = compensation_enabled(vpls, clamp_d2)
        short = np.sqrt(clamp_d2) if compensate else 0.0
        while arr is not None and len(arr):
            arr, y, gain = _as_end_points(scene, arr, lobe_alpha)
            if len(arr) == 0:
                break
            # y's continuation rays serve its BSDF-direct light and, when compensated, its near
            # points; the others' reach only emitters (those that provably reach none are traced 0 far)
            lv = arr.level if compensate else np.zeros(len(arr), np.int64)
            y_rays = trace_bsdf_rays(geom, lights, y, max_depth, rng, np.where(lv > 0, short, 0.0))
            levels.append(_Level(arr, y, y_rays, gain))
            arr = near_arrivals(y, y_rays, lv, clamp_d2, max_depth, rng) if compensate and lv.any() else None
        points = EndPoints.concat([lv.end for lv in levels]) if len(levels) > 1 else end
        all_rays = _concat_rays(levels) if len(levels) > 1 else rays
    with stage("VPL gather"):
        albedo, irr = gather_vpls(geom, points, vpls, clamp_d2, max_depth, force_general=force_general,
                                  lobe_alpha=lobe_alpha, shadow_roulette=shadow_roulette,
                                  seed=int(rng.integers(1 << 62)), lobe_lights=lobe_lights)
    with stage("BSDF direct"):
        irr += bsdf_direct(scene, geom, lights, points, albedo, vpls.direct_count, max_depth, rng, vpls.env_guide,
                           all_rays, vpls.emitter_pmf)
    if photons is not None and len(photons):
        with stage("photon gather"):
            irr += gather_photons(points, photons, albedo, max_depth)
    carry_back([len(lv.end) for lv in levels], [lv.points.parent for lv in levels[1:]],
               [lv.points.factor for lv in levels[1:]], [lv.gain for lv in levels[1:]], albedo, irr)
    e = len(end)
    return albedo[:e], irr[:e]


def carry_back(sizes: list[int], parent: list[np.ndarray], factor: list[np.ndarray], gain: list[np.ndarray | None],
               albedo: np.ndarray, irr: np.ndarray) -> None:
    """Add each level's light to its parents' irradiance, in place, deepest level first (a
    point's light is complete once its own near points' is in): the points of level i ≥ 1 (rows
    ``sizes[0] + … + sizes[i-1]`` on of ``albedo``/``irr``, level 0 the end points) send
    factor × gain × albedo × irradiance to row ``parent[i-1]`` of level i - 1, per unit of
    that parent's albedo. A parent may take several (an end point's near point and chain end)."""
    stops = np.cumsum([0, *sizes])
    for i in range(len(sizes) - 1, 0, -1):
        radiance = albedo[stops[i]:stops[i + 1]] * irr[stops[i]:stops[i + 1]]
        if gain[i - 1] is not None:  # reciprocity: the lobe toward x keeps the energy of the one from x
            radiance *= gain[i - 1]
        rows = stops[i - 1] + parent[i - 1]
        np.add.at(irr, rows, bsdf.finite_or_zero(factor[i - 1] * radiance / np.maximum(albedo[rows], 1e-6)))
