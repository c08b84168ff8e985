"""The ``igi`` command line.

    igi render SCENE -o OUT.exr|OUT.png [--frames N] [--width W --height H] [--workers N]
               [--direct-only] [every render parameter flag of common.params, e.g. --max-depth, --seed]
    igi master [--bind tcp://127.0.0.1:5555] [SCENE]
    igi worker --connect tcp://HOST:5555 [--threads T]
    igi serve [SCENE] [--workers N] [--bind ...] [--http HOST:PORT] [--pub tcp://HOST:PORT]
    igi scenes [--paths]            the bundled scenes (common/scenes/), usable by name as SCENE
    igi record tcp://127.0.0.1:5556 -o DIR [--count N] [--format png|exr]   (master/record.py)
    igi bench NAME [...]           (NAME: scaling, quality, ...; the registry in bench/__init__.py)

``igi render`` renders through the master + local worker processes (one per core by default),
the same path as ``igi serve``; ``--workers 0`` renders in this process (``render_local``), for
debugging. Output by extension: ``.exr`` linear float, ``.png`` sRGB 8 bit.

Bench registry: ``igi bench NAME`` runs the module that ``bench.BENCHES[NAME]`` names (it
defines ``add_arguments(parser)`` and ``run(args) -> int``); the ``bench`` package is imported
only here, inside the bench subcommand.

Viewer hook: ``igi serve`` (and ``igi master`` with a scene) calls
``master.viewer.start(broker, host, port, args)`` when that module exists; it returns an object
with ``stop()``. Without it the master streams frames and logs stats only.

``--scene-root DIR`` (render, serve, master; default: the scene file's folder) confines every
file a scene names to DIR (common/scene_root.py): a path that leads outside is refused.

Bad input (missing scene file, a scene that does not load, a bad parameter, an address that
cannot be bound) gives one line ``igi: error: ...`` on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from igi.master.errors import RenderError, UsageError
from igi.master.local_workers import supervise_workers

log = logging.getLogger("igi")


# ---------------------------------------------------------------------------- helpers

def load_scene_file(path: str | None, root: str | None = None):
    """Load a scene file, or a bundled scene by name (``igi scenes``); an existing path wins.
    ``root`` (``--scene-root``; None = the scene file's folder) confines the files the scene may
    name (:mod:`common.scene_root`)."""
    from igi.common import bundled
    from igi.common.scene import SceneError

    p = bundled.resolve(path)
    if p is None:
        known = ", ".join(bundled.names()) or "none"
        raise UsageError(f"scene file not found: {path} (and no bundled scene of that name; bundled: {known})")
    path = str(p)
    if not p.exists():
        raise UsageError(f"scene file not found: {path}")
    if not p.is_file():
        raise UsageError(f"scene path is not a file: {path}")
    from igi.common.loader import load_scene

    try:
        return load_scene(p, root=root)
    except SceneError as e:
        raise UsageError(f"cannot load scene {path}: {e}") from None
    except OSError as e:
        raise UsageError(f"cannot read scene {path}: {e}") from None


def params_from(args: argparse.Namespace):
    from igi.common.params import params_from_args

    try:
        params = params_from_args(args)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if getattr(args, "direct_only", False):
        if args.max_depth is not None and args.max_depth != 2:
            raise UsageError("--direct-only means --max-depth 2; do not give both")
        from dataclasses import replace

        params = replace(params, max_depth=2)
    return params


def check_sizes(width, height, frames=None, scene=None, params=None) -> None:
    """The shared limits (common/limits.py) on what a render asks for; UsageError naming the limit.
    Without a scene only the sides given are checked; with one, the effective resolution."""
    from igi.common import limits

    try:
        if frames is not None:
            limits.check_frames(frames)
        if scene is None:
            limits.check_resolution(width or 1, height or 1, what="--width/--height")
            return
        from igi.common.camera import resolve_camera

        _cam, _fov, w, h = resolve_camera(scene, None, width, height)
        limits.check_resolution(w, h)
        if params is not None:
            limits.check_params(params, emitters=len(scene.emitters))
    except limits.LimitError as e:
        raise UsageError(str(e)) from None


def apply_memory_budget(args: argparse.Namespace) -> None:
    from igi.common import limits

    try:
        limits.set_memory_budget(getattr(args, "memory_budget", None))
    except limits.LimitError as e:
        raise UsageError(str(e)) from None


def check_bind(address: str) -> None:
    """Warn when the master is reachable from other hosts (an explicit choice)."""
    host = address.split("://", 1)[-1].rsplit(":", 1)[0]
    if host not in ("127.0.0.1", "localhost", "[::1]", "::1") and not address.startswith(("ipc://", "inproc://")):
        log.warning("master bound to %s: reachable from the network, without authentication", address)


class Progress:
    """A one-line progress bar on stderr (a line per ~10% when stderr is not a terminal).

    The frame rate is the one since the first frame: the first holds the start-up (workers
    spawned, kernels and scene loaded, the first sets built), which a rate from the launch
    would spread over every frame, and the ETA with it."""

    def __init__(self, total: int, label: str = "rendering", stream=None, clock=time.monotonic):
        self.total, self.label = total, label
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.clock = clock
        self.t0 = clock()
        self._first: tuple[int, float] | None = None  # (frames done, time) at the first update
        self._last_pct = -1

    def update(self, done: int, error: float | None = None) -> None:
        now = self.clock()
        if self._first is None and done > 0:
            self._first = (done, now)
        f_done, f_time = self._first if self._first is not None else (0, self.t0)
        if done > f_done and now > f_time:
            rate = (done - f_done) / (now - f_time)
        else:
            rate = done / (now - self.t0) if now > self.t0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else 0.0
        width = 30
        fill = int(width * done / self.total)
        line = (f"{self.label} [{'#' * fill}{'-' * (width - fill)}] {done}/{self.total} frames "
                f"{rate:.2f} fps ETA {eta:.0f} s")
        if done >= self.total and self._first is not None:
            line += f" (first frame after {f_time - self.t0:.1f} s)"
        if error is not None:
            line += f" noise estimate {error:.2e}"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done >= self.total else ""))
            self.stream.flush()
        else:
            pct = done * 10 // self.total
            if pct != self._last_pct or done >= self.total:
                self._last_pct = pct
                self.stream.write(line + "\n")
                self.stream.flush()


def write_image(path: str, image) -> None:
    from igi.common.image_io import write_exr, write_png

    ext = Path(path).suffix.lower()
    if ext not in (".exr", ".png"):  # checked before rendering
        raise UsageError(f"output must end in .exr or .png: {path}")
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        (write_exr if ext == ".exr" else write_png)(path, image)
    except OSError as e:
        raise RenderError(f"cannot write {path}: {e.strerror or e}") from None


# ---------------------------------------------------------------------------- subcommands

def cmd_render(args: argparse.Namespace) -> int:
    if args.output and Path(args.output).suffix.lower() not in (".exr", ".png"):
        raise UsageError(f"output must end in .exr or .png: {args.output}")
    for name in ("width", "height", "frames"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise UsageError(f"--{name} must be >= 1")
    if args.workers < 0:
        raise UsageError("--workers must be >= 0")
    if args.threads < 1:
        raise UsageError("--threads must be >= 1")
    params = params_from(args)
    check_sizes(args.width, args.height, args.frames)  # before loading: fail fast
    scene = load_scene_file(args.scene, args.scene_root)
    check_sizes(args.width, args.height, args.frames, scene, params)
    if args.plan:
        from igi.common.camera import resolve_camera
        from igi.worker.renderer import Renderer
        from igi.worker.vpl_importance import View

        r = Renderer(scene)
        print("\n".join(r.plan.lines()))
        cam, fov_x, w, h = resolve_camera(scene, None, args.width, args.height)
        view = View.of(cam, fov_x, w, h)
        if r.importance_on(params, view):
            r.portals(params, view)
            r.emitter_pmf(params, view)
        print(r.importance_notes or "off vpl_importance      no indirect VPLs or turned off")
        print(r.portal_notes or "off vpl_portals         no sky seen through an opening (or VPL importance off)")
        print(r.emitter_notes or "off emitter choice      by power (no more emitters than emitter samples "
                                 "per set, none at all, or VPL importance off)")
        if not args.output:
            return 0
    if not args.output:
        raise UsageError("-o/--output is required (unless --plan alone)")
    progress = Progress(args.frames) if not args.quiet else None
    if progress:
        _say_if_compiling()
    tracker = ErrorTracker()

    def on_frame(i, img):
        err = tracker.error  # of the plain mean (on_plain_mean): the blended one cannot be taken apart
        if progress:
            progress.update(i + 1, err)
        if args.until_error is not None and err is not None and err <= args.until_error:
            raise Converged(img, i + 1, err)

    try:
        image = _render_frames(args, scene, params, on_frame, tracker.add)
    except Converged as c:
        image = c.image
        args.frames = c.frames
    write_image(args.output, image)
    if not args.quiet:
        est = tracker.error
        extra = f", noise estimate (relMSE, even/odd halves) {est:.2e}" if est is not None else ""
        print(f"wrote {args.output} ({image.shape[1]}x{image.shape[0]}, {args.frames} frame(s){extra})",
              file=sys.stderr)
    return 0


def _say_if_compiling() -> None:
    """A first run on a machine compiles the kernels before the first frame (1-2 minutes on 2
    cores): say so instead of looking stuck."""
    from igi.worker.kernels.warm import compiled_before

    if compiled_before() is False:
        print("first run on this machine: compiling igi's kernels (1-2 minutes on 2 cores, cached for later runs)",
              file=sys.stderr)


class Converged(Exception):
    """--until-error reached: carries the accumulated image."""

    def __init__(self, image, frames: int, error: float):
        super().__init__(f"converged after {frames} frames (noise estimate {error:.2e})")
        self.image, self.frames, self.error = image, frames, error


class ErrorTracker:
    """Live error estimate from the plain running means the renderers report (issue 11;
    ``on_plain_mean``: without the filter selection's blend, whose weights change frame by frame).

    Frame i is recovered from consecutive means, (i+1)·m_i − i·m_{i−1}, and fed to an
    Accumulator, whose even/odd halves estimate the relMSE of the mean without a reference."""

    def __init__(self):
        from igi.master.accumulation import Accumulator

        self.acc = Accumulator()
        self.prev = None
        self.error = None

    def add(self, i: int, mean) -> float | None:
        mean = np.asarray(mean, np.float64)
        frame = mean if self.prev is None or i == 0 else (i + 1) * mean - i * self.prev
        self.prev = mean
        self.acc.add(frame)
        self.error = self.acc.relative_error()
        return self.error


def _render_frames(args, scene, params, on_frame, on_plain_mean):
    if args.workers == 0:
        from igi.master.frame_assembly import DEFAULT_TASK_PIXELS
        from igi.master.inprocess import render_local

        image = render_local(scene, params, frames=args.frames, width=args.width, height=args.height,
                             on_frame=on_frame, task_pixels=args.task_pixels or DEFAULT_TASK_PIXELS,
                             on_plain_mean=on_plain_mean)
    else:
        from igi.master.broker import FrameCancelled
        from igi.master.local_workers import local_cluster

        with local_cluster(scene, args.workers, threads=max(1, args.threads),
                           task_pixels=args.task_pixels) as cluster:
            try:
                image = cluster.broker.render_sequence(params, frames=args.frames, width=args.width,
                                                       height=args.height, on_frame=on_frame,
                                                       on_plain_mean=on_plain_mean)
            except FrameCancelled:
                if cluster.all_exited.is_set():
                    raise RenderError("every local worker exited before the render finished") from None
                raise
    return image


def _start_viewer(broker, args):
    http = getattr(args, "http", None)
    if not http:
        return None
    try:
        viewer = importlib.import_module("igi.master.viewer")
    except ImportError:
        log.info("no viewer in this build (master/viewer.py); serving the master only")
        return None
    host, _, port = http.rpartition(":")
    return viewer.start(broker, host or "127.0.0.1", int(port), args)


def _serve(args, scene, local_workers: int) -> int:
    from igi.master.broker import Broker

    check_bind(args.bind)
    params = params_from(args) if scene is not None else None
    stop = threading.Event()

    def on_signal(signum, _frame):
        stop.set()
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    curve = None
    keys = getattr(args, "curve_keys", None)
    if keys:
        from igi.common import protocol as P

        try:
            if local_workers:
                P.generate_keys(keys)  # the local workers' keypair ("worker"); existing keys are kept
            curve = P.CurveServer(keys)
        except (OSError, ValueError) as e:
            raise UsageError(f"CURVE keys in {keys}: {e}") from None
    try:
        broker = Broker(scene, bind=args.bind, configure_socket=curve, task_pixels=args.task_pixels).start()
    except OSError as e:
        raise UsageError(str(e)) from None
    workers = None
    viewer = None
    try:
        print(f"igi master listening on {broker.endpoint}", file=sys.stderr, flush=True)
        if local_workers:
            workers = supervise_workers(broker.endpoint, local_workers, threads=max(1, getattr(args, "threads", 1)),
                                        quiet=not args.verbose, curve_keys=keys)
        if scene is not None:
            broker.start_stream(params, width=getattr(args, "width", None), height=getattr(args, "height", None))
            viewer = _start_viewer(broker, args)
        last = time.monotonic()
        while not stop.wait(0.5):
            if workers is not None:
                for ev in workers.poll():  # logged and restarted by the supervisor
                    if viewer is not None and hasattr(viewer, "note_worker_left"):
                        viewer.note_worker_left(ev.name, f"{ev.reason}; restarting in {ev.restart_in:.1f} s"
                                                if ev.restart_in is not None else ev.reason)
            if time.monotonic() - last >= args.stats_interval > 0:
                last = time.monotonic()
                s = broker.stats()
                lat = s["task_latency_ms"]
                log.info("%d workers, %.2f fps, %d accumulated, %.0f kB/frame, task latency %s ms",
                         s["workers"], s["fps"], s["accumulated"], s["bytes_per_frame"] / 1e3,
                         f"{lat['mean']:.0f}" if lat else "-")
    finally:
        print("igi: stopping", file=sys.stderr, flush=True)
        if viewer is not None:
            try:
                viewer.stop()
            except Exception:
                log.exception("stopping the viewer failed")
        broker.stop()
        if curve is not None:
            curve.stop()
        if workers is not None:
            workers.stop()
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    from igi.common import protocol as P

    try:
        out = P.generate_keys(args.directory, workers=tuple(args.worker or ["worker"]))
    except (OSError, ValueError) as e:
        raise UsageError(str(e)) from None
    print(f"master secret key: {out['master']}")
    for name, path in out["workers"].items():
        print(f"worker {name!r} secret key: {path}")
    print(f"give the master {args.directory} (its secret key + {P.CURVE_WORKERS_DIR}/ of accepted worker keys); "
          f"give each worker its NAME.key_secret and master.key", file=sys.stderr)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    if args.workers < 0:
        raise UsageError("--workers must be >= 0")
    check_sizes(args.width, args.height)
    scene = load_scene_file(args.scene, args.scene_root)
    check_sizes(args.width, args.height, None, scene, params_from(args))
    from igi.common.bundled import resolve

    args.scene_path = str(resolve(args.scene))  # the viewer looks for a reference image beside it
    if args.workers:
        _say_if_compiling()
    return _serve(args, scene, args.workers)


def cmd_scenes(args: argparse.Namespace) -> int:
    from igi.common import bundled

    rows = bundled.scenes()
    width = max((len(n) for n, _, _ in rows), default=0)
    for name, desc, path in rows:
        print(f"{name:<{width}}  {desc}" + (f"  ({path})" if args.paths else ""))
    return 0


def cmd_master(args: argparse.Namespace) -> int:
    scene = load_scene_file(args.scene, args.scene_root) if args.scene else None
    if args.scene:
        from igi.common.bundled import resolve

        args.scene_path = str(resolve(args.scene))
    return _serve(args, scene, 0)


def cmd_worker(args: argparse.Namespace) -> int:
    from igi.worker.node import run_from_args

    return run_from_args(args)


# ---------------------------------------------------------------------------- parser

def cmd_bench(args: argparse.Namespace) -> int:
    """``igi bench NAME ARGS...``: the benchmark's own parser and ``run`` (from the bench registry)."""
    bargs = bench_parser(args.bench).parse_args(args.bench_args)
    bargs.verbose, bargs.command, bargs.bench = args.verbose, args.command, args.bench
    return bargs.func(bargs)


def bench_parser(name: str) -> argparse.ArgumentParser:
    """The parser of ``igi bench NAME``; parsed arguments carry ``func``, the module's ``run``."""
    from igi import bench  # master imports bench only inside cli.py's functions (tests/test_architecture.py)

    mod = bench.load(name)
    p = argparse.ArgumentParser(prog=f"igi bench {name}", description=bench.BENCHES[name].help)
    mod.add_arguments(p)
    p.set_defaults(func=mod.run)
    return p


def bench_names() -> dict[str, str]:
    """``igi bench`` subcommands (name → one-line help) from the bench registry; empty when the
    ``bench`` package is not installed."""
    try:
        from igi import bench
    except ImportError:
        return {}
    return {name: b.help for name, b in bench.BENCHES.items()}


def _add_render_params(p: argparse.ArgumentParser) -> None:
    from igi.common.params import add_arguments

    add_arguments(p)
    p.add_argument("--memory-budget", default=None, metavar="SIZE",
                   help="memory the render may plan for (e.g. 4G; default $IGI_MEMORY_BUDGET or 8G): "
                        "bounds resolution, VPL and photon counts")
    p.add_argument("--scene-root", default=None, metavar="DIR",
                   help="the folder the scene may read from (default: the scene file's folder): every "
                        "mesh, texture, include and MTL library it names must resolve, after symlinks "
                        "and '..', inside DIR")


def _task_pixels(text: str) -> int | None:
    """--task-pixels: a pixel count, or 'auto' (None: sized per frame for the threads connected)."""
    if text.strip().lower() == "auto":
        return None
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a pixel count or 'auto', got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"task pixels must be >= 1, got {n}")
    return n


def _add_task_pixels(p: argparse.ArgumentParser) -> None:
    from igi.master.frame_assembly import DEFAULT_TASK_PIXELS, LARGEST_TASK_PIXELS, SMALLEST_TASK_PIXELS

    p.add_argument("--task-pixels", type=_task_pixels, default=DEFAULT_TASK_PIXELS, metavar="N|auto",
                   help=f"pixels per task (default {DEFAULT_TASK_PIXELS}: a frame's image never depends on "
                        f"the cluster); 'auto': as large as still gives every connected render thread work "
                        f"({SMALLEST_TASK_PIXELS}-{LARGEST_TASK_PIXELS}), for clusters past ~32 threads, "
                        f"where the image then depends on the cluster's size")


def build_parser() -> argparse.ArgumentParser:
    from igi.master.broker import DEFAULT_BIND

    parser = argparse.ArgumentParser(prog="igi", description="Interactive global illumination, distributed "
                                     "(Wald et al. 2002)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser("render", help="render a scene to an EXR (linear) or PNG (sRGB) file")
    r.add_argument("scene", help="Mitsuba XML or OBJ scene file, or a bundled scene's name (igi scenes)")
    r.add_argument("-o", "--output", default=None, help="output image, .exr or .png")
    r.add_argument("--plan", action="store_true", help="print the render plan (passes and why)")
    r.add_argument("--until-error", type=float, default=None, metavar="E",
                   help="stop once the noise estimate (relMSE of the mean from its even/odd frame halves; "
                        "it cannot see bias) is <= E; "
                        "--frames is then the maximum")
    r.add_argument("--frames", type=int, default=1, help="frames to accumulate (default 1)")
    r.add_argument("--width", type=int, default=None, help="image width (default: the scene's)")
    r.add_argument("--height", type=int, default=None, help="image height (default: the scene's)")
    r.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="local worker processes (default: one per core; 0 = render in this process)")
    r.add_argument("--threads", type=int, default=1,
                   help="render threads per local worker process (they share one scene and set cache)")
    r.add_argument("--direct-only", action="store_true", help="direct light only (same as --max-depth 2)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    _add_task_pixels(r)
    _add_render_params(r)
    r.set_defaults(func=cmd_render)

    m = sub.add_parser("master", help="run a master that remote workers connect to")
    m.add_argument("scene", nargs="?", help="scene to stream (optional)")
    m.add_argument("--curve-keys", default=os.environ.get("IGI_KEYS_DIR") or None, metavar="DIR",
                    help="require CURVE-authenticated, encrypted workers (keys from `igi keys DIR`; "
                         "default: $IGI_KEYS_DIR)")
    m.add_argument("--bind", default=DEFAULT_BIND, help=f"ZeroMQ address to bind (default {DEFAULT_BIND}; "
                   "anything but loopback exposes the master to the network)")
    m.add_argument("--http", default=None, help="viewer address HOST:PORT (when the viewer is installed)")
    m.add_argument("--stats-interval", type=float, default=5.0, help="seconds between stats lines (0: none)")
    _add_task_pixels(m)
    _add_render_params(m)
    m.set_defaults(func=cmd_master)

    w = sub.add_parser("worker", help="run a worker that connects to a master")
    from igi.worker.node import add_arguments as worker_args

    worker_args(w)
    w.set_defaults(func=cmd_worker)

    k = sub.add_parser("keys", help="generate CURVE keys for authenticated, encrypted master/worker links")
    k.add_argument("directory", help="folder for the keys (created)")
    k.add_argument("--worker", action="append", help="worker key name (repeatable; default: worker)")
    k.set_defaults(func=cmd_keys)

    s = sub.add_parser("serve", help="master + N local workers (+ the viewer) until Ctrl-C")
    s.add_argument("scene", nargs="?", default=None,
                   help="Mitsuba XML or OBJ scene file, or a bundled scene's name (default: cornell-box)")
    s.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="local worker processes (default: one per core)")
    s.add_argument("--threads", type=int, default=1,
                   help="render threads per local worker process (they share one scene and set cache)")
    s.add_argument("--curve-keys", default=os.environ.get("IGI_KEYS_DIR") or None, metavar="DIR",
                    help="require CURVE-authenticated, encrypted workers (keys from `igi keys DIR`; "
                         "default: $IGI_KEYS_DIR)")
    s.add_argument("--bind", default=DEFAULT_BIND, help=f"ZeroMQ address to bind (default {DEFAULT_BIND})")
    s.add_argument("--http", default="127.0.0.1:8000", help="viewer address HOST:PORT (default 127.0.0.1:8000)")
    s.add_argument("--width", type=int, default=None, help="stream width (default: the scene's)")
    s.add_argument("--height", type=int, default=None, help="stream height (default: the scene's)")
    s.add_argument("--stats-interval", type=float, default=5.0, help="seconds between stats lines (0: none)")
    s.add_argument("--pub", default=None, help="ZeroMQ frame feed (default tcp://127.0.0.1:5556; none: off)")
    _add_task_pixels(s)
    _add_render_params(s)
    s.set_defaults(func=cmd_serve)

    sc = sub.add_parser("scenes", help="list the scenes bundled with igi (usable by name)")
    sc.add_argument("--paths", action="store_true", help="also print each scene file's path")
    sc.set_defaults(func=cmd_scenes)

    from igi.master import record

    rec = sub.add_parser("record", help=record.HELP)
    record.add_arguments(rec)
    rec.set_defaults(func=record.run)

    names = bench_names()
    b = sub.add_parser("bench", help="benchmarks (scaling, quality, ...; igi bench NAME --help)",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="benchmarks:\n" + "\n".join(f"  {n:16s}{h}" for n, h in names.items()))
    b.add_argument("bench", choices=list(names), metavar="BENCH", help="one of: " + ", ".join(names))
    b.add_argument("bench_args", nargs=argparse.REMAINDER, metavar="...", help="the benchmark's arguments")
    b.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    quiet = getattr(args, "quiet", False) or args.command == "render"  # render: the progress bar is the UI
    level = logging.DEBUG if args.verbose else (logging.WARNING if quiet else logging.INFO)
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        apply_memory_budget(args)
        return int(args.func(args) or 0)
    except UsageError as e:
        print(f"igi: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except RenderError as e:
        print(f"igi: error: {_one_line(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("igi: interrupted", file=sys.stderr)
        return 130
    except MemoryError:  # no traceback for any input: one line (the traceback with -v)
        if args.verbose:
            log.exception("out of memory")
        print("igi: error: out of memory (lower the resolution, VPL/photon counts or --memory-budget)",
              file=sys.stderr)
        return 1
    except Exception as e:
        if args.verbose:
            log.exception("igi %s failed", args.command)
        print(f"igi: error: {type(e).__name__}: {_one_line(e)}" + ("" if args.verbose else " (-v for details)"),
              file=sys.stderr)
        return 1


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 400 else text[:397] + "..."


if __name__ == "__main__":
    sys.exit(main())
