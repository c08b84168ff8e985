"""Load (or compile) every compiled kernel before a worker says HELLO (issue 16).

On a cold cache the kernels listed in kernel_signatures.json are first compiled in one helper
process per core (worker.kernels.parallel_compile: 268 s → ~100-140 s on a 2-core EPYC).

numba compiles a kernel on its first call, or loads it from its on-disk cache (``cache=True``,
``__pycache__`` beside the module); either way the first call of each kernel in a process
costs up to seconds. :func:`warm_up` pays that before the node connects, so it does not land
inside the first frame a user waits for: it renders a tiny built-in scene (every pass on:
diffuse, glossy and mirror surfaces, an area, a spot and a directional light, caustic photons) through the
real ``Renderer`` (and once more with a diffuse floor, for the gather's fused Lambertian
path), so the kernels are loaded for exactly the argument types the product passes, then
encodes and decodes a tile (common.codec) and finally calls any public kernel of
``common.kernels`` / ``worker.kernels`` that still has no compiled signature on tiny inputs.
Kernels compiled only into their callers (``inline="always"``) have nothing of their own to
load and are left out.
"""
from __future__ import annotations

import contextlib
import importlib
import pkgutil
import time

import numpy as np

KERNEL_PACKAGES = ("igi.common.kernels", "igi.worker.kernels")


def inlined(disp) -> bool:
    """A kernel compiled only into its callers (``inline="always"``): it has no code of its own
    to load, and compiling it standalone would cost seconds on a cold cache for nothing."""
    return disp.targetoptions.get("inline") == "always"


def kernel_dispatchers() -> dict[str, object]:
    """``module.name`` -> numba dispatcher, for every compiled kernel of :data:`KERNEL_PACKAGES`
    (private helpers included, the inlined ones not)."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for pkg_name in KERNEL_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        for info in pkgutil.iter_modules(pkg.__path__):
            if info.name == "warm":
                continue
            mod = importlib.import_module(f"{pkg_name}.{info.name}")
            for name, obj in vars(mod).items():
                if isinstance(obj, CPUDispatcher) and obj.__module__ == mod.__name__ and not inlined(obj):
                    out[f"{mod.__name__}.{name}"] = obj
    return out


def _tiny_scene(floor: int = 1):
    """An open box with a mirror, an area light, a spot and a sun; ``floor``: the floor's material
    (1 glossy, 0 diffuse: no glossy VPL, so the gather takes its fused Lambertian path)."""
    from igi.common.camera import look_at
    from igi.common.scene import (AREA, CONDUCTOR, DIFFUSE, DIRECTIONAL, ROUGHCONDUCTOR, SPOT, Camera, Emitter,
                                  Material, Mesh, Scene, Texture)

    def quad(c, e1, e2):
        c, e1, e2 = (np.asarray(a, float) for a in (c, e1, e2))
        return np.array([c, c + e1, c + e1 + e2, c + e2]), np.array([[0, 1, 2], [0, 2, 3]], np.int32)

    mats = [Material("wall", DIFFUSE, diffuse=Texture.constant(0.6)),
            Material("glossy", ROUGHCONDUCTOR, alpha=0.3),
            Material("mirror", CONDUCTOR),
            Material("light", DIFFUSE, diffuse=Texture.constant(0.0))]
    meshes = []
    # an open box seen from the front: floor (glossy), back wall, ceiling, two side walls
    for name, (v, f), m in (("floor", quad([0, 0, 0], [0, 0, 2], [2, 0, 0]), floor),
                            ("back", quad([0, 0, 0], [2, 0, 0], [0, 2, 0]), 0),
                            ("ceiling", quad([0, 2, 0], [2, 0, 0], [0, 0, 2]), 0),
                            ("left", quad([0, 0, 0], [0, 2, 0], [0, 0, 2]), 0),
                            ("right", quad([2, 0, 0], [0, 0, 2], [0, 2, 0]), 0),
                            ("mirror", quad([0.6, 0.3, 0.5], [0.8, 0, 0], [0, 0.8, 0.3]), 2)):
        meshes.append(Mesh(name, v, f, m))
    lv, lf = quad([0.8, 1.99, 0.8], [0.4, 0, 0], [0, 0, 0.4])
    meshes.append(Mesh("light", lv, lf, 3, emitter=0))
    emitters = [Emitter(AREA, radiance=np.full(3, 10.0), mesh=len(meshes) - 1),
                Emitter(SPOT, intensity=np.full(3, 5.0), position=np.array([1.0, 1.8, 1.5]),
                        direction=np.array([0.0, -1.0, -0.5]), cutoff_angle=30.0, beam_width=20.0),
                # a sun through the open front onto the mirror: distant lights' photons
                Emitter(DIRECTIONAL, irradiance=np.full(3, 2.0), direction=np.array([0.1, -0.4, -1.0]))]
    cam = Camera(look_at([1.0, 1.0, 3.5], [1.0, 0.9, 0.0], [0, 1, 0]), fov=60, width=12, height=9)
    return Scene(meshes, mats, emitters, cam, source="warm-up")


def _render_tiny() -> None:
    from igi.common.camera import resolve_camera
    from igi.common.codec import decode, encode
    from igi.common.frame import FrameSpec
    from igi.common.interleave import make_tiles
    from igi.common.params import make_params, params_to_dict
    from igi.worker.renderer import Renderer

    pd = params_to_dict(make_params(photons=500, interleave=2))
    for scene in (_tiny_scene(), _tiny_scene(floor=0)):
        cam, fov_x, w, h = resolve_camera(scene, None, None, None)
        r = Renderer(scene)
        for index, jitter in ((0, (0.5, 0.5)), (1, (0.25, 0.75))):  # the first and an accumulating frame
            params = dict(pd, consistent=True, accumulate=True)
            spec = FrameSpec(frame=index, seed=index, camera_to_world=tuple(np.asarray(cam, float).ravel()),
                             fov_x=float(fov_x), width=w, height=h, params=params, scene_version=0, jitter=jitter)
            for t in make_tiles(w, h, 2, 8, 8):  # one tile a set k
                buf = r.render_tile(spec, t)
                decode(encode(buf), len(buf))


def _empty_args(disp) -> list:
    """Arguments of the types of ``disp``'s first compiled signature (empty arrays, zeros)."""
    from numba.core import types

    out = []
    for t in disp.signatures[0]:
        if isinstance(t, types.Array):
            out.append(np.zeros((0,) * t.ndim, np.dtype(str(t.dtype))))
        elif isinstance(t, types.Boolean):
            out.append(False)
        elif isinstance(t, types.Integer):
            out.append(0)
        else:
            out.append(0.0)
    return out


