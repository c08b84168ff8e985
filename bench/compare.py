"""``igi bench compare``: igi against Mitsuba 3's path tracer at equal wall time, and temporal
stability (flicker) of both.

    igi bench compare SCENE… [--budgets 0.25,0.5,1,4] [--scale 0.5 | --width W --height H]
                             [--direct-only] [--converged-frames 64] [--bias-frames 32]
                             [--flicker-frames 8]
                             [--orbit-step 1] [--path-ref-spp 256] [--mitsuba-variant auto]
                             [--mitsuba-threads 1] [--no-mitsuba] [--clock wall|cpu] [--out DIR]
                             [render parameter flags]

Mitsuba is the optional extra ``pip install -e '.[peers]'``; without it the igi half still runs
and the JSON says why Mitsuba is missing. The variant is probed in a subprocess first (an LLVM
that cannot compile Dr.Jit's kernels aborts the process): ``llvm_ad_rgb`` — retried with every
``libLLVM`` found on the system via ``DRJIT_LIBLLVM_PATH`` (Debian: ``apt-get install -y
libllvm19``) — then ``scalar_rgb``; the variant that ran is recorded.

Equal time. igi renders with ``master.inprocess.render_local`` (the distributed path in one
process, one core), accumulating frames; the image at budget B is the running mean after the
last frame that finished within B (at least one frame: ``over_budget`` says when one frame
alone took longer). Counted: the frames (tracing, set building, codec round trip, merge,
filter, accumulation). Not counted: scene load and BVH build (recorded as ``load_s``,
``setup_s``), scoring. Mitsuba renders the same scene file with its ``path`` integrator (same
max depth as the reference), the same camera and resolution and a box filter, on
``--mitsuba-threads`` threads (default 1, like igi's one process); spp is chosen to fit the
budget (max(B, igi's time) when igi is over budget) from a timing fit t = a + b·spp made
after a warm-up (JIT compilation is cached and not counted; scene load is recorded apart).
Both are scored like ``igi bench quality`` (relMSE, RMSE, 4×4 block relMSE, FLIP).

Bias against noise. igi's first frames are what the budgets <= 1 s see; their bias is measured
directly: ``--bias-frames`` M independent single frames (accumulation off, seeds s … s+M-1 —
each exactly what frame 1 of a budget run is: filter on, clamped VPLs, fixed walk length and
photon radius, pixel-centre rays) are averaged, and the fit relMSE(mean of m) = bias + noise/m
gives the bias of one frame (plus the reference's own floor) and one frame's noise; a budget
with n frames then splits into bias + noise/n (the consistent accumulation's shrinking
biases make that an upper bound on the bias for n > 1). The budget run itself keeps
accumulating to ``--converged-frames`` (what accumulation reaches; the default ``consistent``
mode fades the filter and shrinks the photon radius, so its curve is not bias + noise/n).

Temporal stability (``--flicker-frames`` frames, accumulation off): mean absolute change
between consecutive frames, in linear radiance and relative to the reference's mean, with
the camera static (fixed seed: igi re-renders the same seed → 0; new seed per frame) and
along a small scripted orbit of the scene camera (``--orbit-step`` degrees per frame about the
camera's up axis through a point in front of it). Mitsuba PT renders the same frames at equal
time (per case, spp fitted to igi's mean frame time of that case; with a fixed seed igi's
frames reuse the VPL/photon sets it cached, as its workers do while the camera moves). Along the orbit, ``excess`` subtracts the change
a converged render would show (Mitsuba at ``--path-ref-spp`` per frame): what is left is
flicker, not motion.

Clock: ``--clock wall`` (default) or ``cpu`` — the process's CPU time over the same spans, which
is what the work costs on an idle core when other jobs share the machine (both are recorded).
Mitsuba's time per spp is fitted again right before every budget and flicker case.

Writes ``DIR/bench-compare.json`` and ``DIR/bench-compare.md``.
"""
from __future__ import annotations

import argparse
import glob
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from igi.common.reconstruction_filter import KINDS

from . import quality as bq
from .paths import REPO_ROOT
from .report import git_commit, machine_info


DEFAULT_BUDGETS = "0.25,0.5,1,4"
GOAL_RATIO = 0.5  # team goal: igi's error <= 0.5x Mitsuba PT's at equal time <= 1 s
GOAL_MAX_BUDGET = 1.0
HEAVY_TAIL = 3.0  # single-frame errors whose mean exceeds 3x their median: outlier frames dominate

IGI_TIMING = ("igi time: frames only, one process / one core (master.inprocess.render_local: tracing, VPL and "
              "photon set building, wire codec round trip, master merge + discontinuity filter + "
              "accumulation); scene load (load_s) and geometry/BVH build (setup_s) are not counted; "
              "image at budget B = running mean after the last frame finished within B (at least 1 frame)")
IGI_TIMING_WORKERS = ("igi time: frames only, a real master and {n} local worker process(es) on loopback ZeroMQ "
                      "(master.broker.Broker.render_sequence: the workers trace and build the sets, the master merges, "
                      "filters and accumulates); wall clock from the first frame's submission, the relMSE of each "
                      "running mean (computed as frames arrive) counted in igi's time, cpu_s the master process's "
                      "only; start-up (workers started, kernels loaded, HELLO, one 1/4-size frame of another seed: "
                      "scene and BVH on the workers) not counted and reported as startup_s; scene load (load_s) not "
                      "counted; "
                      "image at budget B = running mean after the last frame finished within B (at least 1 frame)")
MITSUBA_TIMING = ("Mitsuba time: mi.render + copy to numpy (kernels already compiled and cached by a warm-up); "
                  "scene load (load_s) not counted; spp fitted to the budget from t = a + b*spp")


# ---------------------------------------------------------------------------- Mitsuba

_MITSUBA: dict | None = None  # the probed set-up, once per process

PROBE_CODE = r"""
import sys
sys.path.insert(0, sys.argv[4])
from igi.bench.compare import _probe
_probe(sys.argv[1], sys.argv[2], int(sys.argv[3]))
"""


def mitsuba_rfilter(kind: str, params: tuple[float, float]) -> dict:
    """The scene's reconstruction filter (common.reconstruction_filter) as Mitsuba's plugin
    dict: both renderers filter their pixels alike."""
    if kind == "box":  # (Mitsuba's box takes no radius: always 0.5)
        return {"type": kind}
    names = [n for n in KINDS[kind][0].split(", ") if n]
    return {"type": kind, **{n: int(v) if n == "lobes" else float(v) for n, v in zip(names, params)}}


