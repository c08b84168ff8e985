"""VPLs distributed by their contribution to the image (Georgiev & Slusallek 2010, "Simple
and robust iterative importance sampling of virtual point lights").

Plain instant radiosity puts VPLs wherever light walks go. In a room lit through a door or a
window most walks stay where the camera does not look, and the few VPLs that reach the visible
room carry huge flux. Here each set draws ``vpl_oversample`` times as many candidate walks
(the same quasi-random light walks, from the same Sobol stream block), measures each candidate
VPL's contribution Φ_j to a small set of camera-visible points (the view's end points, traced
like the eye paths), and keeps candidate j with probability

    p_j = clamp(Φ_j / τ, ε, 1),   τ chosen so that Σ p_j = the plain set's VPL count,

re-weighting a kept VPL's power by 1/p_j. Given the candidates, E[B_j / p_j] = 1 for the
Bernoulli acceptance B_j, so the estimate of every pixel stays unbiased (ε > 0 keeps VPLs the
camera points miss possible); only the variance moves. Everything is a function of (scene,
seed, k, parameters, camera): every worker builds the same P_k with no communication.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from igi.common.camera import camera_rays
from igi.common.geometry import Geometry
from igi.common.lights import VPL_SURFACE, LightSampler
from igi.common.scene import AREA, POINT, SPOT, Scene
from igi.common.sobol_stream import rng as make_rng

from .env_guide import ENV_SAMPLES, build_guide, guide_environment_samples, only_environment, single_environment
from .kernels import vpl_scoring as vs
from .portals import Portals, find_portals
from .shading import EndPoints, contribution_per_vpl, trace_eye
from .vpl import VPLSet, build_vpl_rows, emitter_vpls, sets_of, subset_vpls

CAMERA_POINTS = 256  # eye paths per set that score the candidates
# Shadow rays per candidate VPL for its score: its visibility from the camera points is
# estimated from this many of its (point, VPL) pairs drawn by their unshadowed light, not all
# 256 (the scoring was a quarter of a set's build; the acceptance needs the score only roughly).
VISIBILITY_SAMPLES = 32
EPSILON = 0.02  # lowest acceptance probability: VPLs the camera points miss stay possible
# Half the kept VPLs by importance, half as plain instant radiosity would keep them: a kept VPL
# never weighs more than twice a plain one, however badly the camera points scored it.
MIX = 0.5
# Auto mode: off only when a pilot set's candidates matter almost equally to the view (nothing
# to gain); measured, importance sampling halves single-frame error even on the Cornell box.
AUTO_ESS = 0.9


@dataclass(frozen=True)
class View:
    """What the importance depends on: the camera (world matrix, fov) and film size."""

    to_world: tuple
    fov_x: float
    width: int
    height: int

    @staticmethod
    def of(camera_to_world, fov_x: float, width: int, height: int) -> "View":
        """The view of a camera-to-world matrix (4×4 or 16 numbers)."""
        return View(tuple(np.asarray(camera_to_world, np.float64).ravel()), fov_x, width, height)

    @cached_property
    def key(self) -> tuple:
        """The view rounded to 1e-9 (a hashable key of per-view results); made once per View —
        every task of a frame asks it several times, ~60 µs each."""
        return (tuple(round(float(v), 9) for v in self.to_world), round(float(self.fov_x), 9),
                self.width, self.height)


@dataclass(frozen=True)
class ImportanceStats:
    candidates: int  # candidate indirect VPLs
    accepted: int
    ess: float  # effective sample share of the candidates' contributions (1 = all equal)


def camera_end_points(scene: Scene, geom: Geometry, lights: LightSampler, view: View, seed: int,
                      k: int, count: int, max_depth: int, specular_depth: int,
                      glossy_split_alpha: float = 0.0):
    """End points of ``count`` eye paths through random pixels of the view (deterministic in
    (seed, k), so all workers score candidates alike); ``pixel`` is the path's index."""
    g = make_rng(seed, k, "camera points")
    px = np.floor(g.random(count) * view.width)
    py = np.floor(g.random(count) * view.height)
    o, d = camera_rays(np.asarray(view.to_world, np.float64).reshape(4, 4), view.fov_x, view.width,
                       view.height, px, py, g.random((count, 2)))
    return trace_eye(scene, geom, lights, o, d, max_depth, specular_depth, g, glossy_split_alpha).end


# Eye paths traced once per view; every set draws its camera points from them. Tracing 256
# fresh paths per set cost a quarter of a set's build (their glass and mirror chains are many
# small batches); drawing a different subset per (seed, k) keeps the sets' scores varied.
POOL_PATHS = 8192