def _direct_calls() -> dict:
    """Tiny calls of the kernels the render does not register: the worker never decodes,
    and helpers that are loaded from the cache inside their caller keep no signature."""
    from igi.common.environment_map import no_map
    from igi.common.kernels import environment_map, shading_frame, shading_normals, texture, wire_decode
    from igi.worker.kernels import environment_bins, light_paths, photon_query, tile_buffers, vpl_gather

    z = np.zeros(0, np.uint8)
    out1 = np.zeros(0, np.float32)
    return {
        "igi.worker.kernels.vpl_gather.spot_falloff": lambda: vpl_gather.spot_falloff(0.9, 30.0, 20.0),
        "igi.worker.kernels.vpl_gather.pair_uniform": lambda: vpl_gather.pair_uniform(0, 0, 0),
        # the tiny scene has no bitmap (a textured scene's first hit would load it)
        "igi.common.kernels.texture.lookup": lambda: texture.lookup(
            np.zeros((1, 1, 3), np.float32), np.zeros((1, 2)), 1.0, 1.0, 0.0, 0.0, False, np.zeros((1, 3), np.float32)),
        "igi.common.kernels.wire_decode.oct_decode_one": lambda: wire_decode.oct_decode_one(0, 0),
        "igi.common.kernels.wire_decode.f16_to_f32": lambda: wire_decode.f16_to_f32(z, z, out1),
        "igi.common.kernels.wire_decode.oct_decode_into": lambda: wire_decode.oct_decode_into(
            np.zeros(1, np.int16), np.zeros(1, np.int16), np.zeros((3, 1), np.float32)),
        # the gather's array path (benchmark replays, no Embree C API): the render takes the packets
        "igi.worker.kernels.vpl_gather.accumulate": lambda: vpl_gather.accumulate(
            0, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0, bool),
            np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool), np.zeros((0, 3))),
        # a split plastic's lobe filtered on its own (the tiny scene has no plastic)
        "igi.worker.kernels.tile_buffers.filter_lobes": lambda: tile_buffers.filter_lobes(
            np.zeros(0, np.int64), np.zeros(0, np.bool_), np.zeros((1, 3)), np.zeros((1, 3))),
        # the environment guide's bins (the tiny scene has no sky)
        "igi.worker.kernels.environment_bins.direction_bins": lambda: environment_bins.direction_bins(
            np.zeros((0, 3)), np.zeros(0, np.int64)),
        "igi.worker.kernels.environment_bins.guide_pdfs": lambda: environment_bins.guide_pdfs(
            np.zeros(1), no_map(), np.zeros((0, 3)), np.zeros(0)),
        # an environment map's numpy-facing calls (the tiny scene's sky is no map)
        "igi.common.kernels.environment_map.radiance_many": lambda: environment_map.radiance_many(
            no_map(), np.zeros((0, 3)), np.zeros((0, 3))),
        "igi.common.kernels.environment_map.pdf_many": lambda: environment_map.pdf_many(
            no_map(), np.zeros((0, 3)), np.zeros(0)),
        "igi.common.kernels.environment_map.sample_many": lambda: environment_map.sample_many(
            no_map(), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0)),
        # _stage and the array path's pair_weights: the scoring's rows and columns (empty
        # arrays of the types scored_draws takes) in their order
        "igi.worker.kernels.vpl_gather._stage": lambda: _stage_call(vpl_gather),
        "igi.worker.kernels.vpl_gather._lambert_columns": lambda: _lambert_columns_call(vpl_gather),
        "igi.worker.kernels.vpl_gather.pair_weights": lambda: _pair_weights_call(vpl_gather),
        "igi.worker.kernels.vpl_gather.row_totals": lambda: _row_totals_call(vpl_gather),
        # one bounce alone: what chains of mirrors and glass the numpy loops still follow
        "igi.worker.kernels.specular_chain.delta_bounce": _delta_bounce_call,
        "igi.worker.kernels.photon_query._cell": lambda: photon_query._cell(0.5, 2.0),
        "igi.worker.kernels.photon_query._find": lambda: photon_query._find(np.zeros(1, np.int64), 0),
        # _visit: query's arguments (empty arrays of its types), the rows visited, the outputs
        "igi.worker.kernels.photon_query._visit": _visit_call,
        # what the numpy loops (recorded rays) call alone: compiled paths inline or fuse them
        "igi.common.kernels.shading_frame.to_local_many": lambda: shading_frame.to_local_many(
            np.ones((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.empty((1, 3))),
        "igi.worker.kernels.light_paths.roulette_uniforms": lambda: light_paths.roulette_uniforms(
            np.zeros(1, np.uint64), 1, 0, 3, np.empty((1, 3)), np.empty((1, 1))),
        "igi.worker.kernels.light_paths.continue_paths": _continue_paths_call,
        # the numpy walks' shading-normal ratios (the compiled walks inline them)
        "igi.common.kernels.shading_normals.incident_ratios": lambda: shading_normals.incident_ratios(
            np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)),
    }