def _probe(variant: str, scene_path: str, max_depth: int) -> None:
    """Subprocess body: render a tiny image of the scene as MitsubaPT would, print its mean."""
    import mitsuba as mi

    from igi.common.loader import load_scene

    mi.set_variant(variant)
    cam = load_scene(scene_path).camera
    scene = mi.load_file(scene_path)
    sensor = mi.load_dict({"type": "perspective", "fov_axis": "x", "fov": float(cam.fov_x),
                           "film": {"type": "hdrfilm", "width": 16, "height": 12, "rfilter": {"type": "box"},
                                    "pixel_format": "rgb"},
                           "sampler": {"type": "independent", "sample_count": 1}})
    params = mi.traverse(sensor)
    params["to_world"] = mi.Transform4f(np.asarray(cam.to_world, np.float64).reshape(4, 4).tolist())
    params.update()
    integ = mi.load_dict({"type": "path", "max_depth": max_depth})
    img = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=2, seed=1))
    print("PROBE-OK", float(np.nanmean(img)))


def find_libllvm() -> list[str]:
    """libLLVM shared libraries on this system, newest version first."""
    pats = ["/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
            "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*", "/usr/lib64/libLLVM*.so*"]
    found = {}
    for pat in pats:
        for p in glob.glob(pat):
            m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(p))
            if m:
                found.setdefault(os.path.realpath(p), (int(m.group(1)), p))
    return [p for _, (v, p) in sorted(found.items(), key=lambda kv: -kv[1][0])]


