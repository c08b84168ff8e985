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

``--model`` adds the calibrated scaling model (``bench/scaling_model.py``): it measures the
costs on this machine in the same run (per-task render and set-build time of the scene with
these settings, encode time and bytes per pixel, the master's per-result and per-frame costs),
checks the model against the real runs above (same worker counts, same host: the background
load of other processes is measured during each run and given to the model), and predicts
frames/s and the bottleneck for 1 … 256 workers at 640x480 and 1920x1080 on 1, 10 and
100 Gbit/s. ``--docs docs/scaling.md`` writes the report:

    igi bench scaling --model --frames 4 --latency-inputs 0 --baseline 323c1fd --docs docs/scaling.md
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from .paths import REPO_ROOT, shared_scene
from .report import machine_info, pyplot


DEFAULT_SCENE = shared_scene("cornell-box-sphere")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from igi.common.params import add_arguments as add_params

    p.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE), help="scene (default: cornell-box-sphere)")
    p.add_argument("--workers", default=None,
                   help="comma-separated worker counts (default: 1 … cores)")
    p.add_argument("--sizes", default="320x240,640x480", help="comma-separated WxH (default 320x240,640x480)")
    p.add_argument("--frames", type=int, default=10, help="measured frames per point (default 10)")
    p.add_argument("--warmup", type=int, default=2, help="frames before measuring (default 2)")
    p.add_argument("--merge-reps", type=int, default=15,
                   help="repetitions of the merge+filter timing, best kept (default 15: a shared VM's "
                        "speed moves by 30%% between repetitions)")
    p.add_argument("--task-pixels", type=int, default=None, help="pixels per task (default: the broker's)")
    p.add_argument("--latency-inputs", type=int, default=5,
                   help="camera inputs per point for the input-to-frame latency (master.viewer_latency; 0: skip)")
    p.add_argument("-o", "--out", default="artifacts/bench-scaling",
                   help="output prefix: writes PREFIX.json and PREFIX.png (default artifacts/bench-scaling)")
    m = p.add_argument_group("scaling model")
    m.add_argument("--model", action="store_true", help="calibrate the scaling model and predict 1…256 workers")
    m.add_argument("--model-workers", default="1,2,4,8,16,32,64,128,256", help="worker counts to predict")
    m.add_argument("--model-sizes", default="640x480,1920x1080", help="sizes to predict (WxH,…)")
    m.add_argument("--master-cores", type=int, default=16, help="cores of the modelled master host (default 16)")
    m.add_argument("--master-threads", type=int, default=8,
                   help="threads of the modelled master's parallel stages (default 8)")
    m.add_argument("--calib-sample", type=int, default=2,
                   help="render every N-th task of a frame to calibrate (default 2; 1 = all)")
    m.add_argument("--baseline", default=None, metavar="REV",
                   help="also time the master path of git revision REV (before/after in one run)")
    m.add_argument("--docs", default=None, metavar="PATH", help="write the markdown report (e.g. docs/scaling.md)")
    add_params(p)


def _parse_sizes(text: str) -> list[tuple[int, int]]:
    out = []
    for part in text.split(","):
        w, _, h = part.strip().lower().partition("x")
        out.append((int(w), int(h)))
    return out


def merge_filter_rate(result, reps: int) -> dict:
    """Master-side cost of one frame, the broker's path: every task's wire bytes through
    ``FrameAssembler.add_wire`` (validate, decompress, store), then ``image()`` (float
    conversion, discontinuity filter, compose in parallel stripes). Wall clock with the
    master's threads (``merge_filter_mpixel_s``) and CPU time on one thread."""
    from igi.common.codec import encode
    from igi.common.interleave import extract

    from igi.master.frame_assembly import task_tiles
    from .scaling_model import measure_master

    spec = result.spec
    n = int(spec.params["interleave"])
    tiles = task_tiles(spec.width, spec.height, n)
    wire = [(t, encode(extract(t, n, result.buffers))) for t in tiles]
    m = measure_master(spec.width, spec.height, n, wire, spec.params, 0, reps=reps)
    return {"merge_s": m["wall_merge_ms"] / 1e3, "filter_s": m["wall_finish_ms"] / 1e3,
            "merge_filter_mpixel_s": m["merge_filter_mpixel_s"],
            "merge_mpixel_s": m["pixels"] / m["wall_merge_ms"] / 1e3,
            "filter_mpixel_s": m["pixels"] / m["wall_finish_ms"] / 1e3,
            "bytes": m["bytes"], "threads": m["threads"],
            "cpu_1thread_mpixel_s": m["merge_filter_mpixel_s_1thread"], "detail": m}