def _continue_paths_call() -> None:
    """light_paths.continue_paths on empty inputs of the types worker.light_paths passes it."""
    from igi.common import bsdf
    from igi.common.scene import DIFFUSE, Material
    from igi.worker.kernels import light_paths

    P = bsdf.SurfacePoints.constant(Material("warm-up", DIFFUSE), 1).packed()
    i64, f64 = np.zeros(0, np.int64), np.zeros((0, 3))
    light_paths.continue_paths(P, np.zeros(1, np.int64), i64, i64.copy(), f64, f64.copy(), f64.copy(),
                               np.zeros(0, np.bool_), f64.copy(), f64.copy(), f64.copy(), np.zeros((0, 5)), 0, False,
                               np.zeros((0, 0)), 0, np.zeros(3), 0.0, 0.0, i64.copy())


def _visit_call() -> None:
    from igi.worker.kernels import photon_query

    q, *rest = _empty_args(photon_query.query)
    none = np.zeros(0, np.int64)
    photon_query._visit(q, none, 0, False, *rest, none, none, False)


def _delta_bounce_call() -> None:
    """specular_chain.delta_bounce on empty inputs of the types worker.shading.delta_bounce
    passes it (a materials list's packed rows)."""
    from igi.common import bsdf
    from igi.common.scene import CONDUCTOR, Material
    from igi.worker.kernels import specular_chain

    P, _textured = bsdf.material_packed([Material("warm-up", CONDUCTOR)])
    i64, f64 = np.zeros(0, np.int64), np.zeros((0, 3))
    specular_chain.delta_bounce(P, i64, i64.copy(), f64, f64.copy(), f64.copy(), f64.copy(), f64.copy(), i64.copy(),
                                np.zeros(0), np.zeros((0, 2)), -1, True, np.zeros(3), 0.0, 0.0, i64.copy(),
                                f64.copy(), i64.copy(), f64.copy(), f64.copy())


