"""``igi bench scaling``: frames/s against the number of workers, and where the time goes.

For every image size and every worker count W it starts a master on loopback and W local
worker processes (one render thread each), renders ``--warmup`` frames (scene upload, BVH
builds), then ``--frames`` accumulating frames through the pipelined frame loop
(``Broker.render_sequence``: the same path as ``igi render``/``igi serve``) and records

- frames/s (wall clock over the measured frames, including the master's filter + accumulate),
- bytes per frame on the wire (RESULT payloads) and per pixel,
- task latency (dispatch → result on the master: mean / p50 / p95) and worker render time per
  task,
- parallel efficiency against the W = 1 run.

Separately it measures the master's merge + filter throughput in Mpixel/s: decode every
task's wire bytes, scatter into the frame buffers, discontinuity-filter and compose — what the
master does per frame — on one core, repeated ``--merge-reps`` times.

Writes ``OUT.json`` (machine: cpu model, cores, python, numpy; settings; figures) and
``OUT.png`` (frames/s and efficiency against workers, one line per size).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

HELP = "frames/s against worker count, bytes per frame, master merge+filter Mpixel/s, task latency"

DEFAULT_SCENE = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "cornell-box-sphere" / "scene.xml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from common.params import add_arguments as add_params

    p.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE), help="scene (default: cornell-box-sphere)")
    p.add_argument("--workers", default=None,
                   help="comma-separated worker counts (default: 1 … cores)")
    p.add_argument("--sizes", default="320x240,640x480", help="comma-separated WxH (default 320x240,640x480)")
    p.add_argument("--frames", type=int, default=10, help="measured frames per point (default 10)")
    p.add_argument("--warmup", type=int, default=2, help="frames before measuring (default 2)")
    p.add_argument("--merge-reps", type=int, default=5, help="repetitions of the merge+filter timing")
    p.add_argument("--task-pixels", type=int, default=None, help="pixels per task (default: the broker's)")
    p.add_argument("--latency-inputs", type=int, default=5,
                   help="camera inputs per point for the input-to-frame latency (master.viewer_latency; 0: skip)")
    p.add_argument("-o", "--out", default="artifacts/bench-scaling",
                   help="output prefix: writes PREFIX.json and PREFIX.png (default artifacts/bench-scaling)")
    add_params(p)


def machine_info() -> dict:
    import numpy

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import zmq

        zmq_v = zmq.zmq_version()
    except Exception:  # pragma: no cover
        zmq_v = None
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": numpy.__version__, "zmq": zmq_v, "platform": platform.platform(),
            "load_avg": os.getloadavg() if hasattr(os, "getloadavg") else None}


def _parse_sizes(text: str) -> list[tuple[int, int]]:
    out = []
    for part in text.split(","):
        w, _, h = part.strip().lower().partition("x")
        out.append((int(w), int(h)))
    return out


def merge_filter_rate(result, reps: int) -> dict:
    """Master-side cost of one frame: decode + scatter of every task, filter + compose."""
    from common.codec import encode
    from common.interleave import extract

    from .frame_assembly import FrameAssembler, task_tiles

    spec = result.spec
    n = int(spec.params["interleave"])
    tiles = task_tiles(spec.width, spec.height, n)
    wire = [(t, encode(extract(t, n, result.buffers))) for t in tiles]
    from common.codec import decode

    best_merge = best_filter = float("inf")
    for _ in range(max(1, reps)):
        t0 = time.perf_counter()
        asm = FrameAssembler(spec.width, spec.height, n)
        for t, data in wire:
            asm.add(t, decode(data, None))
        t1 = time.perf_counter()
        asm.image(spec.params)
        t2 = time.perf_counter()
        best_merge, best_filter = min(best_merge, t1 - t0), min(best_filter, t2 - t1)
    px = spec.width * spec.height
    return {"merge_s": best_merge, "filter_s": best_filter,
            "merge_filter_mpixel_s": px / (best_merge + best_filter) / 1e6,
            "merge_mpixel_s": px / best_merge / 1e6, "filter_mpixel_s": px / best_filter / 1e6,
            "bytes": sum(len(d) for _, d in wire)}


def run_point(scene, params, width: int, height: int, workers: int, frames: int, warmup: int,
              task_pixels: int | None, latency_inputs: int = 0) -> tuple[dict, object]:
    from .broker import Broker
    from .cli import LocalWorkers, wait_workers

    kw = {} if task_pixels is None else {"task_pixels": task_pixels}
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    with Broker(scene, bind="tcp://127.0.0.1:*", **kw) as broker:
        procs = LocalWorkers(broker.endpoint, workers)
        try:
            wait_workers(broker, procs, workers)
            if warmup:
                broker.render_sequence(params, frames=warmup, width=width, height=height)
            s0 = broker.stats()
            t0 = time.perf_counter()
            broker.render_sequence(params, frames=frames, width=width, height=height)
            wall = time.perf_counter() - t0
            s1 = broker.stats()
            last = broker.render_frame(broker.frame_spec(0, params, width=width, height=height))
            latency = None
            if latency_inputs > 0:  # camera input -> first frame showing it (the viewer's stream)
                from .viewer_latency import stream_latency

                latency = stream_latency(broker, params, width, height, latency_inputs)
        finally:
            broker.stop()
            procs.stop()
    tasks = s1["tasks_done"] - s0["tasks_done"]
    point = {
        "width": width, "height": height, "workers": workers, "frames": frames, "wall_s": wall,
        "fps": frames / wall, "tasks_per_frame": tasks / frames,
        "bytes_per_frame": s1["bytes_per_frame"], "bytes_per_pixel": s1["bytes_per_frame"] / (width * height),
        "task_latency_ms": s1["task_latency_ms"], "task_render_ms": s1["task_render_ms"],
        "task_encode_ms": s1["task_encode_ms"], "task_merge_ms": s1["task_merge_ms"],
        "task_bytes": s1["task_bytes"],
        "tasks_requeued": s1["tasks_requeued"] - s0["tasks_requeued"],
        "rays_per_s": s1.get("rays_per_s"),
        # where the time goes: worker render seconds per frame, and the fps the workers alone
        # would allow (the rest is transfer, master merge/filter/accumulate and idle slots)
        "render_s_per_frame": (s1["task_render_ms"] or 0) * tasks / frames / 1e3,
        "render_bound_fps": workers / max(1e-9, (s1["task_render_ms"] or 0) * tasks / frames / 1e3),
        "load_avg_before": load_before,
        "input_latency": latency,
    }
    return point, last


def plot(results: dict, path: Path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("igi bench scaling: matplotlib not installed; no plot", file=sys.stderr)
        return False
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    for size, pts in results["points"].items():
        ws = [p["workers"] for p in pts]
        a1.plot(ws, [p["fps"] for p in pts], "o-", label=size)
        if all(p["efficiency"] is not None for p in pts):
            a2.plot(ws, [p["efficiency"] for p in pts], "o-", label=size)
    allw = sorted({p["workers"] for pts in results["points"].values() for p in pts})
    a1.set_xticks(allw)
    a2.set_xticks(allw)
    a1.set_xlabel("workers")
    a1.set_ylabel("frames / s")
    a1.set_title("throughput")
    a1.legend()
    a2.set_xlabel("workers")
    a2.set_ylabel("parallel efficiency")
    a2.set_ylim(0, 1.2)
    a2.set_title("efficiency vs 1 worker")
    a2.legend()
    m = results["machine"]
    fig.suptitle(f"igi bench scaling — {m['cpu']}, {m['cores']} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def run(args: argparse.Namespace) -> int:
    from .cli import UsageError, load_scene_file, params_from

    params = params_from(args)
    scene = load_scene_file(args.scene)
    try:
        sizes = _parse_sizes(args.sizes)
        counts = ([int(x) for x in args.workers.split(",")] if args.workers
                  else list(range(1, (os.cpu_count() or 1) + 1)))
    except ValueError:
        raise UsageError("--sizes is WxH[,WxH…] and --workers N[,N…]") from None
    if not counts or min(counts) < 1 or args.frames < 1:
        raise UsageError("worker counts and --frames must be >= 1")
    from common.params import params_to_dict

    results = {"machine": machine_info(), "scene": str(args.scene),
               "settings": {"params": params_to_dict(params), "frames": args.frames, "warmup": args.warmup,
                            "sizes": [f"{w}x{h}" for w, h in sizes], "workers": counts,
                            "threads_per_worker": 1, "task_pixels": args.task_pixels},
               "points": {}, "merge_filter": {}}
    for w, h in sizes:
        key = f"{w}x{h}"
        pts = []
        last = None
        for c in counts:
            print(f"igi bench scaling: {key}, {c} worker(s) …", file=sys.stderr, flush=True)
            point, last = run_point(scene, params, w, h, c, args.frames, args.warmup, args.task_pixels,
                                    getattr(args, "latency_inputs", 0))
            pts.append(point)
            print(f"  {point['fps']:.2f} fps, {point['bytes_per_frame'] / 1e3:.0f} kB/frame, "
                  f"task latency {point['task_latency_ms']['mean']:.0f} ms"
                  + (f", input→frame {point['input_latency']['mean_ms']:.0f} ms" if point["input_latency"] else ""),
                  file=sys.stderr, flush=True)
        base = next((p for p in pts if p["workers"] == 1), None)
        for p in pts:
            p["efficiency"] = (p["fps"] / (base["fps"] * p["workers"])) if base else None
        results["points"][key] = pts
        mf = merge_filter_rate(last, args.merge_reps)
        results["merge_filter"][key] = mf
        print(f"  master merge+filter {mf['merge_filter_mpixel_s']:.1f} Mpixel/s", file=sys.stderr)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Path(str(out) + ".json").write_text(json.dumps(results, indent=2))
    plot(results, Path(str(out) + ".png"))
    print(f"wrote {out}.json and {out}.png", file=sys.stderr)
    return 0