def probe_variant(variant: str, scene_path: Path, max_depth: int, libllvm: str | None = None,
                  timeout: float = 180) -> tuple[bool, str]:
    env = dict(os.environ)
    if libllvm:
        env["DRJIT_LIBLLVM_PATH"] = libllvm
    try:
        r = subprocess.run([sys.executable, "-c", PROBE_CODE, variant, str(scene_path), str(max_depth),
                            str(REPO_ROOT)], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, "probe timed out"
    if r.returncode == 0 and "PROBE-OK" in r.stdout:
        return True, "ok"
    tail = (r.stderr or r.stdout).strip().splitlines()
    return False, f"exit {r.returncode}: " + (tail[0][:200] if tail else "no output")


def setup_mitsuba(preference: str, threads: int, scene_path: Path, max_depth: int) -> dict:
    """Probe and select a variant; returns {"ok": bool, "variant", "reason", "attempts", …}."""
    global _MITSUBA
    if _MITSUBA is not None:
        if _MITSUBA.get("ok"):
            import drjit as dr

            dr.set_thread_count(threads)
            _MITSUBA["threads"] = threads
        return _MITSUBA
    import importlib.util

    if importlib.util.find_spec("mitsuba") is None:
        _MITSUBA = {"ok": False, "reason": "mitsuba is not installed (pip install -e '.[peers]')"}
        return _MITSUBA
    variants = ["llvm_ad_rgb", "scalar_rgb"] if preference == "auto" else [preference]
    attempts = []
    for v in variants:
        libs: list[str | None] = [None]
        if v.startswith("llvm") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
            libs += find_libllvm()
        for lib in libs:
            ok, msg = probe_variant(v, scene_path, max_depth, lib)
            attempts.append({"variant": v, "libllvm": lib or os.environ.get("DRJIT_LIBLLVM_PATH") or "default search",
                             "ok": ok, "message": msg})
            if not ok:
                continue
            if lib:
                os.environ["DRJIT_LIBLLVM_PATH"] = lib
            import drjit as dr
            import mitsuba as mi

            mi.set_variant(v)
            dr.set_thread_count(threads)
            _MITSUBA = {"ok": True, "variant": v, "mitsuba": mi.__version__, "drjit": dr.__version__,
                        "libllvm": (lib or os.environ.get("DRJIT_LIBLLVM_PATH") or "default search")
                        if v.startswith("llvm") else None,
                        "threads": threads, "attempts": attempts}
            return _MITSUBA
    _MITSUBA = {"ok": False, "reason": "no Mitsuba variant could render (see attempts); for llvm_ad_rgb try "
                "apt-get install -y libllvm19", "attempts": attempts}
    return _MITSUBA


class MitsubaPT:
    """Mitsuba 3's path tracer on the same scene file, camera and resolution as igi."""

    def __init__(self, setup: bq.SceneSetup, max_depth: int, clock: str = "wall"):
        import mitsuba as mi

        self.mi = mi
        self.clock = clock
        self.last_cpu_s = 0.0
        import drjit as dr

        t0 = time.perf_counter()
        threads = dr.thread_count()
        # Mitsuba 3.9.1 with one thread waits forever in OpenEXR's reader while loading an
        # environment map (its EXR read runs in a task of that one thread): load with two.
        dr.set_thread_count(max(threads, 2))
        try:
            self.scene = mi.load_file(str(setup.path))
        finally:
            dr.set_thread_count(threads)
        self.load_s = time.perf_counter() - t0
        cam = setup.scene.camera
        self.base_to_world = np.asarray(cam.to_world, np.float64).reshape(4, 4)
        self.integrator = mi.load_dict({"type": "path", "max_depth": int(max_depth)})
        lens = {"type": "thinlens", "aperture_radius": float(cam.aperture_radius),
                "focus_distance": float(cam.focus_distance)} if cam.aperture_radius > 0 else {"type": "perspective"}
        self.sensor = mi.load_dict({
            **lens, "fov_axis": "x", "fov": float(cam.fov_x), "near_clip": float(cam.near_clip),
            "film": {"type": "hdrfilm", "width": setup.width, "height": setup.height,
                     "rfilter": mitsuba_rfilter(cam.rfilter, cam.rfilter_params), "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": 1}})
        self._params = mi.traverse(self.sensor)
        self._to_world = None
        self.set_camera(self.base_to_world)  # an updated parameter is opaque: camera moves do not recompile
        t0 = time.perf_counter()
        for spp in (1, 2):
            self.render(spp, 0)
        self.warmup_s = time.perf_counter() - t0
        self.a, self.b = 0.0, 0.0
        self.calibration: list = []

    def set_camera(self, to_world) -> None:
        m = np.asarray(to_world, np.float64).reshape(4, 4)
        if self._to_world is not None and np.array_equal(m, self._to_world):
            return
        self._params["to_world"] = self.mi.Transform4f(m.tolist())
        self._params.update()
        self._to_world = m

    def render(self, spp: int, seed: int, to_world=None) -> tuple[np.ndarray, float]:
        if to_world is not None:
            self.set_camera(to_world)
        t0, c0 = time.perf_counter(), time.process_time()
        img = self.mi.render(self.scene, sensor=self.sensor, integrator=self.integrator, spp=int(spp),
                             seed=int(seed))
        arr = np.array(img, dtype=np.float32)[..., :3]
        self.last_cpu_s = time.process_time() - c0
        return arr, time.perf_counter() - t0

    def timed(self, spp: int, seed: int, to_world=None) -> tuple[np.ndarray, float, float]:
        """(image, time on the benchmark's clock, wall time)."""
        img, wall = self.render(spp, seed, to_world)
        return img, (self.last_cpu_s if self.clock == "cpu" else wall), wall

    def calibrate(self, spps=(1, 2, 4, 8), reps: int = 2) -> None:
        """Fit t = a + b·spp on the benchmark's clock (best of ``reps`` per spp)."""
        xs, ys = [], []
        for spp in spps:
            best = min(self.timed(spp, 1000 + spp)[1] for _ in range(reps))
            xs.append(spp)
            ys.append(best)
        b, a = np.polyfit(xs, ys, 1)
        self.b = max(float(b), 1e-6)
        self.a = max(float(a), 0.0)
        self.calibration = [[x, y] for x, y in zip(xs, ys)]

    def spp_for(self, seconds: float) -> int:
        return max(1, int((seconds - self.a) / self.b))

    def render_budget(self, seconds: float, seed: int) -> dict:
        """Render with spp fitted to ``seconds`` (benchmark clock); one retry when > 15% over or
        > 20% under, with the time per spp taken from the first render."""
        spp = self.spp_for(seconds)
        img, t, wall = self.timed(spp, seed)
        attempts = 1
        cpu = self.last_cpu_s
        if (t > 1.15 * seconds and spp > 1) or t < 0.8 * seconds:
            b = max((t - self.a) / spp, 1e-6)
            spp2 = max(1, int((seconds - self.a) / b))
            img2, t2, wall2 = self.timed(spp2, seed)
            attempts = 2
            if abs(math.log(t2 / seconds)) < abs(math.log(t / seconds)):  # keep the closer of the two
                img, t, wall, spp, cpu = img2, t2, wall2, spp2, self.last_cpu_s
        return {"image": img, "spp": spp, "time_s": wall, "cpu_s": cpu, "attempts": attempts}


# ---------------------------------------------------------------------------- igi

class _Stop(Exception):
    pass


warm_up = bq.warm_up


def igi_budget_run(setup: bq.SceneSetup, params, budgets: list[float], converged_frames: int,
                   clock: str = "wall", workers: int = 0) -> dict:
    """Accumulate frames until the largest budget is spent and ``converged_frames`` are done;
    score the running mean after every frame. ``workers`` > 0: rendered by a real master and
    that many local worker processes (wall clock only), else in this process."""
    from igi.worker.renderer import Renderer

    if not workers:  # (the workers warm up in _render_on_workers)
        warm_up(setup, params)
    t0 = time.perf_counter()
    renderer = Renderer(setup.scene) if not workers else None
    setup_s = time.perf_counter() - t0
    tmax = max(budgets)
    curve: list[dict] = []
    picks: dict[float, tuple] = {}  # budget -> (entry, image): scored in full (FLIP: slow) after the run
    state = {"scoring": 0.0, "scoring_cpu": 0.0, "prev": None, "last": None}

    def on_frame(i, img):
        ta, ca = time.perf_counter(), time.process_time()
        t = ta - state["t0"] - state["scoring"]
        cpu = ca - state["c0"] - state["scoring_cpu"]
        entry = {"frames": i + 1, "time_s": t, "cpu_s": cpu, "relmse": setup.evaluator.relmse(img)}
        curve.append(entry)
        tc = cpu if clock == "cpu" else t
        for b in budgets:
            if b not in picks and tc > b:
                prev = state["prev"]
                picks[b] = ((prev[0], prev[1], False) if prev is not None
                            else (entry, np.array(img, copy=True), True))
        state["prev"] = (entry, np.array(img, copy=True))
        done = tc >= tmax and i + 1 >= converged_frames
        if not workers:  # in one process the scoring stops the render: not igi's time
            state["scoring"] += time.perf_counter() - ta
            state["scoring_cpu"] += time.process_time() - ca
        if done:
            raise _Stop

    startup_s = None
    try:
        if workers:
            startup_s = _render_on_workers(setup, params, workers, on_frame, state)
        else:
            from igi.master.inprocess import render_local

            state["t0"], state["c0"] = time.perf_counter(), time.process_time()
            render_local(setup.scene, params, frames=1_000_000, on_frame=on_frame, width=setup.width,
                         height=setup.height, renderer=renderer)
    except _Stop:
        pass
    out_b = []
    for b in budgets:
        if b in picks:
            entry, img, over = picks[b]
            pick = {**entry, **setup.evaluator(img), "over_budget": over}
        else:  # t == tmax exactly
            pick = {**curve[-1], **setup.evaluator(state["prev"][1]), "over_budget": False}
        out_b.append({"budget_s": b, **pick})
    last = {**curve[-1], **setup.evaluator(state["prev"][1])}
    return {"setup_s": setup_s, "startup_s": startup_s, "workers": workers, "budgets": out_b, "converged": last,
            "frame_s_mean": last["time_s"] / last["frames"], "frame_cpu_s_mean": last["cpu_s"] / last["frames"],
            "curve": [[c["frames"], c["time_s"], c["cpu_s"], c["relmse"]] for c in curve],
            "curve_columns": ["frames", "time_s", "cpu_s", "relmse"]}


def _render_on_workers(setup: bq.SceneSetup, params, workers: int, on_frame, state: dict) -> float:
    """Frames rendered by a master (Broker on loopback) and ``workers`` local worker processes,
    as ``igi render --workers N`` does. Start-up, not timed: the processes started and joined,
    then one small frame of another seed (as :func:`warm_up` in one process: each worker that
    takes a task has the scene decoded, its BVH built and its one-time costs paid; none of its
    sets is reused). The clock starts at the first measured frame; returns the start-up seconds."""
    from igi.master.local_workers import local_cluster

    t0 = time.perf_counter()
    with local_cluster(setup.scene, workers) as cluster:  # the broker's task size, as igi render's default
        p, w, h = bq.warm_up_frame(setup, params)
        cluster.broker.render_sequence(p, frames=1, width=w, height=h)
        startup_s = time.perf_counter() - t0
        state["t0"], state["c0"] = time.perf_counter(), time.process_time()
        try:
            cluster.broker.render_sequence(params, frames=1_000_000, width=setup.width, height=setup.height,
                                           on_frame=on_frame)
        except _Stop:
            pass
    return startup_s


def igi_frame_bias(setup: bq.SceneSetup, params, frames: int) -> dict | None:
    """Bias and noise of one igi frame as the first frame of a budget run renders it: the mean of
    ``frames`` independent single frames (accumulation off, consecutive seeds) and the fit
    relMSE(mean of m) = bias + noise/m."""
    if frames < 2:
        return None
    from dataclasses import replace

    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer

    from igi.common.metrics import block_average, relmse

    renderer = Renderer(setup.scene)
    total = None
    curve = []  # [m, relMSE of the mean of m frames, same 4x4, relMSE of frame m alone, same 4x4]
    wall = cpu = 0.0
    for j in range(frames):
        p = replace(params, accumulate=False, seed=(int(params.seed) + j) % 2**31)
        t0, c0 = time.perf_counter(), time.process_time()
        img = render_local(setup.scene, p, frames=1, width=setup.width, height=setup.height, renderer=renderer)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        img = np.asarray(img, np.float64)
        total = img if total is None else total + img
        mean = total / (j + 1)
        curve.append([j + 1, relmse(mean, setup.ref), relmse(block_average(mean, bq.BLOCK), setup.evaluator.ref_blocks),
                      relmse(img, setup.ref), relmse(block_average(img, bq.BLOCK), setup.evaluator.ref_blocks)])
    ms = [c[0] for c in curve]
    fits = {"relmse": bq.fit_bias_noise(ms, [c[1] for c in curve]),
            f"relmse_block{bq.BLOCK}": bq.fit_bias_noise(ms, [c[2] for c in curve])}
    single = np.array([c[3] for c in curve])
    single_b = np.array([c[4] for c in curve])
    stats = {k: {"median": float(np.median(v)), "mean": float(np.mean(v)), "max": float(np.max(v)),
                 "min": float(np.min(v)), "heavy_tailed": bool(np.mean(v) > HEAVY_TAIL * np.median(v))}
             for k, v in (("relmse", single), (f"relmse_block{bq.BLOCK}", single_b))}
    mean = (total / frames).astype(np.float32)
    return {"frames": frames, "fit": fits["relmse"], "fits": fits, "single_frame": stats,
            "mean_of_frames": setup.evaluator(mean), "curve": curve,
            "curve_columns": ["m", "relmse_mean_of_m", "relmse_block4_mean_of_m", "relmse_frame_m",
                              "relmse_block4_frame_m"],
            "frame_s": wall / frames, "frame_cpu_s": cpu / frames,
            "note": "mean of independent single frames (accumulation off): its FLIP/relMSE approach those of "
                    "one frame's expectation, i.e. the bias"}


# ---------------------------------------------------------------------------- temporal stability

def orbit_cameras(scene, frames: int, step_deg: float) -> list[np.ndarray]:
    """``frames`` to_world matrices: the scene camera rotated about its up axis through a point
    in front of it (the scene centre's depth along the view axis), ``step_deg`` apart, centred
    on the original camera."""
    m = np.asarray(scene.camera.to_world, np.float64).reshape(4, 4)
    origin, up, fwd = m[:3, 3], m[:3, 1], m[:3, 2]
    up = up / np.linalg.norm(up)
    fwd = fwd / np.linalg.norm(fwd)
    lo, hi = scene.bounds()
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    d = float(np.clip(np.dot(0.5 * (lo + hi) - origin, fwd), 0.05 * diag, diag))
    target = origin + d * fwd
    out = []
    for i in range(frames):
        a = math.radians((i - (frames - 1) / 2) * step_deg)
        k = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
        r = np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)
        t = np.eye(4)
        t[:3, :3] = r
        t[:3, 3] = target - r @ target
        out.append(t @ m)
    return out