def _stage_call(vpl_gather) -> None:
    """vpl_gather._stage on empty inputs of the types its callers pass it."""
    from igi.worker.kernels import vpl_scoring

    a = _empty_args(vpl_scoring.scored_draws)
    staging = np.zeros((1, 0), np.float32)
    vpl_gather._stage(0, 0, *a[0:7], *a[20:25], *a[7:20], a[25], 0.0, 0, 0, vpl_gather.NO_LOBES,
                      np.zeros(0, np.float32), np.zeros(0), np.zeros((0, 4), np.float32), np.zeros(1, np.int64),
                      staging, staging.copy(), np.zeros((1, 3), np.float32), np.zeros(1, np.bool_),
                      *(np.zeros(0, np.float32) for _ in range(6)), np.zeros(0, np.int32), np.zeros(0, np.uint64),
                      _stage_block(1, 0))


def _lambert_columns_call(vpl_gather) -> None:
    """vpl_gather._lambert_columns on empty inputs of the types _stage passes it."""
    f32 = np.float32
    v, b = np.zeros(0, f32), np.zeros(0, np.bool_)
    vpl_gather._lambert_columns(0, 0, np.zeros((0, 3), f32), np.zeros((0, 3), f32), v, np.zeros(0, np.int8),
                                np.zeros(0, np.int64), np.ones((1, 2)), np.zeros(0, np.int64), np.zeros(0), 0, 0, b,
                                v, b.copy(), v, b.copy(), v, b.copy(), f32(0.0),
                                np.zeros(0), 0.0, 0, 0, vpl_gather.NO_LOBES, np.zeros(0, f32), np.zeros(0),
                                np.zeros((0, 1), f32),
                                np.zeros((0, 1), f32),
                                *(np.zeros(0, f32) for _ in range(6)),
                                np.zeros(0, np.int32), np.zeros(0, np.uint32), _stage_block(1, 0))


def _stage_block(rows: int, width: int) -> tuple:
    """vpl_gather._stage's row scratch (as vpl_gather.staging_for makes it)."""
    f32 = np.float32
    return (*(np.zeros(rows, f32) for _ in range(7)), np.zeros(rows, np.int32), np.zeros(rows, np.int8),
            np.zeros(rows), np.zeros(rows, np.int32), np.zeros(rows, f32), np.zeros(rows, np.uint32),
            np.zeros((1, width), f32), np.zeros((1, width), f32), np.zeros(rows, f32), np.zeros(rows, np.int64),
            np.zeros(rows, np.int64), np.zeros((width, rows), f32))


def _pair_weights_call(vpl_gather) -> None:
    """vpl_gather.pair_weights (the gather's array path) on empty inputs of the types
    shading._pair_rays passes it."""
    from igi.worker.kernels import vpl_scoring

    a = _empty_args(vpl_scoring.scored_draws)
    i64, f32 = np.zeros(0, np.int64), np.zeros(0, np.float32)
    f32x3 = np.zeros((0, 3), np.float32)
    vpl_gather.pair_weights(*a[0:20], np.float32(0.0), *a[20:26], 0.0, 0, 0, vpl_gather.NO_LOBES,
                            np.zeros(0, np.float32), np.zeros((0, 4), np.float32), np.zeros(1, np.int64), i64,
                            i64.copy(), f32, f32.copy(), f32x3, f32x3.copy(), f32.copy(), np.zeros(0, np.bool_))


def _row_totals_call(vpl_gather) -> None:
    """vpl_gather.row_totals on empty inputs of the types shading._pixel_boost passes it."""
    from igi.worker.kernels import vpl_scoring

    a = _empty_args(vpl_scoring.scored_draws)
    vpl_gather.row_totals(*a[0:20], *a[20:26], vpl_gather.NO_LOBES, np.zeros(0))


