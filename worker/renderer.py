"""Renders one task — a tile of sub-image k — into per-pixel buffers.

The worker keeps the VPL set P_k (and photon set C_k) of each (scene version, seed, k) it has
built, so tasks of the same k on the same worker skip the preprocessing (paper §4.2).
"""
from __future__ import annotations

import contextlib
import functools
import threading
import time
from collections import OrderedDict
from dataclasses import replace
from typing import Callable

import numpy as np
from scipy.special import gammaln

from igi.common import bsdf
from igi.common.camera import camera_rays, frame_jitter, lens_jitter
from igi.common.frame import NO_LOBE, FrameSpec, Tile, TileBuffers, accumulation_index, frame_seed
from igi.common.geometry import Geometry
from igi.common.lights import LightSampler
from igi.common.params import Params, make_params
from igi.common.render_plan import analyze
from igi.common.scene import DIFFUSE, GLOSSY_KINDS, PLASTIC, ROUGHPLASTIC_DIFFUSE, Scene, kind_in
from igi.common.sobol_stream import rng as make_rng
from igi.common.specular import specular_targets

from .caustics import (VIEW_SHARE_POINTS, PhotonSet, boosted_photons, build_photon_sets, caustic_share, default_radius,
                       distant_lights, distant_view_share)
from .final_gather import add_sky, compensation_enabled, final_gather, near_arrivals
from .indirect_caustics import lensed_arrivals
from .shading import LightMIS, lobe_light_count, trace_bsdf_rays, trace_eye
from .kernels import tile_buffers
from .set_cache import FrameSets
from .vpl import VPLSet, build_vpl_sets
from .portals import Portals
from .vpl_importance import (AUTO_ESS, CameraPool, View, build_importance_vpl_sets, camera_pool, view_emitter_pmf,
                             view_portals)

DEFAULT_CLAMP = 1e-3  # minimum squared VPL distance, as a fraction of the squared scene diagonal


def radius_scale(index: int, params: Params) -> float:
    """Progressive photon mapping: r_i/r_0 with r²ᵢ₊₁ = r²ᵢ (i + α)/(i + 1), so accumulated
    caustics converge (the averaged estimate is consistent, Knaus & Zwicker 2011)."""
    if index <= 0 or not params.consistent:
        return 1.0
    return _radius_scale(int(index), float(params.ppm_alpha))


@functools.lru_cache(maxsize=256)
def _radius_scale(index: int, a: float) -> float:
    # Π_{j<i} (j+α)/(j+1) = Γ(i+α) / (Γ(α) Γ(i+1))  (asked per tile: three gammaln ~15 µs)
    return float(np.exp(0.5 * (gammaln(index + a) - gammaln(a) - gammaln(index + 1))))


def clamp_distance2(params: Params, diagonal: float) -> float:
    frac = params.clamp if params.clamp >= 0 else DEFAULT_CLAMP
    return frac * diagonal * diagonal


def set_params(params: Params) -> Params:
    """The parameters a frame's VPL sets are built with: a moving camera's frame (shown once:
    its frame rate counts) takes at most ``moving_indirect_vpls`` indirect VPLs; a still
    camera's frames average, error at equal time counts, and they take ``indirect_vpls``."""
    if not params.moving_camera or params.moving_indirect_vpls < 0:
        return params
    return replace(params, indirect_vpls=min(params.indirect_vpls, params.moving_indirect_vpls))


def consistent_frame(params: Params, index: int) -> bool:
    """Whether accumulation frame ``index`` takes the consistent estimators (walks of any
    length, the clamp's energy given back): from the first frame on unless the view is moving
    (the stream's frames at index 0)."""
    return params.consistent and (index > 0 or params.consistent_first_frame)


def frame_clamp_distance2(params: Params, diagonal: float, index: int, consistent: bool) -> float:
    """The squared clamp distance of accumulation frame ``index``: with the clamp's energy
    given back (``consistent``), the larger of the clamp and clamp_first/(index + 1) of the
    squared diagonal — a wide clamp takes the first frames' VPL spikes (their light returns
    through the compensation's BSDF rays, filtered) and narrows to the plain clamp within
    ~clamp_first/clamp frames; without compensation the plain clamp."""
    d2 = clamp_distance2(params, diagonal)
    if not consistent:
        return d2
    return max(d2, params.clamp_first / (index + 1.0) * diagonal * diagonal)


