"""``igi bench quality``: error against the references over parameter sweeps, and the Pareto
front of wall time against error.

    igi bench quality SCENE… [--frames 1,4,16,64] [--sweep name=v1,v2 …] [--grid]
                             [--scale 0.5 | --width W --height H] [--direct-only] [--out DIR]
                             [every render parameter flag: the base the sweeps start from]

SCENE is a scene name (a folder of ``../shared/scenes``) or a path to a scene file; its
reference is ``../shared/references/<name>.exr`` (full GI) or ``<name>-direct.exr`` with
``--direct-only`` (``max_depth`` 2).

Every configuration — the base parameters, then each sweep value (one parameter at a time;
``--grid``: the cartesian product) — is rendered once with ``master.inprocess.render_local``
(exactly the distributed path, in one process) up to the largest ``--frames`` value; the
running mean is scored at every listed frame count, so one render gives the error against
frames and against time. A sweep value ``xF`` scales the parameter's declared default by F
(e.g. ``indirect_vpls=x0.5,x2``), so sweeps follow the defaults as they are tuned.

Scores: relMSE, RMSE, relMSE of 4×4 block averages (the figure that counts for references
with a high noise floor, ``../shared/references/README.md``) and mean HDR-FLIP when the
``flip-evaluator`` package is importable. Wall time counts the frames only (tracing, VPL and
photon set building, wire codec round trip, master merge + discontinuity filter +
accumulation); scene load and BVH build are recorded apart (``load_s``, ``setup_s``), scoring
is not counted.

Reduced resolution: an image ``k`` times smaller (same camera) has pixels that are box-filtered
k×k blocks of the full one, so it is compared against the reference block-averaged k×k; the
JSON says so (``reference_comparison``). ``k`` must be an integer dividing the reference size.

Writes ``DIR/bench-quality.json`` (machine, settings, per scene every point, per configuration
a fit error(frames) = bias + noise/frames, Pareto fronts), ``DIR/bench-quality.png`` (error
against time, log-log, Pareto front marked) and ``DIR/bench-quality.md`` (the tables).
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from .paths import REFERENCES as REFERENCES_DIR, SHARED_SCENES as SCENES_DIR
from .report import git_commit, machine_info, pyplot


BLOCK = 4  # block size of the block-averaged relMSE (references/README.md)
NOISY_FLOOR = 0.01  # full-resolution noise floor (relMSE) above which a reference counts as noisy
DEFAULT_FRAMES = "1,4,16,64"
FIT_MAX_RESIDUAL = 0.5  # a bias + noise/frames fit worse than this (heavy-tailed frames) is flagged
# Sweeps when none are given; "xF" scales the declared default (common.params) by F.
DEFAULT_SWEEPS = ("indirect_vpls=x0.5,x2", "interleave=1,2,4", "filter_window=1", "photons=0,x2")

CLOCK_NOTE = ("time_s is wall-clock time, cpu_s the process's CPU time over the same span; --clock picks the one "
              "budgets and Pareto fronts use. On an idle core they agree; on a machine shared with other jobs "
              "the CPU time is what the same work costs on an idle core (wall time stretches with the load)")
TIMING_NOTE = ("time_s: wall time of the frames only (eye rays, VPL/photon set building, shading, wire codec "
               "round trip, master merge + discontinuity filter + accumulation) in one process "
               "(master.inprocess.render_local); scene load (load_s) and geometry/BVH build (setup_s) are "
               "recorded apart; computing the error is not counted")


class BenchError(Exception):
    """Bad benchmark input (reported by the CLI as ``igi: error: ...``)."""


# ---------------------------------------------------------------------------- scenes, references

def resolve_scene(arg: str) -> tuple[str, Path]:
    """(name, scene file) from a scene name (folder of ../shared/scenes) or a path."""
    p = Path(arg)
    if not p.exists():
        cand = SCENES_DIR / arg / "scene.xml"
        if cand.exists():
            return arg, cand
        raise BenchError(f"scene not found: {arg} (neither a file nor a scene in {SCENES_DIR})")
    if p.is_dir():
        p = p / "scene.xml"
        if not p.exists():
            raise BenchError(f"no scene.xml in {arg}")
    name = p.parent.name if p.name == "scene.xml" else p.stem
    return name, p


def reference_path(name: str, direct_only: bool = False, refdir: Path | None = None) -> Path:
    return Path(refdir or REFERENCES_DIR) / (f"{name}-direct.exr" if direct_only else f"{name}.exr")


def reference_info(name: str, direct_only: bool = False, refdir: Path | None = None) -> dict:
    """The reference's entry in references.json (integrator, spp, noise floor), or {}."""
    try:
        data = json.loads((Path(refdir or REFERENCES_DIR) / "references.json").read_text())
    except (OSError, ValueError):
        return {}
    entry = data.get(name, {})
    out = dict(entry.get("direct" if direct_only else "full", {}))
    for k in ("renderer", "pixel_filter", "size"):
        if k in entry:
            out[k] = entry[k]
    return out