def _bsdf_calls() -> dict:
    """Tiny calls of the BSDF kernels (common.kernels.bsdf) with the argument types the array
    loops pass: the non-inlined scalar functions they call are loaded with them from the cache,
    so they keep no signature of their own; a 1-point diffuse P needs no coat tables."""
    from igi.common import bsdf
    from igi.common.kernels import bsdf as kb
    from igi.common.scene import DIFFUSE, Material

    P = bsdf.SurfacePoints.constant(Material("warm-up", DIFFUSE), 1).packed()
    f, f3, f5, f6 = 0.5, (0.5,) * 3, (0.5,) * 5, (0.5,) * 6
    w1, w2, o1 = np.full((1, 3), 0.5), np.full((1, 2), 0.5), np.zeros(1)
    o3 = np.zeros((1, 3))
    r1 = np.zeros(1, np.int64)
    calls = {
        "max0": lambda: kb.max0(f), "clamp": lambda: kb.clamp(f, 0.0, 1.0), "erfinv": lambda: kb.erfinv(f),
        "fresnel_dielectric": lambda: kb.fresnel_dielectric(f, 1.5),
        "fresnel_conductor": lambda: kb.fresnel_conductor(f, f, f),
        "fresnel_diffuse_reflectance": lambda: kb.fresnel_diffuse_reflectance(1.5),
        "concentric_disk": lambda: kb.concentric_disk(f, f), "cosine_hemisphere": lambda: kb.cosine_hemisphere(f, f),
        "ndf": lambda: kb.ndf(*f3, f, True), "smith_g1": lambda: kb.smith_g1(*f6, f, True),
        "_visible_11_ggx": lambda: kb._visible_11_ggx(*f3), "_visible_11_beckmann": lambda: kb._visible_11_beckmann(*f3),
        "sample_visible": lambda: kb.sample_visible(*f5, f, True), "pdf_visible": lambda: kb.pdf_visible(*f6, f, True),
        "lerp_table": lambda: kb.lerp_table(P[12], 0, f), "_fin": lambda: kb._fin(f),
        "_half": lambda: kb._half(*f6), "_reflect_m": lambda: kb._reflect_m(*f6),
        "_lobe_probability": lambda: kb._lobe_probability(*f3),
        "_thin_r": lambda: kb._thin_r(f, 1.5), "eval_many": lambda: kb.eval_many(P, r1, w1, w1, o3.copy(), o1.copy()),
        "sample_many": lambda: kb.sample_many(P, r1, w1, o1, w2, True, o3.copy(), o3.copy(), o1.copy(), np.zeros(1, bool)),
        "sample_lobe_many": lambda: kb.sample_lobe_many(P, r1, w1, w2, o3.copy(), o3.copy()),
        "albedo_many": lambda: kb.albedo_many(P, r1, w1, o3.copy()),
        "specular_many": lambda: kb.specular_many(P, r1, w1, True, w2, o3.copy(), o3.copy(), o3.copy(), o3.copy()),
        "coat_columns": lambda: bsdf.pack(bsdf.SurfacePoints.constant(Material("warm-up", DIFFUSE), 1)),
        "material_rows": lambda: kb.material_rows(*bsdf.material_packed([Material("warm-up", DIFFUSE)])[:1], r1, 1,
                                                  bsdf.texture_atlas([Material("warm-up", DIFFUSE)]), w2,
                                                  np.zeros(1, np.int64)),
    }
    return {f"igi.common.kernels.bsdf.{name}": call for name, call in calls.items()}


def compiled_before() -> bool | None:
    """Has this machine compiled igi's kernels (a fresh index in numba's on-disk cache for each
    kernel of worker/kernels/kernel_signatures.json)? Checked without importing numba or the
    kernels, so the master can say why a first run waits. None when that cannot be told (the
    list is missing, or numba caches in a folder of its own choosing)."""
    todo = _uncached()
    return None if todo is None else not todo


def _uncached() -> list[dict] | None:
    """The listed kernels without a fresh index in numba's cache; None when that cannot be told
    (no list, or a cache numba keeps where it cannot be seen)."""
    from igi.common.kernel_cache import keep_true

    from .parallel_compile import cache_located, load_manifest, missing

    entries = load_manifest()
    if not entries or not cache_located(entries):
        return None
    keep_true()  # stale caches go before they are counted (caches of kernels whose imports changed)
    return missing(entries)