def _set_blocks(keys: list[tuple], params: Params) -> tuple[int, list[int]]:
    """(stream seed, blocks) of the sets ``keys`` ((configuration, frame seed, accumulation
    index), k).

    Accumulated frames continue the first frame's sequence (frame i after a reset with seed
    params.seed has seed params.seed + i): frame i's K sets are blocks [i·K, (i+1)·K) of the
    first frame's streams, so the frames of an accumulation are jointly stratified
    (randomized QMC across frames) rather than independent realizations — and any of them can
    be built ahead, in one batch with the current frame's."""
    (_, seed, index), _ = keys[0]
    if index == 0:  # later frames are offered only while accumulating: one frame, one seed
        if any(frame != keys[0][0] for frame, _ in keys):
            raise ValueError("sets of a first frame are built with their own frame's only")
        return seed, [k for _, k in keys]
    sets = params.interleave ** 2
    return params.seed, [frame[2] * sets + k for frame, k in keys]


LOOKAHEAD_FRAMES = 16  # at most this many later accumulation frames' sets in one batch


def later_frames(seed: int, index: int, params: Params, config: tuple = ()) -> list[tuple]:
    """The set cache's frame keys (``config``, seed, index) of the accumulation frames after
    frame ``index`` whose sets a batch may build ahead (set_cache.FrameSets.get): as many as the
    accumulation has already shown, at most LOOKAHEAD_FRAMES; none for a frame outside the
    master's sequencing."""
    if index <= 0 or seed != frame_seed(params.seed, index):
        return []
    return [(config, frame_seed(params.seed, i), i)
            for i in range(index + 1, index + 1 + min(index, LOOKAHEAD_FRAMES))]


class _StageTimer:
    """Adds a stage's wall time to ``times[name]`` (Renderer.stage_times, benchmarks only)."""

    __slots__ = ("times", "name", "t0")

    def __init__(self, times: dict, name: str):
        self.times, self.name = times, name

    def __enter__(self):
        self.t0 = time.perf_counter()

    def __exit__(self, *exc):
        self.times[self.name] = self.times.get(self.name, 0.0) + time.perf_counter() - self.t0


_NO_STAGE = contextlib.nullcontext()


MAX_VIEW_ENTRIES = 32  # per-view results kept (4 per view: the last 8 views)