def load_reference(name: str, direct_only: bool = False, refdir: Path | None = None) -> tuple[Path, np.ndarray]:
    from igi.common.image_io import read_image

    path = reference_path(name, direct_only, refdir)
    if not path.exists():
        raise BenchError(f"no reference for {name}: {path}")
    return path, np.asarray(read_image(path), np.float32)[..., :3]


def downscale_factor(ref_w: int, ref_h: int, width: int | None = None, height: int | None = None,
                     scale: float | None = None) -> int:
    """The integer k with render size = reference size / k (1 = full resolution)."""
    if scale is not None:
        if width is not None or height is not None:
            raise BenchError("give --scale or --width/--height, not both")
        if not 0 < scale <= 1:
            raise BenchError("--scale must be in (0, 1]")
        k = round(1 / scale)
        if abs(1 / scale - k) > 1e-6:
            raise BenchError(f"--scale {scale} is not 1/k for an integer k")
    elif width is None and height is None:
        return 1
    else:
        ks = set()
        if width is not None:
            if width < 1 or ref_w % width:
                raise BenchError(f"--width {width} does not divide the reference width {ref_w}")
            ks.add(ref_w // width)
        if height is not None:
            if height < 1 or ref_h % height:
                raise BenchError(f"--height {height} does not divide the reference height {ref_h}")
            ks.add(ref_h // height)
        if len(ks) != 1:
            raise BenchError("--width and --height must shrink the reference by the same factor")
        k = ks.pop()
    if ref_w % k or ref_h % k:
        raise BenchError(f"scale 1/{k} does not divide the reference size {ref_w}x{ref_h}")
    return k


def reduced_reference(ref: np.ndarray, k: int) -> np.ndarray:
    """The reference as a k× smaller render of the same camera sees it: k×k box averages."""
    from igi.common.metrics import block_average

    if k == 1:
        return np.asarray(ref, np.float32)
    return block_average(ref, k).astype(np.float32)


def pixel_centre_reference(ref: np.ndarray, k: int) -> np.ndarray | None:
    """The full-resolution reference sampled at the centres of the k× smaller image's pixels
    (the central pixel for odd k, the central 2×2 average for even k): what a perfect renderer
    that shoots one ray through each pixel centre would show; None for k <= 2 (at 1/2 the
    central 2×2 is the whole block)."""
    if k <= 2:
        return None
    h, w = ref.shape[0] // k, ref.shape[1] // k
    x = np.asarray(ref[:h * k, :w * k], np.float64).reshape(h, k, w, k, -1)
    c = k // 2
    if k % 2:
        return x[:, c, :, c].astype(np.float32)
    return x[:, c - 1:c + 1, :, c - 1:c + 1].mean(axis=(1, 3)).astype(np.float32)


def comparison_note(k: int, ref_w: int, ref_h: int) -> str:
    if k == 1:
        return f"full resolution {ref_w}x{ref_h}: compared pixel for pixel with the reference"
    return (f"rendered at 1/{k} resolution ({ref_w // k}x{ref_h // k}, same camera) and compared with the "
            f"reference block-averaged {k}x{k}: a box-filtered pixel of the smaller image is the {k}x{k} "
            f"average of the full-resolution one; the reference's own noise floor shrinks by ~{k * k}x")


class Evaluator:
    """Scores an image against the (possibly reduced) reference."""

    def __init__(self, ref: np.ndarray, use_flip: bool = True):
        from igi.common.metrics import block_average

        self.ref = np.asarray(ref, np.float32)
        self.ref_blocks = block_average(self.ref, BLOCK)
        self.use_flip = use_flip and flip_available()

    def relmse(self, img: np.ndarray) -> float:
        from igi.common.metrics import relmse

        return relmse(img, self.ref)

    def __call__(self, img: np.ndarray, flip: bool = True) -> dict:
        from igi.common.metrics import block_average, flip as flip_metric, relmse, rmse

        img = np.asarray(img, np.float32)
        out = {"relmse": relmse(img, self.ref), "rmse": rmse(img, self.ref),
               f"relmse_block{BLOCK}": relmse(block_average(img, BLOCK), self.ref_blocks),
               "flip": flip_metric(img, self.ref) if (flip and self.use_flip) else None}
        return out


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401
    except ImportError:
        return False
    return True


class SceneSetup:
    """A scene with its reference at the benchmark resolution."""

    def __init__(self, arg: str, direct_only: bool = False, width: int | None = None, height: int | None = None,
                 scale: float | None = None, refdir: Path | None = None, use_flip: bool = True):
        from igi.common.loader import load_scene

        self.name, self.path = resolve_scene(arg)
        self.ref_path, ref = load_reference(self.name, direct_only, refdir)
        self.info = reference_info(self.name, direct_only, refdir)
        from igi.common.scene import SceneError

        t0 = time.perf_counter()
        try:
            self.scene = load_scene(self.path)
        except (SceneError, OSError) as e:
            raise BenchError(f"cannot load scene {self.path}: {e}") from None
        self.load_s = time.perf_counter() - t0
        self.ref_h, self.ref_w = ref.shape[:2]
        cam = self.scene.camera
        if (cam.width, cam.height) != (self.ref_w, self.ref_h):
            raise BenchError(f"{self.name}: the scene's film is {cam.width}x{cam.height} but the reference is "
                             f"{self.ref_w}x{self.ref_h}")
        self.k = downscale_factor(self.ref_w, self.ref_h, width, height, scale)
        self.width, self.height = self.ref_w // self.k, self.ref_h // self.k
        self.ref = reduced_reference(ref, self.k)
        centre = pixel_centre_reference(ref, self.k)
        from igi.common.metrics import relmse

        self.pixel_centre_relmse = None if centre is None else relmse(centre, self.ref)
        self.pixel_centre_flip = (None if centre is None or not self.evaluator_flip(use_flip)
                                  else self._flip(centre))
        floor_full = self.info.get("noise_relmse_est")
        m = 1 if self.k % 2 else 4
        # the reference's own noise in (centre - block mean): sigma^2 (1/m - 1/k^2)
        self.pixel_centre_noise = (None if centre is None or floor_full is None
                                   else floor_full * (1 / m - 1 / self.k ** 2))
        self.evaluator = Evaluator(self.ref, use_flip)
        floor = self.info.get("noise_relmse_est")
        self.noisy = floor is not None and floor >= NOISY_FLOOR
        self.primary = f"relmse_block{BLOCK}" if self.noisy else "relmse"

    @staticmethod
    def evaluator_flip(use_flip: bool) -> bool:
        return use_flip and flip_available()

    def _flip(self, img):
        from igi.common.metrics import flip

        return flip(img, self.ref)

    def describe(self) -> dict:
        floor = self.info.get("noise_relmse_est")
        return {
            "scene": str(self.path), "reference": str(self.ref_path), "reference_info": self.info,
            "reference_resolution": [self.ref_w, self.ref_h], "resolution": [self.width, self.height],
            "downscale": self.k, "reference_comparison": comparison_note(self.k, self.ref_w, self.ref_h),
            "noise_floor_relmse_full_res": floor,
            "noise_floor_relmse_est": None if floor is None else floor / (self.k * self.k),
            "noise_floor_note": "the reference's own noise (references.json noise_relmse_est) divided by k^2 for "
                                "a k-times block-averaged reference: no render can score below it",
            "noisy_reference": self.noisy, "primary_metric": self.primary, "load_s": self.load_s,
            "pixel_centre_relmse": self.pixel_centre_relmse,
            "pixel_centre_flip": self.pixel_centre_flip,
            "pixel_centre_ref_noise": self.pixel_centre_noise,
            "pixel_centre_aliasing": (None if self.pixel_centre_relmse is None else
                                      max(0.0, self.pixel_centre_relmse - (self.pixel_centre_noise or 0.0))),
            "pixel_centre_note": "relMSE of the full-resolution reference sampled at the reduced pixels' centres "
                                 "against the block-averaged one: the aliasing a frame with one ray through each "
                                 "pixel centre (igi without accumulation jitter) carries at this scale; "
                                 "pixel_centre_aliasing subtracts the reference's own noise in that difference "
                                 "(pixel_centre_ref_noise, from noise_relmse_est)",
        }


# ---------------------------------------------------------------------------- sweeps

def parse_value(name: str, text: str):
    """One sweep value of parameter ``name``: a literal, or ``xF`` = F × the declared default."""
    from igi.common.params import PARAM_BY_NAME

    p = PARAM_BY_NAME[name]
    text = text.strip()
    if text[:1] in ("x", "*") and p.type in (int, float):
        try:
            f = float(text[1:])
        except ValueError:
            raise BenchError(f"--sweep {name}: bad factor {text!r}") from None
        if p.default is None or p.default < 0:
            raise BenchError(f"--sweep {name}: its default {p.default} means 'automatic'; give values, not {text}")
        v = p.default * f
        return max(1, round(v)) if p.type is int and p.default > 0 else p.type(v)
    if p.type is bool:
        if text.lower() in ("1", "true", "on", "yes"):
            return True
        if text.lower() in ("0", "false", "off", "no"):
            return False
        raise BenchError(f"--sweep {name}: {text!r} is not a boolean")
    try:
        return p.type(text)
    except ValueError:
        raise BenchError(f"--sweep {name}: {text!r} is not a {p.type.__name__}") from None


def parse_sweeps(items) -> list[tuple[str, list]]:
    from igi.common.params import PARAM_BY_NAME

    out = []
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not values.strip():
            raise BenchError(f"--sweep wants name=v1,v2,…: {item!r}")
        if name == "frames":
            raise BenchError("frames are swept with --frames 1,4,16,…")
        if name not in PARAM_BY_NAME:
            raise BenchError(f"--sweep: unknown parameter {name!r}")
        out.append((name, [parse_value(name, v) for v in values.split(",") if v.strip()]))
    return out


def _label(overrides: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in overrides.items()) or "base"


def make_configs(base, sweeps: list[tuple[str, list]], grid: bool = False) -> list[dict]:
    """The configurations: the base parameters first, then one per sweep value (or the grid).
    Each is {"label", "overrides", "params"}; invalid values raise BenchError."""
    from igi.common.params import make_params, params_to_dict

    bd = params_to_dict(base)

    def build(overrides: dict) -> dict:
        try:
            params = make_params(**{**bd, **overrides})
        except ValueError as e:
            raise BenchError(str(e)) from None
        return {"label": _label(overrides), "overrides": overrides, "params": params}

    configs = [build({})]
    seen = {tuple(sorted(params_to_dict(base).items()))}
    if grid and sweeps:
        names = [n for n, _ in sweeps]
        combos = [dict(zip(names, vals)) for vals in itertools.product(*(v for _, v in sweeps))]
    else:
        combos = [{n: v} for n, vals in sweeps for v in vals]
    for ov in combos:
        ov = {k: v for k, v in ov.items() if bd[k] != v}
        c = build(ov)
        key = tuple(sorted(params_to_dict(c["params"]).items()))
        if key in seen:
            continue
        seen.add(key)
        configs.append(c)
    return configs


def default_sweeps(scene) -> list[str]:
    """DEFAULT_SWEEPS, less photons when the scene has no caustic paths (photons would not run)."""
    try:
        from igi.worker.renderer import Renderer

        caustics = Renderer(scene).plan.caustics
    except Exception:  # pragma: no cover - a plan failure only costs a useless sweep
        caustics = True
    return [s for s in DEFAULT_SWEEPS if caustics or not s.startswith("photons")]


# ---------------------------------------------------------------------------- analysis

def pareto_front(points: list[dict], x: str = "time_s", y: str = "relmse") -> list[int]:
    """Indices of the points no other point beats in both x and y (lower is better), by x."""
    idx = [i for i, p in enumerate(points) if p.get(x) is not None and p.get(y) is not None
           and math.isfinite(p[x]) and math.isfinite(p[y])]
    idx.sort(key=lambda i: (points[i][x], points[i][y]))
    front, best = [], math.inf
    for i in idx:
        if points[i][y] < best:
            front.append(i)
            best = points[i][y]
    return front


def dominated(points: list[dict], i: int, x: str = "time_s", y: str = "relmse") -> bool:
    """Whether some point is at least as good as point i in x and y, and better in one."""
    a = points[i]
    return any(p[x] <= a[x] and p[y] <= a[y] and (p[x] < a[x] or p[y] < a[y])
               for j, p in enumerate(points) if j != i)


def fit_bias_noise(frames, errors) -> dict | None:
    """Least-squares fit of error(frames) = bias + noise / frames with bias, noise >= 0.

    For a mean of independent frames the expected relMSE is exactly that: the squared bias
    (plus the reference's own noise floor) and the variance of one frame over the frame count.
    """
    f = np.asarray(frames, np.float64)
    e = np.asarray(errors, np.float64)
    ok = np.isfinite(e) & (f > 0)
    f, e = f[ok], e[ok]
    if len(np.unique(f)) < 2:
        return None
    from scipy.optimize import nnls

    a = np.stack([np.ones_like(f), 1.0 / f], axis=1)
    (bias, noise), _ = nnls(a, e)
    pred = bias + noise / f
    resid = float(np.max(np.abs(pred - e) / np.maximum(e, 1e-30)))
    return {"bias": float(bias), "noise_1frame": float(noise), "max_rel_residual": resid,
            "reliable": resid <= FIT_MAX_RESIDUAL,
            "model": "relmse(frames) = bias + noise_1frame / frames"}


# ---------------------------------------------------------------------------- rendering

def warm_up_frame(setup: "SceneSetup", params) -> tuple:
    """(params, width, height) of the warm-up frame: ¼ size, another seed (its sets never reused)."""
    from dataclasses import replace

    from igi.common.frame import frame_seed

    return (replace(params, seed=frame_seed(params.seed, 99991)), max(1, setup.width // 4),
            max(1, setup.height // 4))


def warm_up(setup: "SceneSetup", params) -> float:
    """One small frame on a throwaway Renderer (:func:`warm_up_frame`), so measured runs do not
    pay this process's one-time costs (lazy imports, first-call allocations); a later Renderer
    does not see its cached VPL/photon sets."""
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer

    t0 = time.perf_counter()
    p, w, h = warm_up_frame(setup, params)
    render_local(setup.scene, p, frames=1, width=w, height=h, renderer=Renderer(setup.scene))
    return time.perf_counter() - t0


def render_config(setup: SceneSetup, params, frames: list[int], save_dir: Path | None = None,
                  label: str = "") -> dict:
    """Render one configuration up to max(frames); score the running mean at each count."""
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer

    t0 = time.perf_counter()
    renderer = Renderer(setup.scene)
    setup_s = time.perf_counter() - t0
    checkpoints = set(frames)
    points, curve = [], []
    state = {"scoring": 0.0, "scoring_cpu": 0.0}

    def on_frame(i, img):
        ta, ca = time.perf_counter(), time.process_time()
        t = ta - state["t0"] - state["scoring"]
        cpu = ca - state["c0"] - state["scoring_cpu"]
        n = i + 1
        curve.append([n, t, cpu, setup.evaluator.relmse(img)])
        if n in checkpoints:
            pt = {"frames": n, "time_s": t, "cpu_s": cpu, **setup.evaluator(img)}
            points.append(pt)
            if save_dir is not None:
                from igi.common.image_io import write_exr

                save_dir.mkdir(parents=True, exist_ok=True)
                safe = "".join(c if c.isalnum() or c in "-_.=" else "_" for c in label) or "base"
                write_exr(save_dir / f"{setup.name}_{safe}_f{n}.exr", img)
        state["scoring"] += time.perf_counter() - ta
        state["scoring_cpu"] += time.process_time() - ca

    state["t0"], state["c0"] = time.perf_counter(), time.process_time()
    render_local(setup.scene, params, frames=max(frames), on_frame=on_frame, width=setup.width,
                 height=setup.height, renderer=renderer)
    fit = fit_bias_noise([c[0] for c in curve], [c[3] for c in curve])
    return {"setup_s": setup_s, "points": points, "curve": curve, "bias_fit": fit}


# ---------------------------------------------------------------------------- output

def command_line() -> str:
    import shlex

    argv = sys.argv[1:]
    return shlex.join(["igi"] + argv) if argv[:1] == ["bench"] else shlex.join(sys.argv)


def fmt(v, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, (int, np.integer)):
        return str(v)
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 1e-3:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def markdown(results: dict) -> str:
    lines = ["# igi bench quality", ""]
    m = results["machine"]
    lines.append(f"Machine: {m.get('cpu')}, {m.get('cores')} cores; load average at start "
                 f"{', '.join(f'{x:.2f}' for x in results.get('load_avg_start') or [])}. "
                 f"Commit {results.get('commit')}. Command: `{results['command']}`")
    lines += ["", results["timing"] + ". " + CLOCK_NOTE + f"; this run: --clock {results['settings']['clock']}.", ""]
    for name, s in results["scenes"].items():
        prim = s["primary_metric"]
        lines += [f"## {name}", "",
                  f"{s['resolution'][0]}x{s['resolution'][1]}; {s['reference_comparison']}. Reference noise floor "
                  f"(relMSE) ≈ {fmt(s['noise_floor_relmse_est'])}. Scene load {s['load_s']:.2f} s. "
                  f"Pareto front on {results['settings']['clock']} time vs {prim} marked ★.", "",
                  f"| configuration | frames | wall (s) | CPU (s) | relMSE | relMSE {BLOCK}×{BLOCK} | RMSE | FLIP | |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
        front = set(s["pareto"][prim])
        for i, p in enumerate(s["points"]):
            lines.append(f"| {p['config']} | {p['frames']} | {p['time_s']:.2f} | {p['cpu_s']:.2f} | {fmt(p['relmse'])} | "
                         f"{fmt(p[f'relmse_block{BLOCK}'])} | {fmt(p['rmse'])} | {fmt(p['flip'])} | "
                         f"{'★' if i in front else ''} |")
        lines += ["", "Fit relMSE(frames) = bias + noise/frames over every frame of each configuration:", "",
                  "| configuration | setup (s) | bias | noise (1 frame) | noise share at 1 frame | fit holds (max residual) |",
                  "|---|---:|---:|---:|---:|---|"]
        for c in s["configs"]:
            f = c["bias_fit"]
            if f is None:
                lines.append(f"| {c['label']} | {c['setup_s']:.2f} | – | – | – |")
                continue
            tot = f["bias"] + f["noise_1frame"]
            lines.append(f"| {c['label']} | {c['setup_s']:.2f} | {fmt(f['bias'])} | {fmt(f['noise_1frame'])} | "
                         f"{(f['noise_1frame'] / tot if tot > 0 else 0):.0%} | "
                         f"{'yes' if f.get('reliable', True) else 'no'} ({f['max_rel_residual']:.0%}) |")
        lines.append("")
    return "\n".join(lines)


def plot(results: dict, path: Path) -> bool:
    plt = pyplot("quality")
    if plt is None:
        return False
    scenes = list(results["scenes"].items())
    tk = clock_key(results["settings"]["clock"])
    has_flip = any(p["flip"] is not None for _, s in scenes for p in s["points"])
    cols = 2 if has_flip else 1
    fig, axes = plt.subplots(len(scenes), cols, figsize=(6.5 * cols, 4.5 * len(scenes)), squeeze=False)
    for row, (name, s) in enumerate(scenes):
        for col, metric in enumerate([s["primary_metric"]] + (["flip"] if has_flip else [])):
            ax = axes[row][col]
            pts = s["points"]
            for c in s["configs"]:
                cp = [p for p in pts if p["config"] == c["label"] and p.get(metric) is not None]
                if cp:
                    ax.plot([p[tk] for p in cp], [p[metric] for p in cp], "o-", ms=4, lw=1,
                            label=c["label"])
            front = s["pareto"].get(metric, [])
            if front:
                fx = [pts[i][tk] for i in front]
                fy = [pts[i][metric] for i in front]
                ax.step(fx, fy, "k--", where="post", lw=1.2, label="Pareto front")
                ax.scatter(fx, fy, s=90, facecolors="none", edgecolors="k", zorder=5)
            floor = s.get("noise_floor_relmse_est")
            ys = [p[metric] for p in pts if p.get(metric)]
            if metric == "relmse" and floor and ys and floor > min(ys) / 30:
                ax.axhline(floor, color="grey", lw=0.8, ls=":", label="reference noise floor")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(("CPU" if tk == "cpu_s" else "wall") + " time (s), frames only")
            ax.set_ylabel(metric)
            ax.set_title(f"{name} {s['resolution'][0]}x{s['resolution'][1]}: {metric}")
            ax.grid(True, which="both", alpha=0.3)
            if col == 0:
                ax.legend(fontsize=7)
    m = results["machine"]
    fig.suptitle(f"igi bench quality — {m.get('cpu')}, {m.get('cores')} cores")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


# ---------------------------------------------------------------------------- CLI

def clock_key(clock: str) -> str:
    return "cpu_s" if clock == "cpu" else "time_s"


def parse_frames(text: str) -> list[int]:
    try:
        frames = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise BenchError(f"--frames wants N[,N…]: {text!r}") from None
    if not frames or frames[0] < 1:
        raise BenchError("--frames values must be >= 1")
    return frames


def add_common_arguments(p: argparse.ArgumentParser) -> None:
    """Size, reference and output options shared with ``igi bench compare``."""
    p.add_argument("--width", type=int, default=None, help="render width (must divide the reference's)")
    p.add_argument("--height", type=int, default=None, help="render height (must divide the reference's)")
    p.add_argument("--scale", type=float, default=None,
                   help="render at 1/k of the reference size (0.5, 0.25, …); compared with the reference "
                        "block-averaged k×k")
    p.add_argument("--direct-only", action="store_true",
                   help="max_depth 2, against <scene>-direct.exr (default: full GI against <scene>.exr)")
    p.add_argument("--references", default=None, help=f"reference folder (default {REFERENCES_DIR})")
    p.add_argument("--no-flip", action="store_true", help="skip FLIP even when flip-evaluator is installed")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="time that budgets / Pareto fronts use: wall clock (default) or this process's CPU time "
                        "(what the work costs on an idle core when the machine is shared)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from igi.common.params import add_arguments as add_params

    p.add_argument("scenes", nargs="+", metavar="SCENE",
                   help="scene names (folders of ../shared/scenes) or scene files")
    p.add_argument("--frames", default=DEFAULT_FRAMES, help=f"frame counts scored (default {DEFAULT_FRAMES})")
    p.add_argument("--sweep", action="append", default=[], metavar="NAME=V1,V2",
                   help="a parameter and its values (repeatable; 'xF' = F × the default); default: "
                        + "; ".join(DEFAULT_SWEEPS))
    p.add_argument("--grid", action="store_true", help="every combination of the sweeps (default: one at a time)")
    p.add_argument("--save-images", action="store_true", help="also write every scored image as EXR into DIR/images")
    p.add_argument("-o", "--out", default="artifacts/bench-quality",
                   help="output folder (default artifacts/bench-quality)")
    add_common_arguments(p)
    add_params(p)


def base_params(args: argparse.Namespace):
    from igi.master.cli import params_from
    from igi.master.errors import UsageError

    try:
        return params_from(args)
    except UsageError as e:
        raise BenchError(str(e)) from None


def run_quality(args: argparse.Namespace) -> dict:
    frames = parse_frames(args.frames)
    base = base_params(args)
    sweeps_given = parse_sweeps(args.sweep) if args.sweep else None
    refdir = Path(args.references) if args.references else None
    out = Path(args.out)
    results = {
        "benchmark": "igi bench quality", "machine": machine_info(), "commit": git_commit(),
        "command": command_line(),
        "load_avg_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "timing": TIMING_NOTE, "clock_note": CLOCK_NOTE,
        "settings": {"clock": args.clock, "frames": frames, "grid": bool(args.grid), "direct_only": bool(args.direct_only),
                     "base_params": None, "sweeps": None, "block": BLOCK, "flip": None},
        "scenes": {},
    }
    from igi.common.params import params_to_dict

    results["settings"]["base_params"] = params_to_dict(base)
    for arg in args.scenes:
        setup = SceneSetup(arg, args.direct_only, args.width, args.height, args.scale, refdir, not args.no_flip)
        results["settings"]["flip"] = setup.evaluator.use_flip
        sweeps = sweeps_given if sweeps_given is not None else parse_sweeps(default_sweeps(setup.scene))
        results["settings"]["sweeps"] = {n: v for n, v in sweeps}
        configs = make_configs(base, sweeps, args.grid)
        entry = setup.describe()
        entry.update({"points": [], "configs": [], "pareto": {}})
        entry["warmup_s"] = warm_up(setup, base)  # not counted, as for Mitsuba's JIT warm-up
        for c in configs:
            print(f"igi bench quality: {setup.name} {setup.width}x{setup.height} [{c['label']}] "
                  f"{max(frames)} frames …", file=sys.stderr, flush=True)
            r = render_config(setup, c["params"], frames, out / "images" if args.save_images else None, c["label"])
            for p in r["points"]:
                entry["points"].append({"config": c["label"], **p})
            entry["configs"].append({"label": c["label"], "overrides": c["overrides"],
                                     "params": params_to_dict(c["params"]), "setup_s": r["setup_s"],
                                     "bias_fit": r["bias_fit"], "curve": r["curve"],
                                     "curve_columns": ["frames", "time_s", "cpu_s", "relmse"]})
            last = r["points"][-1]
            print(f"  {last['frames']} frames {last['time_s']:.2f} s relMSE {fmt(last['relmse'])} "
                  f"FLIP {fmt(last['flip'])}", file=sys.stderr, flush=True)
        for metric in ("relmse", f"relmse_block{BLOCK}", "rmse", "flip"):
            entry["pareto"][metric] = pareto_front(entry["points"], clock_key(args.clock), metric)
        results["scenes"][setup.name] = entry
    results["load_avg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return results


def write_outputs(results: dict, out: Path, stem: str, md: str, plotter=None) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}.json", out / f"{stem}.md"]
    paths[0].write_text(json.dumps(results, indent=1, default=_json_default))
    paths[1].write_text(md)
    if plotter is not None and plotter(results, out / f"{stem}.png"):
        paths.append(out / f"{stem}.png")
    return paths


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def run(args: argparse.Namespace) -> int:
    from igi.master.errors import UsageError

    try:
        results = run_quality(args)
    except BenchError as e:
        raise UsageError(str(e)) from None
    paths = write_outputs(results, Path(args.out), "bench-quality", markdown(results), plot)
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)
    return 0