def change_stats(frames: list[np.ndarray], ref_mean: float, truth: list[np.ndarray] | None = None) -> dict:
    """Mean absolute change between consecutive frames (linear radiance, and / reference mean);
    with ``truth`` also the change left after subtracting the converged frames' change."""
    d = [float(np.mean(np.abs(b.astype(np.float64) - a))) for a, b in zip(frames, frames[1:])]
    out = {"mean_abs_change": float(np.mean(d)) if d else 0.0,
           "relative_change": (float(np.mean(d)) / ref_mean) if d and ref_mean > 0 else 0.0,
           "per_pair": d}
    if truth is not None:
        e = [float(np.mean(np.abs((b.astype(np.float64) - a) - (tb.astype(np.float64) - ta))))
             for a, b, ta, tb in zip(frames, frames[1:], truth, truth[1:])]
        out["excess_abs_change"] = float(np.mean(e)) if e else 0.0
        out["excess_relative_change"] = (float(np.mean(e)) / ref_mean) if e and ref_mean > 0 else 0.0
    return out


def igi_frames(setup, renderer, params, cameras, seeds) -> tuple[list[np.ndarray], float, float]:
    """One frame (accumulation off) per (camera, seed); returns the frames, mean wall and CPU time."""
    from dataclasses import replace

    from igi.master.inprocess import render_local

    imgs, total, total_cpu = [], 0.0, 0.0
    for cam, seed in zip(cameras, seeds):
        p = replace(params, accumulate=False, seed=int(seed))
        t0, c0 = time.perf_counter(), time.process_time()
        img = render_local(setup.scene, p, frames=1, camera=cam, width=setup.width, height=setup.height,
                           renderer=renderer)
        total += time.perf_counter() - t0
        total_cpu += time.process_time() - c0
        imgs.append(np.asarray(img, np.float32).copy())
    n = max(1, len(imgs))
    return imgs, total / n, total_cpu / n