def _cpu_jiffies() -> tuple[float, float] | None:
    """(busy, total) jiffies of the whole machine from /proc/stat."""
    try:
        f = [float(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return None
    idle = f[3] + (f[4] if len(f) > 4 else 0.0)
    return sum(f) - idle, sum(f)


def _proc_cpu_s(pid: int, tid: int | None = None) -> float:
    """CPU seconds of a process (or of its thread ``tid``) from /proc."""
    try:
        path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
        parts = Path(path).read_text().rsplit(")", 1)[1].split()
        return (float(parts[11]) + float(parts[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0


def run_point(scene, params, width: int, height: int, workers: int, frames: int, warmup: int,
              task_pixels: int | None, latency_inputs: int = 0) -> tuple[dict, object]:
    from igi.master.local_workers import local_cluster

    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    kw = {} if task_pixels is None else {"task_pixels": task_pixels}
    with local_cluster(scene, workers, **kw) as cluster:
        broker, procs = cluster.broker, cluster.workers
        if warmup:
            broker.render_sequence(params, frames=warmup, width=width, height=height)
        s0 = broker.stats()
        j0, own0 = _cpu_jiffies(), _own_cpu(procs)
        loop0 = _proc_cpu_s(os.getpid(), broker._thread.native_id)
        t0 = time.perf_counter()
        broker.render_sequence(params, frames=frames, width=width, height=height)
        wall = time.perf_counter() - t0
        j1, own1 = _cpu_jiffies(), _own_cpu(procs)
        loop1 = _proc_cpu_s(os.getpid(), broker._thread.native_id)
        s1 = broker.stats()
        last = broker.render_frame(broker.frame_spec(0, params, width=width, height=height))
        latency = None
        if latency_inputs > 0:  # camera input -> first frame showing it (the viewer's stream)
            from .viewer_latency import stream_latency

            latency = stream_latency(broker, params, width, height, latency_inputs)
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
        # CPU seconds per second of the master + workers, and of everything else on the machine
        # (other processes: the background the scaling model is given for this point)
        "own_cores": (sum(own1) - sum(own0)) / wall,
        "master_cpu_s": own1[0] - own0[0], "workers_cpu_s": own1[1] - own0[1],
        # the broker's loop thread (receive + merge + dispatch), per RESULT
        "loop_cpu_ms_per_task": (loop1 - loop0) / max(1, tasks) * 1e3,
        "background_cores": _background(j0, j1, sum(own1) - sum(own0), wall),
    }
    return point, last


def _own_cpu(procs) -> tuple[float, float]:
    """(CPU seconds of this process — the master —, of the local workers)."""
    t = os.times()
    return t.user + t.system, sum(_proc_cpu_s(p.pid) for p in procs.procs)


def _background(j0, j1, own_s: float, wall: float) -> float | None:
    if j0 is None or j1 is None or j1[1] <= j0[1]:
        return None
    cores = os.cpu_count() or 1
    busy_s = (j1[0] - j0[0]) / (j1[1] - j0[1]) * cores * wall  # machine CPU seconds used
    return max(0.0, (busy_s - own_s) / wall)


def plot(results: dict, path: Path) -> bool:
    plt = pyplot("scaling")
    if plt is None:
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
    from igi.master.cli import load_scene_file, params_from
    from igi.master.errors import UsageError

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
    from igi.common.params import params_to_dict

    results = {"machine": machine_info(), "scene": str(args.scene),
               "settings": {"params": params_to_dict(params), "frames": args.frames, "warmup": args.warmup,
                            "sizes": [f"{w}x{h}" for w, h in sizes], "workers": counts,
                            "threads_per_worker": 1, "task_pixels": args.task_pixels},
               "points": {}, "merge_filter": {}}
    lasts = {}
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
        lasts[key] = last
        mf = merge_filter_rate(last, args.merge_reps)
        results["merge_filter"][key] = mf
        print(f"  master merge+filter {mf['merge_filter_mpixel_s']:.1f} Mpixel/s on {mf['threads']} thread(s), "
              f"{mf['cpu_1thread_mpixel_s']:.1f} on one core (CPU time)", file=sys.stderr)
    if getattr(args, "model", False):
        results["model"] = run_model(args, scene, params, results, lasts)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Path(str(out) + ".json").write_text(json.dumps(results, indent=2))
    plot(results, Path(str(out) + ".png"))
    print(f"wrote {out}.json and {out}.png", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ the model
def run_model(args, scene, params, results: dict, lasts: dict) -> dict:
    """Calibrate the scaling model in this run, check it against the real points, predict."""
    from dataclasses import replace

    from igi.common.codec import encode
    from igi.common.interleave import extract
    from igi.common.params import params_to_dict

    from igi.master import parallel
    from . import scaling_model as sm
    from igi.master.frame_assembly import DEFAULT_TASK_PIXELS, task_tiles

    say = lambda s: print(s, file=sys.stderr, flush=True)
    n = int(params.interleave)
    pdict = params_to_dict(params)
    tp = args.task_pixels or DEFAULT_TASK_PIXELS
    cal = sm.calibrate(scene, params, 640, 480, sample=args.calib_sample, task_pixels=tp, log=say)
    base = cal["costs"]
    say(f"  render {cal['detail']['render_ms_per_task']:.1f} ms/task, set build {base.set_build_s * 1e3:.1f} ms, "
        f"{base.bytes_per_px:.2f} B/px")

    def with_master(w: int, h: int, wire: list, bytes_px: float | None = None):
        m = sm.measure_master(w, h, n, wire, pdict, tp, reps=3)
        c = replace(base, master_recv_s_per_px=m["recv_s_per_px"], finish_s_per_px=m["finish_s_per_px"],
                    accumulate_s_per_px=m["accumulate_s_per_px"],
                    bytes_per_px=bytes_px if bytes_px is not None else m["bytes"] / (w * h))
        return c, m

    def real_wire(res):
        spec = res.spec
        return [(t, encode(extract(t, n, res.buffers))) for t in task_tiles(spec.width, spec.height, n, tp)]

    costs, masters = {}, {}
    for key, res in lasts.items():
        w, h = (int(v) for v in key.split("x"))
        costs[key], masters[key] = with_master(w, h, real_wire(res))
    src_key = "640x480" if "640x480" in lasts else max(lasts, key=lambda k: int(k.split("x")[0]))
    for w, h in _parse_sizes(args.model_sizes):
        key = f"{w}x{h}"
        if key not in costs:  # a size not rendered here: the master timed on a resampled frame
            wire = sm.synthetic_wire(lasts[src_key].buffers, w, h, n, tp)
            costs[key], masters[key] = with_master(w, h, wire, bytes_px=costs[src_key].bytes_per_px)

    # the model against the real runs: same host (cores shared with the measured background)
    cores = os.cpu_count() or 1
    validation = []
    for key, pts in results["points"].items():
        w, h = (int(v) for v in key.split("x"))
        for p in pts:
            bg = p.get("background_cores") or 0.0
            # The other processes on this machine took `bg` cores during the run: our master and
            # workers shared what was left (processor sharing among themselves).
            cfg = sm.Config(workers=p["workers"], width=w, height=h, interleave=n, task_pixels=tp,
                            frames=results["settings"]["frames"], warmup=0, network=sm.LOOPBACK,
                            shared_host_cores=max(0.05, cores - bg), master_cores=cores,
                            master_threads=parallel.threads(),
                            # the timed frames reuse the warm-up frames' seeds, whose sets the
                            # workers still hold
                            prewarm_frames=min(results["settings"]["warmup"], results["settings"]["frames"]))
            standalone = sm.simulate(costs[key], cfg)
            # CPU work inflates under the machine's other load (shared caches, hyperthreads):
            # scale the calibrated costs to the CPU seconds the workers and the master actually
            # used in this run (/proc), so the model checks the loop's dynamics, not the load
            inrun = costs[key]
            frames = results["settings"]["frames"]
            if p.get("workers_cpu_s") and p.get("master_cpu_s"):
                wk_model = standalone.worker_cpu_s_per_frame * frames
                ms_model = standalone.master_cpu_s_per_frame * frames
                sw, smas = p["workers_cpu_s"] / wk_model, p["master_cpu_s"] / ms_model
                inrun = replace(inrun, render_s_per_px=inrun.render_s_per_px * sw,
                                set_build_s=inrun.set_build_s * sw, encode_s_per_px=inrun.encode_s_per_px * sw,
                                master_msg_s=inrun.master_msg_s * smas,
                                master_recv_s_per_px=inrun.master_recv_s_per_px * smas,
                                finish_s_per_px=inrun.finish_s_per_px * smas,
                                accumulate_s_per_px=inrun.accumulate_s_per_px * smas)
            else:
                sw = smas = None
            r = sm.simulate(inrun, cfg)
            validation.append({"size": key, "workers": p["workers"], "measured_fps": p["fps"],
                               "model_fps": r.fps, "error": r.fps / p["fps"] - 1.0,
                               "standalone_fps": standalone.fps, "standalone_error": standalone.fps / p["fps"] - 1.0,
                               "worker_cpu_scale": sw, "master_cpu_scale": smas,
                               "background_cores": p.get("background_cores"), "bottleneck": r.bottleneck,
                               "measured_bytes_per_frame": p["bytes_per_frame"],
                               "model_bytes_per_frame": r.bytes_per_frame,
                               "loop_ms_measured": p.get("loop_cpu_ms_per_task"),
                               "loop_ms_model": (costs[key].master_msg_s + costs[key].master_recv_s_per_px
                                                 * w * h / max(1, r.tasks_per_frame)) * 1e3})
            say(f"  model {key} {p['workers']} worker(s): {r.fps:.3f} fps vs measured {p['fps']:.3f} "
                f"({(r.fps / p['fps'] - 1) * 100:+.0f}%; standalone calibration {standalone.fps:.3f})")

    workers = [int(x) for x in args.model_workers.split(",")]
    # as the measured broker: its default size unless --task-pixels says otherwise
    kw = dict(master_cores=args.master_cores, master_threads=args.master_threads, interleave=n,
              task_pixels=tp)
    predictions, capacities = {}, {}
    for w, h in _parse_sizes(args.model_sizes):
        key = f"{w}x{h}"
        rows = sm.predict(costs[key], w, h, workers=workers, **kw)
        # a moving camera keeps the seed: a worker lists only the frame's n² sets in its RESULTs
        c_moving = replace(costs[key], master_msg_s=cal["detail"]["master"]["msg_s_current_sets"])
        moving = sm.predict(c_moving, w, h, workers=workers, networks=(sm.NETWORKS[1],), accumulate=False, **kw)
        spread = sm.predict(costs[key], w, h, workers=workers, networks=(sm.NETWORKS[1],),
                            affinity_lookahead=len(task_tiles(w, h, n, tp)), **kw)
        predictions[key] = ([r.as_dict() for r in rows] + [dict(r.as_dict(), moving=True) for r in moving]
                            + [dict(r.as_dict(), spread=True) for r in spread])
        cap = sm.master_capacity(costs[key], sm.Config(workers=1, width=w, height=h, **kw))
        cap_m = sm.master_capacity(c_moving, sm.Config(workers=1, width=w, height=h, **kw))
        cap_px = sm.master_capacity(replace(costs[key], master_msg_s=0.0), sm.Config(workers=1, width=w, height=h, **kw))
        capacities[key] = {"accumulating": cap, "camera_moving": cap_m, "pixel_path": cap_px}
        say(f"  {key}: master capacity {cap:.1f} Mpixel/s accumulating, {cap_m:.1f} camera moving, "
            f"pixel path alone {cap_px:.1f} (pipelined, {args.master_threads} threads)")

    baseline = None
    if args.baseline:
        try:
            baseline = _baseline(args.baseline, costs, lasts, src_key, n, pdict, tp, workers, kw, _parse_sizes(args.model_sizes))
        except Exception as e:  # documentation aid only: never fail the benchmark for it
            say(f"  baseline {args.baseline} skipped: {type(e).__name__}: {e}")
    model = {"calibration": cal["detail"], "costs": {k: _costs_dict(c) for k, c in costs.items()},
             "master": masters, "validation": validation, "predictions": predictions,
             "master_capacity_mpixel_s": {k: v["accumulating"] for k, v in capacities.items()},
             "master_capacities": capacities,
             "master_cores": args.master_cores, "master_threads": args.master_threads,
             "master_threads_here": parallel.threads(),
             "networks": [{"name": x.name, "gbit_s": x.bandwidth_bps / 1e9, "latency_us": x.latency_s * 1e6}
                          for x in sm.NETWORKS],
             "baseline": baseline}
    if args.docs:
        Path(args.docs).parent.mkdir(parents=True, exist_ok=True)
        Path(args.docs).write_text(report(results, model, args))
        say(f"wrote {args.docs}")
    return model


def _costs_dict(c) -> dict:
    from dataclasses import asdict

    d = asdict(c)
    d.pop("tile_weights")
    return d


def _baseline(rev, costs, lasts, src_key, n, pdict, tp, workers, kw, sizes) -> dict:
    """The master path of git revision ``rev`` (per-tile decode + scatter, serial filter),
    timed in this process on the same frames, and the model's predictions with it."""
    import importlib
    import subprocess
    import types
    from dataclasses import replace

    from igi.common.interleave import extract

    from . import scaling_model as sm
    from igi.master.frame_assembly import task_tiles

    root = REPO_ROOT

    def load(path: str, name: str):
        text = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=root, capture_output=True, text=True,
                              check=True).stdout
        mod = types.ModuleType(name)
        mod.__file__ = str(root / path)
        exec(compile(text, f"{rev}:{path}", "exec"), mod.__dict__)
        return mod

    out = {"rev": rev, "sizes": {}}
    # the old revision's files import the top-level names the packages had before `igi.*`
    names = ("common", "master", "worker", "common.codec", "master.discontinuity_buffer")
    saved = {k: sys.modules.get(k) for k in names}
    try:
        for top in ("common", "master", "worker"):
            sys.modules[top] = importlib.import_module(f"igi.{top}")
        old_codec = load("common/codec.py", "common.codec")
        old_db = load("master/discontinuity_buffer.py", "master.discontinuity_buffer")
        sys.modules["common.codec"], sys.modules["master.discontinuity_buffer"] = old_codec, old_db
        old_fa = load("master/frame_assembly.py", "master.frame_assembly")
        for w, h in sizes:
            key = f"{w}x{h}"
            if key in lasts:
                res = lasts[key]
                # the revision's own codec: its wire format may be older than this one's
                wire = [(t, old_codec.encode(extract(t, n, res.buffers))) for t in task_tiles(w, h, n, tp)]
            else:
                wire = sm.synthetic_wire(lasts[src_key].buffers, w, h, n, tp, encode=old_codec.encode)
            recv = fin = float("inf")
            for _ in range(3):
                asm = old_fa.FrameAssembler(w, h, n)
                c0 = time.process_time()
                for t, d in wire:
                    asm.add(t, old_codec.decode(d, None))
                c1 = time.process_time()
                asm.image(pdict)
                c2 = time.process_time()
                recv, fin = min(recv, c1 - c0), min(fin, c2 - c1)
            px = w * h
            c = replace(costs[key], master_recv_s_per_px=recv / px, finish_s_per_px=fin / px,
                        finish_serial_share=1.0)
            rows = sm.predict(c, w, h, workers=workers, **kw)
            out["sizes"][key] = {"merge_cpu_ms": recv * 1e3, "finish_cpu_ms": fin * 1e3,
                                 "merge_filter_mpixel_s_1thread": px / (recv + fin) / 1e6,
                                 "master_capacity_mpixel_s": sm.master_capacity(c, sm.Config(workers=1, width=w, height=h, **kw)),
                                 "predictions": [r.as_dict() for r in rows]}
    finally:
        for k, m in saved.items():
            if m is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = m
    return out


def report(results: dict, model: dict, args) -> str:
    """docs/scaling.md: calibration, model vs measured, master throughput, predictions."""
    from igi.master.frame_assembly import DEFAULT_TASK_PIXELS

    m = results["machine"]
    st = results["settings"]
    cal = model["calibration"]
    L = []
    a = L.append
    a("# Scaling past one machine: the calibrated model")
    a("")
    a("Generated by `igi bench scaling --model` (`bench/scaling.py`, `bench/scaling_model.py`); "
      "regenerate after any change to the renderer, the codec or the master with")
    a("")
    a("    igi bench scaling --model --frames 4 --latency-inputs 0 --baseline 323c1fd --docs docs/scaling.md")
    a("")
    a(f"Machine: {m['cpu']}, {m['cores']} cores (shared with other jobs: the load of other processes is "
      f"measured during every real run and given to the model), Python {m['python']}, numpy {m['numpy']}. "
      f"Scene `{Path(results['scene']).parent.name}`, interleave {st['params']['interleave']}, "
      f"{st['params'].get('direct_vpls')}+{st['params'].get('indirect_vpls')} VPLs, "
      f"{st['params'].get('photons')} photons per set, tasks of ~{st['task_pixels'] or DEFAULT_TASK_PIXELS} pixels.")
    a("")
    a("## Calibration (measured in the same run, CPU time of one core)")
    a("")
    a("| cost | value |")
    a("|---|---|")
    a(f"| worker render, per task of {cal['width']}x{cal['height']} ({cal['tasks']} tasks/frame, set cached) | "
      f"{cal['render_ms_per_task']:.1f} ms |")
    a(f"| VPL/photon set build, per (worker, frame, k), accumulating: {cal.get('set_build_note', '')} | "
      f"{cal['set_build_ms']:.1f} ms |")
    if "set_build_alone_ms" in cal:
        a(f"| the same, one set built alone (a frame's first task of its k) | {cal['set_build_alone_ms']:.1f} ms |")
    a(f"| encode, per task | {cal['encode_ms_per_task']:.2f} ms |")
    a(f"| wire bytes per pixel | {cal['bytes_per_px']:.2f} B |")
    for key, mm in model["master"].items():
        c = model["costs"][key]
        a(f"| master {key}: per RESULT (zmq, protocol, bookkeeping, dispatch) | {c['master_msg_s'] * 1e6:.0f} µs |")
        a(f"| master {key}: receive (validate, lz4, store) per frame | {c['master_recv_s_per_px'] * mm['pixels'] * 1e3:.1f} ms |")
        a(f"| master {key}: finish (convert, filter, compose) per frame, 1 thread | {mm['finish_cpu_ms']:.1f} ms |")
    a("")
    a("The per-task render time is an input: the renderer is being sped up in parallel, and the "
      "command above re-measures it. Everything else scales from these numbers.")
    a("")
    a("## Model vs measured (real runs on this machine, loopback)")
    a("")
    a("The other processes on this shared machine take CPU during the runs (measured from /proc: the "
      "background column); the model gives master and workers the cores left. CPU work also runs slower "
      "under that load than in the calibration, so the model is run twice: with the calibration's costs "
      "scaled to the CPU seconds workers and master actually used in the run (in-run: checks the frame "
      "loop's dynamics — pipeline, queueing, overlap) and with the standalone calibration as it is. While "
      "the machine is saturated the in-run check is close to exact by construction (frames/s = the cores "
      "left / the CPU work per frame); the standalone column is the real test of the prediction, and its "
      "error here is the CPU inflation (also shown) that a dedicated machine would not have.")
    a("")
    a("| size | workers | measured fps | model fps (in-run CPU) | error | model fps (standalone) | error | "
      "CPU inflation workers / master | background (cores) | bytes/frame measured | model | "
      "master loop CPU per RESULT measured | model |")
    a("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    errs, errs2 = [], []
    for v in model["validation"]:
        errs.append(abs(v["error"]))
        errs2.append(abs(v["standalone_error"]))
        bg = v["background_cores"]
        infl = (f"{v['worker_cpu_scale']:.2f} / {v['master_cpu_scale']:.2f}"
                if v.get("worker_cpu_scale") else "?")
        a(f"| {v['size']} | {v['workers']} | {v['measured_fps']:.3f} | {v['model_fps']:.3f} | "
          f"{v['error'] * 100:+.0f}% | {v['standalone_fps']:.3f} | {v['standalone_error'] * 100:+.0f}% | {infl} | "
          f"{'?' if bg is None else f'{bg:.2f}'} | "
          f"{v['measured_bytes_per_frame'] / 1e3:.0f} kB | {v['model_bytes_per_frame'] / 1e3:.0f} kB | "
          f"{v.get('loop_ms_measured') or 0:.2f} ms | {v.get('loop_ms_model') or 0:.2f} ms |")
    if errs:
        a("")
        a(f"Model error on the real runs: in-run CPU costs mean {sum(errs) / len(errs) * 100:.0f}%, "
          f"max {max(errs) * 100:.0f}% (target: within 20%); standalone calibration mean "
          f"{sum(errs2) / len(errs2) * 100:.0f}%, max {max(errs2) * 100:.0f}%.")
    a("")
    a("## Master throughput")
    a("")
    c0 = next(iter(model["costs"].values()))
    a(f"Per RESULT, before and now alike: zmq receive, protocol decode + validation (with the "
      f"{STEADY_SETS_NOTE} sets a worker lists once it has cached them), bookkeeping and the next TASK: "
      f"{c0['master_msg_s'] * 1e6:.0f} µs on the loop thread (calibrated), "
      + ", ".join(f"{v['loop_ms_measured']:.2f} ms measured in the {v['size']}/{v['workers']}-worker run (loop thread, "
                  "incl. merge)" for v in model["validation"] if v.get("loop_ms_measured")) + ".")
    a("")
    a("| size | path | merge CPU ms/frame (decode/store) | finish CPU ms/frame | merge+finish, 1 thread (CPU) | "
      f"pipelined capacity, {model['master_threads']} threads (model) |")
    a("|---|---|---|---|---|---|")
    base = model.get("baseline") or {"sizes": {}}
    for key, mm in model["master"].items():
        b = base["sizes"].get(key)
        if b:
            a(f"| {key} | before ({base['rev']}) | {b['merge_cpu_ms']:.1f} | {b['finish_cpu_ms']:.1f} | "
              f"{b['merge_filter_mpixel_s_1thread']:.1f} Mpixel/s | {b['master_capacity_mpixel_s']:.1f} Mpixel/s (serial) |")
        cap = model["master_capacity_mpixel_s"].get(key)
        a(f"| {key} | now | {mm['merge_cpu_ms']:.1f} | {mm['finish_cpu_ms']:.1f} | "
          f"{mm['merge_filter_mpixel_s_1thread']:.1f} Mpixel/s | {'–' if cap is None else f'{cap:.1f} Mpixel/s'} |")
    a("")
    for key, cv in model.get("master_capacities", {}).items():
        a(f"Predicted master capacity at {key} ({model['master_threads']} threads, pipelined): pixel path alone "
          f"(merge + filter, what the paper's 1.5 Mpixel/s measured) {cv['pixel_path']:.1f} Mpixel/s; with the "
          f"per-RESULT protocol cost {cv['camera_moving']:.1f} Mpixel/s when workers list only the frame's sets "
          f"(camera moving), {cv['accumulating']:.1f} Mpixel/s with {STEADY_SETS_NOTE} cached sets listed "
          "(accumulating for a while).")
        a("")
    mf = results.get("merge_filter", {})
    if mf:
        a("Measured wall clock here (merge then finish of one frame, "
          f"{model['master_threads_here']} threads on this {results['machine']['cores']}-core machine): " + ", ".join(
              f"{k}: {v['merge_filter_mpixel_s']:.1f} Mpixel/s" for k, v in mf.items()) + ".")
        a("")
    for key, preds in model["predictions"].items():
        a(f"## Predicted frames/s at {key} (master: {model['master_cores']} cores, "
          f"{model['master_threads']} finishing threads)")
        a("")
        nets = [x["name"] for x in model["networks"]]
        a("Accumulating (a new seed, so new VPL/photon sets, every frame — the benchmark's case), per "
          "network; last columns: the camera moving on 10 Gbit/s (seed and sets kept: docs/design-notes.md). "
          "Cells: frames/s (bottleneck).")
        a("")
        a("| workers | " + " | ".join(nets) + " | bytes/frame | set builds/frame | camera moving, 10 Gbit/s "
          "| what-if: issue 12's lookahead policy, 10 Gbit/s (set builds) |")
        a("|---|" + "---|" * len(nets) + "---|---|---|---|")
        by, mv, sp = {}, {}, {}
        for r in preds:
            if r.get("moving"):
                mv[r["config"]["workers"]] = r
            elif r.get("spread"):
                sp[r["config"]["workers"]] = r
            else:
                by.setdefault(r["config"]["workers"], {})[r["config"]["network"]] = r
        for wk, row in sorted(by.items()):
            cells = [f"{row[nm]['fps']:.1f} ({row[nm]['bottleneck']})" for nm in nets]
            any_r = row.get("10 Gbit/s") or next(iter(row.values()))
            m_r = mv.get(wk)
            a(f"| {wk} | " + " | ".join(cells) + f" | {any_r['bytes_per_frame'] / 1e6:.2f} MB | "
              f"{any_r['set_builds_per_frame']:.0f} | "
              + (f"{m_r['fps']:.1f} ({m_r['bottleneck']})" if m_r else "") + " | "
              + (f"{sp[wk]['fps']:.1f} ({sp[wk]['set_builds_per_frame']:.0f})" if wk in sp else "") + " |")
        one = by.get(1, {}).get("10 Gbit/s")
        sixty4 = by.get(64, {}).get("10 Gbit/s")
        if one and sixty4:
            a("")
            line = (f"Parallel efficiency at 64 workers on 10 Gbit/s: "
                    f"{sixty4['fps'] / (64 * one['fps']) * 100:.0f}% of linear when accumulating")
            if 1 in mv and 64 in mv:
                line += f", {mv[64]['fps'] / (64 * mv[1]['fps']) * 100:.0f}% with the camera moving"
            a(line + ".")
        sixteen = by.get(16, {}).get("10 Gbit/s")
        if one and sixteen:  # issue 19's target: >= 90% at 16 workers accumulating, <= 20 set builds
            a("")
            a(f"At 16 workers on 10 Gbit/s: {sixteen['fps'] / (16 * one['fps']) * 100:.0f}% of linear when "
              f"accumulating, {sixteen['set_builds_per_frame']:.1f} set builds per frame.")
        b = base["sizes"].get(key)
        if b:
            a("")
            a(f"With the master of {base['rev']} (before), 10 Gbit/s: " + ", ".join(
                f"{r['config']['workers']}: {r['fps']:.1f} ({r['bottleneck']})"
                for r in b["predictions"] if r["config"]["network"] == "10 Gbit/s") + ".")
        a("")
    a(_findings(model))
    a(MODEL_NOTES)
    return "\n".join(L) + "\n"


def _findings(model: dict) -> str:
    """What the numbers say, computed from them (so the text regenerates with the tables)."""
    out = ["## Findings", ""]
    preds = model["predictions"].get("640x480", [])
    acc = {r["config"]["workers"]: r for r in preds
           if not r.get("moving") and not r.get("spread") and r["config"]["network"] == "10 Gbit/s"}
    mv = {r["config"]["workers"]: r for r in preds if r.get("moving")}
    sp = {r["config"]["workers"]: r for r in preds if r.get("spread")}
    caps = model.get("master_capacities", {}).get("640x480")
    cap = caps["pixel_path"] if caps else None
    base = (model.get("baseline") or {}).get("sizes", {}).get("640x480")
    if cap is not None:
        line = (f"- Master pixel path (merge + filter): {cap:.1f} Mpixel/s predicted at 640x480 with "
                f"{model['master_threads']} threads (pipelined: the loop thread receives frame i+1 while frame i "
                f"is finished); {caps['camera_moving']:.1f} / {caps['accumulating']:.1f} Mpixel/s with the per-RESULT "
                "protocol cost (camera moving / accumulating)")
        if base:
            line += (f", from {base['master_capacity_mpixel_s']:.1f} Mpixel/s with the master of {model['baseline']['rev']} "
                     f"(1 thread CPU: {base['merge_filter_mpixel_s_1thread']:.1f} → "
                     f"{model['master']['640x480']['merge_filter_mpixel_s_1thread']:.1f} Mpixel/s)")
        out.append(line + ". The paper's server did 1.5 Mpixel/s.")
    if 64 in acc and 1 in acc:
        r = acc[64]
        out.append(f"- 64 workers at 640x480 on 10 Gbit/s: {r['fps']:.1f} fps ({r['bottleneck']}), "
                   f"{r['fps'] / (64 * acc[1]['fps']) * 100:.0f}% of linear when accumulating; "
                   + (f"{mv[64]['fps']:.1f} fps, {mv[64]['fps'] / (64 * mv[1]['fps']) * 100:.0f}% of linear "
                      f"({mv[64]['bottleneck']}) with the camera moving. " if 64 in mv and 1 in mv else "")
                   + f"The master is not the bottleneck there (loop thread {r['utilization']['master loop'] * 100:.0f}% "
                   f"busy, finishing {r['utilization']['master finish'] * 100:.0f}%).")
    if 16 in acc and 16 in sp:
        out.append(f"- When accumulating, every frame has new VPL/photon sets. The broker's set-aware policy "
                   f"(issue 19) gives each set of a frame one owner: {acc[16]['set_builds_per_frame']:.1f} set builds "
                   f"per frame at 16 workers (105 with the strict queue order before it; issue 12's lookahead "
                   f"what-if column: {sp[16]['set_builds_per_frame']:.0f}); "
                   f"past ~32 workers there are more workers than sets in flight and sets are shared, so cheaper "
                   f"sets (or keeping sets across frames) are what scales.")
    if 256 in mv:
        out.append(f"- Past 64–128 workers at 640x480 a frame has too few tasks "
                   f"({mv[256]['tasks_per_frame']} of ≥ 4096 pixels) and the loop keeps 3 frames in flight: "
                   f"{mv[256]['fps']:.1f} fps at 256 workers ({mv[256]['bottleneck']}). Smaller tasks or a deeper "
                   f"pipeline move that limit; the master's per-RESULT cost then matters more.")
    out.append("- Workers list their cached sets in a RESULT only when the list changed (issue 19), so the "
               "loop thread no longer validates ~64 entries per RESULT; `python -m igi.bench.result_cost` measures "
               "the loop thread's cost per RESULT with and without the list.")
    out.append("")
    return "\n".join(out)


STEADY_SETS_NOTE = "64"

MODEL_NOTES = """## What the model is

`bench/scaling_model.py` simulates the frame loop of `Broker.render_sequence` event by event:
`pipeline` (3) frames in flight; a frame's tasks dispatched by the broker's own scheduling
policy (`master.scheduler.assign`: credit 3 per render thread; set-aware — a free worker takes
a task of a VPL/photon set it holds or builds, else of the set fewest workers hold, and takes a
set another worker holds only when it is idle; then least loaded); TASK latency; the worker's render
thread (plus a set build when it does not hold set (seed, k)); encode; the RESULT through the
worker's link and the master's link (bandwidth, FIFO) and the latency; the master's loop
thread (one FIFO server: zmq receive, protocol decode, validation + lz4 + storing the tile,
bookkeeping, next dispatch); the finishing thread (image: a serial share plus a share spread
over the master's threads; accumulation), frames in order. CPUs are processor-sharing hosts:
remote workers each have their own; the validation runs put master, workers and the measured
background load on the one host they ran on. Bottleneck: the resource with the highest utilization
in the measured window when it is >= 85% busy; otherwise "task supply" (fewer tasks in
flight than worker threads) or "frame latency" (the pipeline depth bounds the rate).

The "lookahead" column is issue 12's what-if, not the broker: `Config.affinity_lookahead`
lets a free worker take the first queued task whose set it holds, else a task of the set
fewest workers hold, with no restraint on sharing sets. Before issue 19 the broker took tasks
strictly in queue order (105 set builds per frame at 16 workers).

Assumptions: each worker is one render thread on its own host with its own link; the master
has one link of the same bandwidth; the finishing stage's serial share is 10% (numpy releases
the GIL in its loops; the Python between them does not); 1080p render costs are the measured
640x480 per-pixel costs (by image position), its wire bytes per pixel the 640x480 ones, its
master costs measured on a resampled 640x480 frame.
"""