@dataclass(frozen=True)
class CameraPool:
    """End points of ``paths`` eye paths through uniformly random pixels of one view."""

    end: EndPoints
    paths: int

    def first(self, count: int) -> EndPoints:
        """The end points of the first ``count`` paths (a uniform sample of the view's pixels)."""
        return self.end.subset(np.nonzero(self.end.pixel < count)[0])

    def draw(self, seed: int, k: int, count: int) -> EndPoints:
        """The end points of ``count`` paths drawn without replacement for set (seed, k)."""
        if count >= self.paths:
            return self.end
        return self.end.subset(self.draw_rows(seed, k, count))

    def draw_rows(self, seed: int, k: int, count: int) -> np.ndarray:
        """The rows of ``end`` that :meth:`draw` takes for set (seed, k)."""
        if count >= self.paths:
            return np.arange(len(self.end))
        take = np.zeros(self.paths, bool)
        take[make_rng(seed, k, "camera pool").choice(self.paths, count, replace=False)] = True
        return np.nonzero(take[self.end.pixel])[0]

    def draw_sets(self, seed: int, ks: Sequence[int], count: int) -> tuple[EndPoints, list[EndPoints]]:
        """:meth:`draw` for every k of ``ks``, copied out of the pool in one go: (all of them in
        order, each set's as a view of that)."""
        rows = [self.draw_rows(seed, k, count) for k in ks]
        drawn = self.end.subset(np.concatenate(rows))
        stops = np.cumsum([len(r) for r in rows])
        return drawn, [drawn.subset(slice(int(b - len(r)), int(b))) for r, b in zip(rows, stops)]


def camera_pool(scene: Scene, geom: Geometry, lights: LightSampler, view: View, max_depth: int,
                specular_depth: int, glossy_split_alpha: float = 0.0, paths: int = POOL_PATHS,
                seed: int = 0, k: int = 0) -> CameraPool:
    """The view's camera-point pool (the view's is seed 0, k 0: the same in every worker)."""
    return CameraPool(camera_end_points(scene, geom, lights, view, seed, k, paths, max_depth, specular_depth,
                                        glossy_split_alpha), paths)


PORTAL_POINTS = 1024  # camera points whose escaped rays find the openings (once per view)


def view_portals(scene: Scene, geom: Geometry, lights: LightSampler, view: View, max_depth: int,
                 specular_depth: int, glossy_split_alpha: float = 0.0,
                 pool: CameraPool | None = None) -> Portals | None:
    """The openings through which the view sees its sky (worker.portals), from the escaped rays
    of camera points drawn once per view (seed 0): None without a single environment emitter or
    an enclosure around the view. ``pool``: the view's camera pool (None: traced here)."""
    ei = single_environment(scene, lights)
    if ei < 0:
        return None
    if pool is None:
        pool = camera_pool(scene, geom, lights, view, max_depth, specular_depth, glossy_split_alpha, PORTAL_POINTS)
    end = pool.first(PORTAL_POINTS)
    guide = build_guide(scene, geom, lights, end, make_rng(0, 0, "portal rays"))
    if guide is None or guide.escape_origin is None:
        return None
    return find_portals(geom, lights, ei, guide.escape_origin, guide.escape_direction)


EMITTER_POINTS = 1024  # emitter samples, over all emitters, that score their light on the view
MAX_SCORED_EMITTERS = 512  # beyond this many emitters the choice stays by power
EMITTER_MIX = 0.5  # share of the emitter choice made by the view; the rest stays by power