class Renderer:
    """Owns the scene's geometry and light sampler, and caches per-set preprocessing."""

    # Profiler hook (``igi bench rays``): a dict to add each render_tile stage's seconds to;
    # None (the default) makes every stage a shared no-op context.
    stage_times: dict | None = None

    def _stage(self, name: str):
        return _NO_STAGE if self.stage_times is None else _StageTimer(self.stage_times, name)

    def __init__(self, scene: Scene, scene_version: int = 0, max_cached_sets: int = 256,
                 use_plan: bool = True):
        self.scene = scene
        self.scene_version = scene_version
        self.geom = Geometry(scene)
        self.geom.shadow_bvh()  # built now, not inside the first frame
        self.geom.interior_bvh()  # (and the one without the walls: common.hull_culling)
        self.lights = LightSampler(scene, self.geom)
        # The plan decides which passes run; use_plan=False forces every pass on (benchmarks).
        self.plan = analyze(scene, self.geom, self.lights) if use_plan else None
        if self.plan is not None and not self.plan.textures:
            self.geom.need_uv = False  # no bitmap is read: skip uv interpolation on every hit
        self._frame_sets = FrameSets(max_cached_sets)
        self._lock = threading.Lock()
        self._task = threading.local()  # per render thread: the running task's ``timings`` (render_tile)
        self._specular_targets = specular_targets(scene, self.geom)  # mirror/glass bounding spheres
        # Per view: importance sampling on? (pilot), the camera pool, the portals, the emitter
        # choice; the most recent views only (a drag visits a new view every frame).
        self._views: OrderedDict[tuple, object] = OrderedDict()
        self._caustic_shares: dict[tuple, float] = {}  # per (photons, chain length): photon_count
        # suns whose photons' count follows their light on the view (caustics.distant_view_share);
        # a map's split into base and peak (its sun) made once, here, and only with mirror/glass
        self._distant_photons = len(self._specular_targets[1]) > 0 and bool(distant_lights(scene, self.lights))
        peak = self.lights.sky_parts()[1] if self._distant_photons else None
        self._sky_base = self.lights.sky_parts()[0] if peak is not None else None
        self.importance_notes = ""
        self.portal_notes = ""
        self.emitter_notes = ""

    # -- per-set preprocessing --------------------------------------------------------------
    def importance_on(self, params: Params, view: View | None) -> bool:
        """Importance-sample this view's VPLs? Auto: a pilot candidate set (seed 0, k 0) scored
        on the view; on when its contributions are uneven (few candidates carry the light)."""
        if view is None or params.vpl_importance == 0 or params.indirect_vpls == 0:
            return False
        if params.vpl_importance == 1:
            return True
        key = ("pilot", self.scene_version, view.key, params.indirect_vpls, params.light_path_length,
               params.vpl_oversample, params.max_depth, params.clamp, params.vpl_lobe_alpha)
        # Decided on plain walks: portal walks even out the candidates they serve.
        st, fresh = self._per_view(key, lambda: self._build_importance(0, [0], params, view, False, pilot=True)[0][1])
        if fresh:
            self.importance_notes = (f"{'ON ' if st.ess < AUTO_ESS else 'off'} vpl_importance      pilot: "
                                     f"effective share {st.ess:.2f} of {st.candidates} candidate VPLs "
                                     f"(on below {AUTO_ESS})")
        return st.ess < AUTO_ESS

    def _per_view(self, key: tuple, compute) -> tuple:
        """(the per-view result under ``key``, whether it was computed now): computed once per
        view, outside the lock (two threads may both compute it; both get equal values)."""
        with self._lock:
            if key in self._views:
                return self._views[key], False
        with self._set_time():  # (set preparation: pilot, camera points, portals)
            value = compute()
        with self._lock:
            self._views[key] = value
            while len(self._views) > MAX_VIEW_ENTRIES:  # the oldest views' go first
                self._views.popitem(last=False)
        return value, True

    def camera_pool(self, params: Params, view: View) -> CameraPool:
        """The view's camera points (vpl_importance.camera_pool), traced once per view: the
        pilot, the portals, the emitter choice and every set's scoring draw from them."""
        key = ("camera pool", self.scene_version, view.key, params.max_depth, params.specular_depth,
               params.filter_glossy_alpha)
        return self._per_view(key, lambda: camera_pool(self.scene, self.geom, self.lights, view, params.max_depth,
                                                       params.specular_depth, params.filter_glossy_alpha))[0]

    def portals(self, params: Params, view: View) -> Portals | None:
        """The view's portals for light walks from the sky (worker.portals), found once per view."""
        if not params.vpl_portals:
            return None
        key = ("portals", self.scene_version, view.key, params.max_depth, params.specular_depth,
               params.filter_glossy_alpha)
        found, fresh = self._per_view(key, lambda: view_portals(
            self.scene, self.geom, self.lights, view, params.max_depth, params.specular_depth,
            params.filter_glossy_alpha, self.camera_pool(params, view)))
        if fresh and found is not None:
            self.portal_notes = (f"ON  vpl_portals         sky enters the view through {len(found)} "
                                 f"opening(s): half the sky's light walks start there")
        return found

    def emitter_pmf(self, params: Params, view: View):
        """The view's choice of emitter for emitter samples (vpl_importance.view_emitter_pmf),
        scored once per view; None: by power (also when the sets have no emitter samples)."""
        direct = self._set_sizes(params)[0]
        if direct == 0:
            return None
        key = ("emitter pmf", self.scene_version, view.key, params.max_depth, params.specular_depth,
               params.filter_glossy_alpha, params.clamp, params.vpl_lobe_alpha, params.direct_vpls)
        pmf, fresh = self._per_view(key, lambda: view_emitter_pmf(
            self.scene, self.geom, self.lights, view, params.max_depth, params.specular_depth,
            clamp_distance2(params, self.geom.diagonal), params.filter_glossy_alpha, params.vpl_lobe_alpha,
            direct, self.camera_pool(params, view)))
        if fresh and pmf is not None:
            moved = 0.5 * float(np.abs(pmf - self.lights.pmf).sum())
            self.emitter_notes = (f"ON  emitter choice      {len(self.scene.emitters)} emitters scored on the "
                                  f"view: {moved:.0%} of the emitter samples moved from choice by power")
        return pmf

    def _build_importance(self, seed, ks, params, view, roulette, pilot=False):
        direct, indirect, length = self._set_sizes(params)
        return build_importance_vpl_sets(
            self.scene, self.geom, self.lights, seed, ks, direct, indirect, length, view,
            params.vpl_oversample, clamp_distance2(params, self.geom.diagonal), params.max_depth,
            params.specular_depth, roulette=roulette and params.max_depth < 0,
            glossy_split_alpha=params.filter_glossy_alpha, lobe_alpha=params.vpl_lobe_alpha,
            portals=None if pilot else self.portals(params, view),
            emitter_pmf=None if pilot else self.emitter_pmf(params, view), pool=self.camera_pool(params, view))

    def _set_sizes(self, params: Params) -> tuple[int, int, int]:
        direct = params.direct_vpls
        if self.plan is not None and self.plan.point_light:
            direct = min(direct, 1)  # a point-like emitter: more samples on it add nothing
        length = params.light_path_length
        if params.max_depth >= 0:
            # A VPL at light depth d lights paths of >= 2 + d segments: walks past
            # max_depth - 2 bounces could never contribute.
            length = min(length, params.max_depth - 2)
        indirect = params.indirect_vpls if length > 0 else 0
        return (direct if params.max_depth != 1 else 0), indirect, max(length, 1)

    def vpl_set(self, seed: int, k: int, params: Params, roulette: bool = False,
                view: View | None = None, index: int = 0) -> VPLSet:
        """P_k of the frame with ``seed`` at accumulation index ``index`` (a moving camera's
        frame: of :func:`set_params`' size; importance sampling on or off as for the view's
        still frames, from one pilot)."""
        importance = self.importance_on(params, view)
        params = set_params(params)
        importance = importance and params.indirect_vpls > 0
        config = ("vpl", self.scene_version, params.interleave, params.direct_vpls, params.indirect_vpls,
                  params.light_path_length, params.max_depth, roulette,
                  (view.key, params.vpl_oversample, params.clamp, params.specular_depth, params.filter_glossy_alpha,
                   params.vpl_lobe_alpha, params.vpl_portals)
                  if importance else None)

        def build(keys: list[tuple]) -> list[VPLSet]:
            stream, blocks = _set_blocks(keys, params)
            if importance:
                return [s for s, _ in self._build_importance(stream, blocks, params, view, roulette)]
            direct, indirect, length = self._set_sizes(params)
            return build_vpl_sets(self.scene, self.geom, self.lights, stream, blocks, direct, indirect, length,
                                  roulette=roulette and params.max_depth < 0)

        return self._frame_sets.get((config, seed, index), k, params.interleave ** 2, self._timed(build),
                                    later_frames(seed, index, params, config))

    def photon_count(self, params: Params, view: View | None = None) -> int:
        """Caustic photons per light per set: --photons, boosted where the scene's caustics carry
        more than --photon-share of the lights' flux (worker.caustics.boosted_photons; the
        share from a pilot set, once per scene and chain length) or, for distant lights, of their
        light on the ``view`` (caustics.distant_view_share, once per view) — not on a moving
        view's frames."""
        if params.photon_share <= 0 or params.photons <= 0 or params.moving_camera:
            return params.photons  # (a moving view's frame is shown once: its frame rate counts)
        key = (params.photons, params.specular_depth)
        share = self._caustic_shares.get(key)
        if share is None:  # (two threads may both measure it: both get the same share)
            with self._set_time():
                share = caustic_share(self.scene, self.geom, self.lights, params.photons, params.specular_depth,
                                      self._specular_targets)
            self._caustic_shares[key] = share
        if view is not None and self._distant_photons:
            vkey = ("photon share", self.scene_version, view.key, params.photons, params.specular_depth,
                    params.max_depth, params.filter_glossy_alpha)  # (and the camera pool's key)
            with self._set_time():
                on_view, _ = self._per_view(vkey, lambda: distant_view_share(
                    self.scene, self.geom, self.lights, self.camera_pool(params, view).first(VIEW_SHARE_POINTS),
                    params.photons, params.specular_depth, self._specular_targets))
            share = max(share, on_view)
        return boosted_photons(params.photons, share, params.photon_share)

    def shoots_photons(self, params: Params) -> bool:
        """Are caustic photons shot (else every photon set is empty)? Caustic paths have >= 3
        segments (eye -> diffuse -> specular -> light, as Mitsuba counts)."""
        return (self.plan is None or self.plan.caustics) and not 0 <= params.max_depth < 3 and params.photons > 0

    def chain_sky(self, params: Params) -> tuple:
        """The sky the mirror/glass chains from surfaces see (worker.indirect_caustics): the map less
        its peak where the peak's caustic photons are shot (worker.caustics), else the whole map."""
        if self._sky_base is not None and self.shoots_photons(params):
            return self._sky_base
        return self.lights.env_tables

    def photon_set(self, seed: int, k: int, params: Params, index: int = 0, view: View | None = None) -> PhotonSet:
        radius = default_radius(self.geom.diagonal, params.photon_radius)
        if not self.shoots_photons(params):
            return PhotonSet(*(np.zeros((0, 3)),) * 4, np.zeros(0, np.int32), radius * radius_scale(index, params),
                             None)
        photons = self.photon_count(params, view)
        config = ("photons", self.scene_version, params.interleave, photons, params.photon_radius,
                  params.consistent, params.ppm_alpha, params.specular_depth)

        def build(keys: list[tuple]) -> list[PhotonSet]:
            stream, blocks = _set_blocks(keys, params)
            radii = [radius * radius_scale(frame[2], params) for frame, _ in keys]
            return build_photon_sets(self.scene, self.geom, self.lights, stream, blocks, photons, radii,
                                     params.specular_depth, targets=self._specular_targets)

        return self._frame_sets.get((config, seed, index), k, params.interleave ** 2, self._timed(build),
                                    later_frames(seed, index, params, config))

    @property
    def stats(self) -> dict:
        """sets_built / set_hits of the VPL sets (benchmarks, tests)."""
        return self._frame_sets.stats

    @property
    def sets_version(self) -> int:
        """Changes whenever :meth:`cached_sets` may have (a worker asks for the list only then)."""
        return self._frame_sets.version

    def cached_sets(self) -> set[tuple[int, int]]:
        """The (frame seed, k) of the VPL sets held for the current scene version."""
        return {(seed, k) for (config, seed, _index), k in self._frame_sets.keys()
                if config[0] == "vpl" and config[1] == self.scene_version}

    # -- a task ------------------------------------------------------------------------------
    def _timed(self, build: Callable[[list], list]) -> Callable[[list], list]:
        """``build`` (a set cache's builder), its seconds counted as the running task's set time."""
        def timed(keys: list) -> list:
            with self._set_time():
                return build(keys)

        return timed

    @contextlib.contextmanager
    def _set_time(self):
        """Count the block's seconds (set building, per-view preparation) in the running task's
        ``timings["sets"]`` when render_tile was given one; a block inside another is counted
        with it, not twice."""
        task = self._task
        timings = getattr(task, "timings", None)
        if timings is None or getattr(task, "timing", False):
            yield
            return
        task.timing = True
        t0 = time.perf_counter()
        try:
            yield
        finally:
            task.timing = False
            timings["sets"] = timings.get("sets", 0.0) + time.perf_counter() - t0

    def render_tile(self, spec: FrameSpec, tile: Tile, timings: dict | None = None) -> TileBuffers:
        """The tile's per-pixel buffers. ``timings``: the seconds this call spent building VPL and
        photon sets and the view's set preparation (pilot, camera points, portals) are added to
        its "sets" — the master's task timeouts allow for them."""
        self._task.timings = timings
        try:
            return self._render_tile(spec, tile)
        finally:
            self._task.timings = None

    def _render_tile(self, spec: FrameSpec, tile: Tile) -> TileBuffers:
        params = make_params(**spec.params)
        n = params.interleave
        xs, ys = tile.pixels(n, spec.width, spec.height)
        p = len(xs)
        index = accumulation_index(spec)
        view = View.of(spec.camera_to_world, spec.fov_x, spec.width, spec.height)
        consistent = consistent_frame(params, index)
        with self._stage("VPL set"):
            vpls = self.vpl_set(spec.seed, tile.k, params, roulette=consistent, view=view, index=index)
        with self._stage("eye paths"):
            # Accumulating: each pixel walks its own rotation of the frames' jitter sequence.
            cam = self.scene.camera
            jitter = frame_jitter(spec.jitter, index > 0, xs, ys, cam, spec.width, spec.height)
            lens = (cam.aperture_radius, cam.focus_distance, lens_jitter(index, xs, ys)) if cam.aperture_radius > 0 \
                else None
            o, d = camera_rays(np.asarray(spec.camera_to_world).reshape(4, 4), spec.fov_x, spec.width,
                               spec.height, xs, ys, jitter, lens)
            rng = make_rng(spec.seed, tile.k, tile.sx0, tile.sy0)
            # A split lobe's direct-only end point takes the first lobe_lights emitter samples;
            # its sampled ray's MIS weight must count the same samples.
            lobe_lights = lobe_light_count(vpls, params.lobe_light_samples)
            eye = trace_eye(self.scene, self.geom, self.lights, o, d, params.max_depth,
                            params.specular_depth, rng, params.filter_glossy_alpha,
                            LightMIS(lobe_lights, vpls.env_guide, vpls.emitter_pmf))
        clamp_d2 = frame_clamp_distance2(params, self.geom.diagonal, index, consistent)
        # Regularized glossy senders: the bound shrinks like the photon radius (consistent)
        lobe_alpha = params.vpl_lobe_alpha * radius_scale(index, params)
        end = eye.end
        compensate = consistent
        lensed = self.plan is None or self.plan.specular_chains
        with self._stage("BSDF rays"):
            # One traced BSDF ray per end point serves BSDF-direct lighting, the compensation and
            # the light reflected through mirror/glass chains.
            rays = trace_bsdf_rays(self.geom, self.lights, end, params.max_depth, rng,
                                   np.sqrt(clamp_d2) if compensate else 0.0,
                                   self._specular_targets if lensed else None)
        with self._stage("photon set"):
            photons = self.photon_set(spec.seed, tile.k, params, index, view)
        chain_sky = self.chain_sky(params)
        near, sky, ends = None, None, None
        if compensate and compensation_enabled(vpls, clamp_d2):
            # Accumulating: give back what the clamp took (its near points, found by the rays).
            near = near_arrivals(end, rays, 1, clamp_d2, params.max_depth, rng)
        if lensed:
            with self._stage("lensed chains"):
                sky, ends = lensed_arrivals(self.scene, self.geom, self.lights, end, rays, params.max_depth,
                                            params.specular_depth, rng, chain_sky)
        albedo, irr = final_gather(self.scene, self.geom, self.lights, end, rays, near, vpls,
                                   clamp_d2, params.max_depth, rng, lobe_alpha, photons, params.shadow_roulette,
                                   force_general=self.plan is None, lobe_lights=lobe_lights, stage=self._stage,
                                   lensed=ends, specular_depth=params.specular_depth,
                                   targets=self._specular_targets if lensed else None, sky_map=chain_sky)
        if sky is not None:
            add_sky(irr, albedo, sky)
        refl = np.zeros((p, 3))
        irr_buf = np.zeros((p, 3))
        unf = eye.unfiltered
        # Lambertian, rough and split-off diffuse-layer end points go through the discontinuity
        # buffer; smooth glossy ones reached after a mirror/glass chain (not split) would have
        # their highlights smeared by it, so their radiance stays unfiltered.
        kind = end.sp.kind
        filterable = (kind == DIFFUSE) | (kind == PLASTIC) | (kind == ROUGHPLASTIC_DIFFUSE) | (
            kind_in(kind, GLOSSY_KINDS) & ~bsdf.split_smooth(kind, end.sp.alpha, params.filter_glossy_alpha))
        tile_buffers.compose(np.ascontiguousarray(end.pixel, np.int64), end.main & filterable,
                             np.ascontiguousarray(albedo, np.float64), np.ascontiguousarray(end.throughput, np.float64),
                             np.ascontiguousarray(irr, np.float64), refl, irr_buf, unf)
        # A split plastic's lobe (all of its pixel's unfiltered radiance) is filtered on its own
        # where it is rough enough that the filter's blur stays inside it: not over the layer's
        # reflectance (a dark or textured layer's would amplify and skew it).
        carry = end.main & filterable & (kind == ROUGHPLASTIC_DIFFUSE) & (end.sp.alpha >= params.filter_lobe_alpha)
        lobe = None
        if carry.any():
            lobe = np.full((p, 3), NO_LOBE)
            tile_buffers.filter_lobes(np.ascontiguousarray(end.pixel, np.int64), carry, unf, lobe)
        return TileBuffers(
            reflectance=refl.astype(np.float32),
            irradiance=irr_buf.astype(np.float32),
            unfiltered=unf.astype(np.float32),
            depth=eye.depth.astype(np.float32),
            normal=eye.normal.astype(np.float32),
            lobe=None if lobe is None else lobe.astype(np.float32),
        )