def flicker(setup: bq.SceneSetup, params, frames: int, step_deg: float, pt: MitsubaPT | None,
            path_ref_spp: int, clock: str = "wall") -> dict:
    from igi.worker.renderer import Renderer

    ref_mean = float(np.mean(setup.ref))
    base = np.asarray(setup.scene.camera.to_world, np.float64).reshape(4, 4)
    static = [base] * frames
    orbit = orbit_cameras(setup.scene, frames, step_deg)
    s0 = int(params.seed)
    fixed, new = [s0] * frames, [s0 + i for i in range(frames)]
    out = {"frames": frames, "orbit_step_deg": step_deg, "reference_mean": ref_mean, "cases": {}}
    truth = None
    if pt is not None and path_ref_spp > 0:
        truth = [pt.render(path_ref_spp, 7000 + i, cam)[0] for i, cam in enumerate(orbit)]
        out["orbit_truth"] = f"Mitsuba PT {path_ref_spp} spp per orbit frame"
    cases = {"static_fixed_seed": (static, fixed), "static_new_seeds": (static, new),
             "orbit_fixed_seed": (orbit, fixed), "orbit_new_seeds": (orbit, new)}
    def vs_truth(imgs):
        if truth is None:
            return None
        return float(np.mean([bq.Evaluator(t, False).relmse(i) for i, t in zip(imgs, truth)]))

    igi_t, mts_t = [], []
    for name, (cams, seeds) in cases.items():
        tr = truth if name.startswith("orbit") else None
        renderer = Renderer(setup.scene)  # per case: no VPL/photon sets cached by another case
        if name.endswith("fixed_seed"):
            # not counted: builds the sets of the fixed seed, as a running session already has them
            igi_frames(setup, renderer, params, [base], [s0])
        imgs, tf, tcpu = igi_frames(setup, renderer, params, cams, seeds)
        tsel = tcpu if clock == "cpu" else tf
        igi_t.append(tsel)
        row = {"igi": {**change_stats(imgs, ref_mean, tr), "frame_s": tf, "frame_cpu_s": tcpu}}
        if tr is not None:
            row["igi"]["relmse_vs_truth"] = vs_truth(imgs)
        if pt is not None:
            # equal time per case (fixed seeds reuse igi's cached VPL sets: cheaper frames); the
            # load on a shared machine drifts, so the time per spp is fitted again right here
            pt.calibrate()
            spp = pt.spp_for(tsel)
            imgs, ts = [], []
            for cam, seed in zip(cams, seeds):
                img, t, _ = pt.timed(spp, seed, cam)
                imgs.append(img)
                ts.append(t)
            mts_t.append(float(np.mean(ts)))
            row["mitsuba"] = {**change_stats(imgs, ref_mean, tr), "spp": spp, "frame_s": float(np.mean(ts))}
            if tr is not None:
                row["mitsuba"]["relmse_vs_truth"] = vs_truth(imgs)
        out["cases"][name] = row
    out["igi_frame_s"] = float(np.mean(igi_t))
    if mts_t:
        out["mitsuba_frame_s"] = float(np.mean(mts_t))
    return out


# ---------------------------------------------------------------------------- one scene

def mean_rows(rows: list[dict]) -> dict:
    """Average repeated measurements key by key (numbers: mean; flags: any); keeps the list."""
    out = {}
    for k, v in rows[0].items():
        vals = [r.get(k) for r in rows]
        if isinstance(v, bool):
            out[k] = any(bool(x) for x in vals)
        elif isinstance(v, (int, float)) and all(isinstance(x, (int, float)) for x in vals):
            out[k] = float(np.mean(vals)) if len(rows) > 1 else v
        else:
            out[k] = v
    if len(rows) > 1:
        for k in ("relmse", f"relmse_block{bq.BLOCK}"):
            if all(r.get(k) is not None for r in rows):
                out[k + "_median"] = float(np.median([r[k] for r in rows]))
        out["repeats"] = rows
    return out


def compare_scene(setup: bq.SceneSetup, params, budgets: list[float], args, mts: dict) -> dict:
    from dataclasses import replace

    entry = setup.describe()
    clock = args.clock
    tk = bq.clock_key(clock)
    repeats = max(1, args.repeats)
    runs = []
    for rep in range(repeats):
        seed = (int(params.seed) + 100_003 * rep) % 2**31
        conv = args.converged_frames if rep == 0 else 0
        print(f"igi bench compare: {setup.name} {setup.width}x{setup.height}: igi seed {seed} to {max(budgets)} s"
              + (f" / {conv} frames" if conv else "") + " …", file=sys.stderr, flush=True)
        runs.append(igi_budget_run(setup, replace(params, seed=seed), budgets, conv, clock, args.workers))
    igi = dict(runs[0])
    igi["budgets"] = [mean_rows([run["budgets"][i] for run in runs]) for i in range(len(budgets))]
    igi["repeats"] = repeats
    if args.bias_frames >= 2:
        print(f"  igi single-frame bias: {args.bias_frames} frames …", file=sys.stderr, flush=True)
        fb = igi_frame_bias(setup, params, args.bias_frames)
        igi["frame_bias"] = fb
        fit = fb and fb["fits"].get(setup.primary)
        if fit and fit.get("reliable", True) and not fb["single_frame"][setup.primary]["heavy_tailed"]:
            for r in igi["budgets"]:
                noise = fit["noise_1frame"] / r["frames"]
                r.update({"bias": fit["bias"], "noise": noise, "bias_metric": setup.primary,
                          "bias_share": fit["bias"] / (fit["bias"] + noise) if fit["bias"] + noise > 0 else None})
    entry["igi"] = igi
    pt = None
    if mts.get("ok"):
        pt = MitsubaPT(setup, params.max_depth, clock)
        rows = []
        for i, (b, ib) in enumerate(zip(budgets, igi["budgets"])):
            budget = max(b, ib[tk]) if ib["over_budget"] else b
            pt.calibrate()  # again before every budget: the load on a shared machine drifts
            reps = []
            for rep in range(repeats):
                r = pt.render_budget(budget, seed=1 + i + 1000 * rep)
                img = r.pop("image")
                reps.append({"budget_s": b, "target_s": budget, **r, "fit_a_s": pt.a, "fit_b_s_per_spp": pt.b,
                             **setup.evaluator(img)})
            rows.append(mean_rows(reps))
            rows[-1]["calibration"] = pt.calibration
            print(f"  {b:g} s: igi {ib['frames']:g} frames {ib[tk]:.2f} s relMSE {bq.fmt(ib['relmse'])} | "
                  f"Mitsuba {rows[-1]['spp']:g} spp {rows[-1][tk]:.2f} s relMSE {bq.fmt(rows[-1]['relmse'])}",
                  file=sys.stderr, flush=True)
        entry["mitsuba"] = {"load_s": pt.load_s, "warmup_s": pt.warmup_s, "budgets": rows}
        entry["ratios"] = ratios(igi["budgets"], rows, setup.primary)
        entry["goal_analysis"] = goal_analysis(igi, rows, setup.primary)
    else:
        for ib in igi["budgets"]:
            print(f"  {ib['budget_s']:g} s: igi {ib['frames']:g} frames {ib[tk]:.2f} s relMSE "
                  f"{bq.fmt(ib['relmse'])}", file=sys.stderr, flush=True)
    if args.flicker_frames >= 2:
        print(f"  flicker: {args.flicker_frames} frames …", file=sys.stderr, flush=True)
        entry["flicker"] = flicker(setup, params, args.flicker_frames, args.orbit_step, pt, args.path_ref_spp, clock)
    return entry