# Helpers of a cold compile: past ~6 the longest group of kernels (trace_eye's, ~70 s of 250)
# bounds the time, and each helper holds ~400 MB while it compiles.
MAX_COMPILE_HELPERS = 8


def compile_cold_kernels(processes: int | None = None) -> dict | None:
    """On a cold (or partly cold) cache, compile the listed kernels not yet cached in one helper
    process per core (worker.kernels.parallel_compile); None where there is nothing to gain
    (cache warm, one core, no list, a cache numba keeps where it cannot be seen)."""
    from .parallel_compile import compile_in_parallel, usable_cores

    todo = _uncached()
    processes = processes or min(usable_cores(), MAX_COMPILE_HELPERS)
    if todo is None or processes < 2 or sum(e.get("seconds", 0.0) for e in todo) < 10.0:
        return None
    return compile_in_parallel(todo, processes)


def warm_up(render: bool = True, parallel: bool = True) -> dict:
    """Load or compile every kernel (on a cold cache first in parallel, see
    :func:`compile_cold_kernels`); returns {"seconds": s, "kernels": count, "cold": names still
    without a compiled signature (should be empty), "parallel": what the helpers did, or None}."""
    t0 = time.perf_counter()
    helpers = compile_cold_kernels() if parallel else None
    if render:
        _render_tiny()
    kernels = kernel_dispatchers()
    calls = {**_direct_calls(), **_bsdf_calls()}
    for name, disp in kernels.items():
        if not disp.signatures and name in calls:
            try:
                calls[name]()
            except IndexError:  # _empty_args of a kernel the render did not reach
                pass
    cold = sorted(name for name, disp in kernels.items() if not disp.signatures)
    return {"seconds": time.perf_counter() - t0, "kernels": len(kernels), "cold": cold, "parallel": helpers}


@contextlib.contextmanager
def one_compiler():
    """Hold a lock of this checkout's kernels while warming up a cold cache, so the workers one
    machine starts together compile them once: the first compiles into numba's on-disk cache, the
    others wait and then load from it (on a fresh checkout each would otherwise spend minutes
    of a core compiling the same code). Where no lock can be taken (no fcntl, no temporary
    directory), each warms up on its own, as before."""
    try:
        import fcntl
        import hashlib
        import os
        import tempfile

        here = os.path.dirname(os.path.abspath(__file__))
        key = hashlib.sha1(here.encode()).hexdigest()[:16]
        fh = open(os.path.join(tempfile.gettempdir(), f"igi-kernels-{key}.lock"), "w")
    except (ImportError, OSError):
        yield
        return
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX)
        except OSError:
            pass
        yield  # (closing the file releases the lock)


def warm_up_before_hello(log) -> None:
    """The worker's start (worker.node): :func:`warm_up`, its duration logged at INFO. A
    failure here must not keep a worker from serving (its kernels then load on first use):
    it is logged as a warning."""
    try:
        # (a machine that has compiled them loads them, each worker on its own)
        with one_compiler() if compiled_before() is not True else contextlib.nullcontext():
            res = warm_up()
    except Exception as e:  # noqa: BLE001 - any failure only costs the first frame's latency
        log.warning("kernel warm-up failed (%s: %s); kernels load on first use", type(e).__name__, e)
        return
    helpers = res.get("parallel")
    if helpers:
        log.info("compiled the kernels of a cold cache in %d processes in %.1f s", helpers["processes"],
                 helpers["seconds"])
        for line in helpers["errors"]:
            log.warning("parallel kernel compile: %s", line)
    log.info("kernels ready in %.2f s (%d compiled kernels, loaded from numba's cache or compiled)",
             res["seconds"], res["kernels"])


def main(argv: list[str] | None = None) -> int:
    """``--record-signatures``: write kernel_signatures.json anew (parallel_compile.write);
    with no argument, warm up and print what it did."""
    import sys

    from . import parallel_compile

    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--record-signatures"]:
        return parallel_compile.write(lambda: warm_up(parallel=False), kernel_dispatchers,
                                      ["-m", "igi.worker.kernels.warm", *argv])
    if argv:
        print("usage: python -m igi.worker.kernels.warm [--record-signatures]", file=sys.stderr)
        return 2
    print(warm_up())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