def view_emitter_pmf(scene: Scene, geom: Geometry, lights: LightSampler, view: View, max_depth: int,
                     specular_depth: int, clamp_d2: float, glossy_split_alpha: float = 0.0,
                     lobe_alpha: float = 0.0, samples_per_set: int = 0,
                     pool: CameraPool | None = None) -> np.ndarray | None:
    """How the emitter samples of this view's sets choose their emitter: half by power (as
    ``lights.pmf``), half by each emitter's direct light on camera points (shadow rays
    included), scored once per view from seed 0 so every worker gets the same pmf.

    Choosing by power alone ignores distance: in a hall lit by a few huge panels and many small
    lamps, the wall beside a small lamp is lit mostly by it, yet it is drawn in a few percent of
    the samples, so a frame's light there is usually too dark and sometimes far too bright (the
    frames' low-frequency error). The environment keeps its share (its guided samples divide by
    it). None (by power) when fewer than two emitters could use the view's score, or when they
    are no more than a set's ``samples_per_set`` emitter samples: a set's Sobol-stratified draws
    then give each emitter a steady count (2 + 2 of 4 at even power), which any other choice
    unsettles (veach-bidir's direct light: 2-6x the noise at 0.56 / 0.44).
    """
    pmf = lights.pmf
    cand = np.nonzero((pmf > 0) & np.array([e.kind in (AREA, POINT, SPOT) for e in scene.emitters], bool))[0]
    if len(cand) < 2 or len(cand) <= samples_per_set or len(cand) > MAX_SCORED_EMITTERS:
        return None
    if pool is None:
        pool = camera_pool(scene, geom, lights, view, max_depth, specular_depth, glossy_split_alpha,
                           CAMERA_POINTS * 2)
    end = pool.first(CAMERA_POINTS * 2)
    if len(end) == 0:
        return None
    per = max(4, EMITTER_POINTS // len(cand))
    em = np.repeat(cand, per)
    u = make_rng(0, 0, "emitter scores").random((len(em), 2))
    u[:, 0] = (np.tile(np.arange(per), len(cand)) + u[:, 0]) / per  # stratified over each emitter
    samples = emitter_vpls(scene, lights.points_on(em, u), per, mis=False)
    phi = contribution_per_vpl(geom, end, samples, clamp_d2, max_depth, lobe_alpha)
    score = np.bincount(np.searchsorted(cand, em), weights=phi, minlength=len(cand))
    total = float(score.sum())
    if not np.isfinite(total) or total <= 0:
        return None
    share = float(pmf[cand].sum())  # what these emitters hold now; the others keep theirs
    out = pmf.copy()
    out[cand] = (1 - EMITTER_MIX) * pmf[cand] + EMITTER_MIX * share * score / total
    return out


def effective_share(phi: np.ndarray) -> float:
    """(ΣΦ)² / (n ΣΦ²): 1 when all candidates matter equally, 1/n when one carries all."""
    s2 = float(np.sum(phi * phi))
    if len(phi) == 0 or s2 <= 0:
        return 0.0
    return float(np.sum(phi)) ** 2 / (len(phi) * s2)


def acceptance(phi: np.ndarray, target: float, mix: float = 1.0, epsilon: float = EPSILON) -> np.ndarray:
    """p_j = min(1, mix·Φ_j/τ + (1 - mix)·target/n), at least ε, with τ such that Σ p_j ≈ target.

    ``mix`` < 1 is a defensive mixture with plain instant radiosity's uniform acceptance: a
    kept VPL then weighs at most n / ((1 - mix)·target) candidates, however badly the camera
    points scored it. No contribution anywhere (nothing lit in view): uniform target/n."""
    n = len(phi)
    if n == 0:
        return np.zeros(0)
    if target >= n:
        return np.ones(n)
    eps = min(epsilon, 0.5 * target / n)
    floor = max(eps, (1.0 - mix) * target / n)
    phi = np.where(np.isfinite(phi) & (phi > 0), phi, 0.0)
    if not np.any(phi > 0) or mix <= 0:
        return np.full(n, target / n)
    # Σ_j min(1, floor + a_j/τ) = target, a = mix·Φ, solved exactly (kernels.vpl_scoring.acceptance).
    out = np.empty(n)
    if not vs.acceptance(phi, float(target), float(mix), float(floor), out):
        return np.where(phi > 0, 1.0, floor)  # too few lit candidates to reach the target: keep every lit one
    return out


def systematic_keep(p: np.ndarray, u: float) -> np.ndarray:
    """Which candidates to keep, each with probability min(p, 1), by systematic sampling: one
    uniform ``u`` offsets the running sum of the probabilities and a candidate is kept where the
    sum passes an integer. Each is kept with exactly its probability (so the 1/p weights stay
    unbiased) and the number kept is within one of Σp, where independent coin flips let it
    wander by its square root."""
    q = np.minimum(np.asarray(p, np.float64), 1.0)
    c = np.cumsum(q) + u
    return np.floor(c) > np.floor(c - q)


def build_importance_vpl_set(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, k: int,
                             *args, **kwargs) -> tuple[VPLSet, ImportanceStats]:
    """P_k with its indirect VPLs importance-sampled for the view: :func:`build_importance_vpl_sets`
    (same further arguments) for the one block k."""
    return build_importance_vpl_sets(scene, geom, lights, seed, [k], *args, **kwargs)[0]


def build_importance_vpl_sets(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, ks: Sequence[int],
                              direct_vpls: int, indirect_vpls: int, max_length: int, view: View,
                              oversample: int, clamp_d2: float, max_depth: int, specular_depth: int,
                              roulette: bool = False, camera_points: int = CAMERA_POINTS,
                              glossy_split_alpha: float = 0.0,
                              lobe_alpha: float = 0.0, portals: Portals | None = None,
                              emitter_pmf: np.ndarray | None = None, pool: CameraPool | None = None,
                              ) -> list[tuple[VPLSet, ImportanceStats]]:
    """P_k of every block k of ``ks`` with its indirect VPLs importance-sampled for ``view``
    (see the module docstring), each set as it is alone, built together: one candidate build
    (vpl.build_vpl_rows) and one scoring call in which each set's candidates meet only its own
    camera points. ``portals`` (:func:`view_portals`): walks from the sky start where it enters
    the view; ``emitter_pmf`` (:func:`view_emitter_pmf`): the emitter samples' choice of
    emitter; ``pool`` (:func:`camera_pool`): the view's camera points (None: traced per set)."""
    if direct_vpls > 0 and only_environment(scene, lights):
        direct_vpls = max(direct_vpls, ENV_SAMPLES)
    if pool is not None:
        drawn, ends = pool.draw_sets(seed, ks, camera_points)
    else:
        drawn, ends = None, [camera_pool(scene, geom, lights, view, max_depth, specular_depth, glossy_split_alpha,
                                         camera_points, seed, k).draw(seed, k, camera_points) for k in ks]
    joined, set_rows = build_vpl_rows(scene, geom, lights, seed, ks, direct_vpls, indirect_vpls * oversample,
                                      max_length, roulette=roulette, portals=portals, emitter_pmf=emitter_pmf)
    cands = sets_of(joined, set_rows)
    sky = single_environment(scene, lights) >= 0
    for k, end, cand in zip(ks, ends, cands):
        # The sky seen through openings: environment samples drawn where camera points see it
        # (and light walks from the sky started where it enters: the portals).
        guide = build_guide(scene, geom, lights, end, make_rng(seed, k, "env guide rays")) if sky else None
        if guide is not None:
            guide_environment_samples(cand, lights, guide, direct_vpls, make_rng(seed, k, "env guide samples"))
            cand.env_guide = guide
    surfs = [np.nonzero(c.kind == VPL_SURFACE)[0] for c in cands]
    # Every set's surface candidates in one copy (the guide redraws environment samples only).
    scored = subset_vpls(joined, np.concatenate([r[s] for r, s in zip(set_rows, surfs)]))
    phis = _score(geom, ks, seed, ends, [len(s) for s in surfs], scored, clamp_d2, max_depth, lobe_alpha, drawn)
    out = []
    for k, cand, surf, phi in zip(ks, cands, surfs, phis):
        if len(surf) == 0:
            out.append((cand, ImportanceStats(0, 0, 0.0)))
            continue
        target = len(surf) / oversample
        p = acceptance(phi, target, MIX)
        keep = systematic_keep(p, make_rng(seed, k, "vpl acceptance").random())
        rows = np.concatenate([np.nonzero(cand.kind != VPL_SURFACE)[0], surf[keep]])
        scale = np.ones(len(cand))
        scale[surf[keep]] = 1.0 / p[keep]
        out.append((subset_vpls(cand, np.sort(rows), power_scale=scale),
                    ImportanceStats(len(surf), int(keep.sum()), effective_share(phi))))
    return out


def _score(geom: Geometry, ks: Sequence[int], seed: int, ends: list[EndPoints], counts: list[int], cands: VPLSet,
           clamp_d2: float, max_depth: int, lobe_alpha: float, drawn: EndPoints | None = None) -> list[np.ndarray]:
    """Each set's candidate contributions Φ to its own camera points, all sets in one
    contribution_per_vpl call (end points of set i score only the columns of set i): ``cands``
    holds every set's candidates in order, ``counts[i]`` of set i.
    ``drawn``: all of ``ends`` in one (CameraPool.draw_sets), used as is when every set scores."""
    sizes = np.array(counts, np.int64)
    stops = np.cumsum(sizes)
    live = [i for i in range(len(sizes)) if sizes[i] and len(ends[i])]
    phi = np.zeros(int(stops[-1]) if len(stops) else 0)
    if live:
        lo = np.concatenate([np.full(len(ends[i]), stops[i] - sizes[i], np.int64) for i in live])
        hi = np.concatenate([np.full(len(ends[i]), stops[i], np.int64) for i in live])
        column_u = np.concatenate([make_rng(seed, k, "visibility samples").random(c) for k, c in zip(ks, counts)])
        end = drawn if drawn is not None and len(live) == len(sizes) else EndPoints.concat([ends[i] for i in live])
        phi = contribution_per_vpl(geom, end, cands, clamp_d2, max_depth, lobe_alpha, None, VISIBILITY_SAMPLES,
                                   (lo, hi), column_u)
    return np.split(phi, stops[:-1])