def ratios(igi_rows: list[dict], mts_rows: list[dict], primary: str) -> list[dict]:
    """igi / Mitsuba per budget; the goal is judged on the primary relMSE (4x4 blocks for a noisy
    reference, references/README.md) and FLIP."""
    out = []
    for a, b in zip(igi_rows, mts_rows):
        r = {"budget_s": a["budget_s"], "goal_metric": primary}
        for k in ("relmse", f"relmse_block{bq.BLOCK}", "flip"):
            r[k] = (a[k] / b[k]) if a.get(k) is not None and b.get(k) else None
        if a["budget_s"] <= GOAL_MAX_BUDGET:
            terms = [r[primary], r["flip"]]
            r["goal_met"] = all(x is not None and x <= GOAL_RATIO for x in terms) if r[primary] is not None else None
            r["shortfall"] = max((x / GOAL_RATIO for x in terms if x is not None), default=None)
        out.append(r)
    return out


def goal_analysis(igi: dict, mts_rows: list[dict], primary: str = "relmse") -> list[dict]:
    """Per budget <= GOAL_MAX_BUDGET: what igi would need to reach GOAL_RATIO x Mitsuba's error.

    relMSE: with one frame's bias B and noise V (``igi_frame_bias``), the goal g = 0.5 x PT's
    relMSE is out of reach of faster frames when B >= g (bias dominates); otherwise igi needs
    V/(g - B) frames within the budget (speed-up = that / the frames it had). FLIP is not
    additive: the FLIP of the mean of many single frames (≈ one frame's expectation) against
    0.5 x PT's FLIP says whether noise-free frames would reach it; the FLIP after the converged
    accumulation run says whether accumulating for longer does."""
    fb = igi.get("frame_bias") or {}
    fit = (fb.get("fits") or {}).get(primary)
    heavy = bool(((fb.get("single_frame") or {}).get(primary) or {}).get("heavy_tailed"))
    if heavy or (fit and not fit.get("reliable", True)):
        fit = None  # bias + noise/frames does not describe outlier frames
    conv = igi["converged"]
    out = []
    for r, p in zip(igi["budgets"], mts_rows):
        if r["budget_s"] > GOAL_MAX_BUDGET:
            continue
        g = GOAL_RATIO * p[primary]
        row = {"budget_s": r["budget_s"], "metric": primary, "goal_relmse": g, "igi_relmse": r[primary],
               "frames": r["frames"]}
        if heavy:
            row["relmse_dominant"] = "outlier frames"
        if fit:
            row.update({"bias": fit["bias"], "noise": fit["noise_1frame"] / r["frames"]})
            row["relmse_dominant"] = "noise" if row["noise"] > fit["bias"] else "bias"
            row["bias_exceeds_goal"] = fit["bias"] >= g
            need = None if fit["bias"] >= g else fit["noise_1frame"] / (g - fit["bias"])
            row.update({"frames_needed": need, "speedup_needed": None if need is None else need / r["frames"]})
        if p.get("flip") is not None and r.get("flip") is not None:
            gf = GOAL_RATIO * p["flip"]
            mean_flip = (fb.get("mean_of_frames") or {}).get("flip")
            row.update({"goal_flip": gf, "igi_flip": r["flip"], "igi_flip_frame_mean": mean_flip,
                        "igi_flip_converged": conv.get("flip"), "converged_frames": conv["frames"],
                        "flip_dominant": None if mean_flip is None else ("bias" if mean_flip > gf else "noise")})
        out.append(row)
    return out


def _pct(v) -> str:
    return "–" if v is None else format(v, ".0%")


def markdown(results: dict) -> str:
    f = bq.fmt
    lines = ["# igi bench compare", ""]
    m = results["machine"]
    mts = results["settings"]["mitsuba"]
    clock = results["settings"].get("clock", "wall")
    tk = bq.clock_key(clock)
    fk = "frame_cpu_s" if clock == "cpu" else "frame_s"
    blk = f"relmse_block{bq.BLOCK}"
    lines.append(f"Machine: {m.get('cpu')}, {m.get('cores')} cores, {m.get('memory_gib')} GiB; load average at "
                 f"start {', '.join(f'{x:.2f}' for x in results.get('load_avg_start') or [])}, at end "
                 f"{', '.join(f'{x:.2f}' for x in results.get('load_avg_end') or [])}. Commit "
                 f"{results.get('commit')}. Command: `{results['command']}`")
    if mts.get("ok"):
        lines.append(f"Mitsuba {mts['mitsuba']} `{mts['variant']}` (libLLVM: {mts.get('libllvm')}), "
                     f"{mts['threads']} thread(s).")
    else:
        lines.append(f"Mitsuba not run: {mts.get('reason')}.")
    lines += ["", results["timing"]["igi"] + ".", "", results["timing"]["mitsuba"] + ".", "",
              results["timing"]["clock"] + f". Budgets here: **{clock}** time.", ""]
    for name, s in results["scenes"].items():
        ig = s["igi"]
        prim = s["primary_metric"]
        pname = "relMSE" if prim == "relmse" else f"relMSE {bq.BLOCK}×{bq.BLOCK}"
        lines += [f"## {name}", "",
                  f"{s['resolution'][0]}x{s['resolution'][1]}; {s['reference_comparison']}. Reference noise floor "
                  f"(relMSE) ≈ {f(s['noise_floor_relmse_est'])}"
                  + (" (a noisy reference: the goal is judged on relMSE 4×4)" if s.get("noisy_reference") else "")
                  + (f". igi scene load {s['load_s']:.2f} s + start-up of {ig['workers']} worker process(es) "
                     f"{ig['startup_s']:.2f} s (their scene, BVH and a small frame)" if ig.get("workers") else
                     f". igi scene load {s['load_s']:.2f} s + BVH {ig['setup_s']:.2f} s")
                  + (f"; Mitsuba scene load {s['mitsuba']['load_s']:.2f} s" if "mitsuba" in s else "")
                  + " (not counted).", ""]
        mt = {r["budget_s"]: r for r in s.get("mitsuba", {}).get("budgets", [])}
        rt = {r["budget_s"]: r for r in s.get("ratios", [])}
        lines += [f"| budget (s) | igi frames | igi {clock} (s) | igi relMSE | igi FLIP | igi relMSE 4×4 | "
                  f"PT spp | PT {clock} (s) | PT relMSE | PT FLIP | PT relMSE 4×4 | relMSE ratio | FLIP ratio | "
                  f"4×4 ratio | goal ({pname}, FLIP) |",
                  "|" + "---:|" * 14 + "---|"]
        for r in ig["budgets"]:
            b = r["budget_s"]
            p = mt.get(b, {})
            q = rt.get(b, {})
            goal = "" if "goal_met" not in q else ("met" if q["goal_met"] else f"short ×{q['shortfall']:.1f}")
            lines.append(f"| {b:g} | {r['frames']:g}{'*' if r['over_budget'] else ''} | {r[tk]:.2f} | "
                         f"{f(r['relmse'])} | {f(r['flip'])} | {f(r[blk])} | {f(p.get('spp'))} | "
                         f"{f(p.get(tk))} | {f(p.get('relmse'))} | {f(p.get('flip'))} | {f(p.get(blk))} | "
                         f"{f(q.get('relmse'))} | {f(q.get('flip'))} | {f(q.get(blk))} | {goal} |")
        lines.append("")
        if ig.get("repeats", 1) > 1:
            lines.append(f"Means over {ig['repeats']} runs with different seeds (per-run values in the JSON). ")
        lines.append("\\* one igi frame alone took longer than the budget; Mitsuba then got igi's time. "
                     f"Ratio = igi / Mitsuba PT; goal: ratio ≤ {GOAL_RATIO:g} for budgets ≤ {GOAL_MAX_BUDGET:g} s in "
                     f"{pname} and FLIP; 'short ×F' = the larger of the two ratios / {GOAL_RATIO:g}.")
        conv = ig["converged"]
        lines += ["", f"igi accumulation run (first seed): after {conv['frames']} frames ({conv[tk]:.1f} s {clock}) "
                  f"relMSE {f(conv['relmse'])}, FLIP {f(conv['flip'])}, relMSE 4×4 {f(conv[blk])}."]
        fb = ig.get("frame_bias") or {}
        fit = (fb.get("fits") or {}).get(prim)
        if fit:
            mf = fb["mean_of_frames"]
            sf = fb["single_frame"][prim]
            lines += ["", f"igi bias vs noise of one frame ({pname}; {fb['frames']} independent single frames, "
                      f"{fb[fk]:.2f} s each): the fit {pname}(mean of m frames) = bias + noise/m gives bias "
                      f"{f(fit['bias'])} (includes the reference floor) and noise of one frame "
                      f"{f(fit['noise_1frame'])}; single frames alone score median {f(sf['median'])}, mean "
                      f"{f(sf['mean'])}, max {f(sf['max'])}; the mean of the {fb['frames']} frames scores relMSE "
                      f"{f(mf['relmse'])}, relMSE 4×4 {f(mf[blk])}, FLIP {f(mf['flip'])}."
                      + (f" Pixel-centre sampling (one ray through each pixel centre, no jitter in a single frame; "
                         f"estimated from the reference) accounts for ≈ {f(s['pixel_centre_aliasing'])} of a "
                         f"single frame's relMSE bias." if s.get("pixel_centre_aliasing") is not None else "")
                      + (f" **The single frames are heavy-tailed** (mean > {HEAVY_TAIL:g}× median: a few frames with "
                         "outliers dominate the mean), so bias + noise/m does not describe them and no split is "
                         "given." if sf.get("heavy_tailed") else "")
                      + ("" if fit.get("reliable", True) else
                         f" The fit does not hold (max residual {fit['max_rel_residual']:.0%}).")
                      + (f" FLIP of a perfect pixel-centre image: {f(s['pixel_centre_flip'])}."
                         if s.get("pixel_centre_flip") is not None else ""),
                      "", f"| budget (s) | igi frames | igi {pname} | bias part | noise part (/frames) | bias share |",
                      "|---:|---:|---:|---:|---:|---:|"]
            for r in ig["budgets"]:
                lines.append(f"| {r['budget_s']:g} | {r['frames']:g} | {f(r[prim])} | {f(r.get('bias'))} | "
                             f"{f(r.get('noise'))} | {_pct(r.get('bias_share'))} |")
        ga = s.get("goal_analysis")
        if ga:
            lines += ["", f"Against the goal (0.5 × PT, {pname}): 'frames needed' = igi frames within the budget for "
                      "bias + noise/frames to reach the goal; the FLIP of the mean of many single frames ≈ the FLIP "
                      "noise-free frames would have:", "",
                      f"| budget (s) | goal {pname} | igi bias | igi noise | larger term | frames needed (had) | "
                      "goal FLIP | igi FLIP | FLIP mean of frames | FLIP dominant | FLIP after accumulation |",
                      "|---:|---:|---:|---:|---|---:|---:|---:|---:|---|---:|"]
            for g in ga:
                need = ("never: bias ≥ goal" if g.get("bias_exceeds_goal")
                        else f"{g['frames_needed']:.0f} ({g['frames']:g})" if g.get("frames_needed") else "–")
                lines.append(f"| {g['budget_s']:g} | {f(g['goal_relmse'])} | {f(g.get('bias'))} | {f(g.get('noise'))} | "
                             f"{g.get('relmse_dominant', '–')} | {need} | {f(g.get('goal_flip'))} | "
                             f"{f(g.get('igi_flip'))} | {f(g.get('igi_flip_frame_mean'))} | "
                             f"{g.get('flip_dominant') or '–'} | {f(g.get('igi_flip_converged'))} |")
        fl = s.get("flicker")
        if fl:
            lines += ["", f"Temporal stability ({fl['frames']} frames per case, accumulation off; orbit "
                      f"{fl['orbit_step_deg']:g}° per frame"
                      + (f"; truth along the orbit: {fl['orbit_truth']}" if fl.get("orbit_truth") else "") + "). "
                      "Change = mean |frame − previous frame| / reference mean "
                      f"({f(fl['reference_mean'])}); excess = the same for (change − the truth's change), i.e. "
                      "flicker without the motion; Mitsuba PT at igi's time per frame of the case:", "",
                      f"| case | igi {clock} s/frame | igi change | igi excess | igi relMSE vs truth | PT spp | "
                      "PT change | PT excess | PT relMSE vs truth |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
            for cname, c in fl["cases"].items():
                a, b = c["igi"], c.get("mitsuba", {})
                lines.append(f"| {cname.replace('_', ' ')} | {a[fk]:.2f} | {f(a['relative_change'])} | "
                             f"{f(a.get('excess_relative_change'))} | {f(a.get('relmse_vs_truth'))} | "
                             f"{f(b.get('spp'))} | {f(b.get('relative_change'))} | "
                             f"{f(b.get('excess_relative_change'))} | {f(b.get('relmse_vs_truth'))} |")
        lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- CLI

def add_arguments(p: argparse.ArgumentParser) -> None:
    from igi.common.params import add_arguments as add_params

    p.add_argument("scenes", nargs="+", metavar="SCENE",
                   help="scene names (folders of ../shared/scenes) or scene files")
    p.add_argument("--budgets", default=DEFAULT_BUDGETS, help=f"wall-time budgets in s (default {DEFAULT_BUDGETS})")
    p.add_argument("--converged-frames", type=int, default=64,
                   help="igi keeps accumulating to this many frames (what accumulation reaches; default 64)")
    p.add_argument("--repeats", type=int, default=1,
                   help="budget runs per renderer with different seeds, errors averaged (default 1)")
    p.add_argument("--bias-frames", type=int, default=32,
                   help="independent single frames averaged to measure one frame's bias and noise "
                        "(default 32; < 2: skip)")
    p.add_argument("--flicker-frames", type=int, default=8, help="frames per flicker case (default 8; < 2: skip)")
    p.add_argument("--orbit-step", type=float, default=1.0, help="orbit degrees per frame (default 1)")
    p.add_argument("--path-ref-spp", type=int, default=256,
                   help="Mitsuba spp of the converged frames along the orbit (default 256; 0: none)")
    p.add_argument("--mitsuba-variant", default="auto", help="auto (llvm_ad_rgb, else scalar_rgb) or a variant")
    p.add_argument("--mitsuba-threads", type=int, default=1,
                   help="Mitsuba render threads (default 1: igi's render_local uses one core)")
    p.add_argument("--workers", type=int, default=0,
                   help="igi on a real master and this many local worker processes (wall clock; give "
                        "Mitsuba as many --mitsuba-threads); default 0: in this process, one core")
    p.add_argument("--no-mitsuba", action="store_true", help="igi only")
    p.add_argument("-o", "--out", default="artifacts/bench-compare", help="output folder (default artifacts/bench-compare)")
    bq.add_common_arguments(p)
    add_params(p)


def parse_budgets(text: str) -> list[float]:
    try:
        b = sorted({float(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise bq.BenchError(f"--budgets wants seconds[,seconds…]: {text!r}") from None
    if not b or b[0] <= 0:
        raise bq.BenchError("--budgets must be > 0")
    return b


def run_compare(args: argparse.Namespace) -> dict:
    budgets = parse_budgets(args.budgets)
    if args.mitsuba_threads < 1:
        raise bq.BenchError("--mitsuba-threads must be >= 1")
    if args.workers < 0:
        raise bq.BenchError("--workers must be >= 0")
    if args.workers and args.clock != "wall":
        raise bq.BenchError("--workers renders in other processes: budgets need --clock wall")
    params = bq.base_params(args)
    refdir = Path(args.references) if args.references else None
    from igi.common.params import params_to_dict

    setups = [bq.SceneSetup(a, args.direct_only, args.width, args.height, args.scale, refdir, not args.no_flip)
              for a in args.scenes]
    if args.no_mitsuba:
        mts = {"ok": False, "reason": "--no-mitsuba"}
    else:
        mts = setup_mitsuba(args.mitsuba_variant, args.mitsuba_threads, setups[0].path,
                            2 if args.direct_only else -1)
        if not mts.get("ok"):
            print(f"igi bench compare: Mitsuba not run: {mts.get('reason')}", file=sys.stderr)
    results = {
        "benchmark": "igi bench compare", "machine": machine_info(), "commit": git_commit(),
        "command": bq.command_line(), "load_avg_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "timing": {"igi": IGI_TIMING_WORKERS.format(n=args.workers) if args.workers else IGI_TIMING,
                   "mitsuba": MITSUBA_TIMING, "clock": bq.CLOCK_NOTE},
        "settings": {"clock": args.clock, "budgets": budgets, "params": params_to_dict(params), "direct_only": bool(args.direct_only),
                     "converged_frames": args.converged_frames, "bias_frames": args.bias_frames,
                     "repeats": args.repeats,
                     "flicker_frames": args.flicker_frames,
                     "orbit_step_deg": args.orbit_step, "path_ref_spp": args.path_ref_spp,
                     "igi_processes": 1 + args.workers, "igi_workers": args.workers,
                     "mitsuba": {k: v for k, v in mts.items()},
                     "goal": f"budget <= {GOAL_MAX_BUDGET:g} s: igi relMSE and FLIP <= {GOAL_RATIO:g} x Mitsuba PT's",
                     "flip": setups[0].evaluator.use_flip},
        "scenes": {},
    }
    for setup in setups:
        results["scenes"][setup.name] = compare_scene(setup, params, budgets, args, mts)
    results["load_avg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return results


def run(args: argparse.Namespace) -> int:
    from igi.master.errors import UsageError

    try:
        results = run_compare(args)
    except bq.BenchError as e:
        raise UsageError(str(e)) from None
    paths = bq.write_outputs(results, Path(args.out), "bench-compare", markdown(results))
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)
    return 0
