"""`igi bench rays`: ray throughput of the whole pipeline against raw embreex on the same rays,
where a frame's worker time goes, and what start-up costs.

Per scene: one frame is rendered through ``Renderer.render_tile`` (the first frame of a fresh
renderer: sets are built here, ``first_frame_seconds``), then ``--frames`` steady frames (the
same seed: the sets are cached, as while the camera moves) with the Geometry recording every
ray batch, then ``--frames`` accumulating frames (new seeds: every set rebuilt,
``set_share_accumulating`` is the sets' share of such a frame); the batches are then replayed
on the bare Embree scene: its full BVHs (``pipeline_over_raw``), embreex's one ray per call for
the shadow rays (``pipeline_over_raw_embreex``), and the BVHs the product's gather takes — the
shadow BVH without the walls for the pairs inside them, common.hull_culling
(``pipeline_over_raw_own_bvh``). The ratio says how much of the pipeline's time is ray tracing
(1.0 would be a renderer that is all Embree; above 1 where the gather's culling beats Embree on
the full scene). Those frames run with the hooks below on, which send every shadow ray through
Python-visible batches; the headline times (``frame_seconds``, the pipeline's rays/s,
``accumulating_frame_seconds``) are of the same kinds of frames rendered again with every hook
off — the product's path, where the VPL gather traces its shadow rays inside its kernel. The
steady frames and the full-BVH and own-BVH replays run in ROUNDS interleaved rounds and each
counts its fastest (a neighbour's load on a shared machine slows a round, not the ratio).

Stage breakdown (``stages``, seconds per frame, first frame and steady frames): the renderer's
profiler hook (``Renderer.stage_times``: eye paths, VPL set, BSDF rays, lensed chains, final
gather points, VPL gather, BSDF direct, photon set, photon gather — the last three over the end
points and the final gather's points together) and the Geometry's Embree timer
(``time_embree``), so each stage is split into Embree time (intersect, occluded) and the rest; ``buffers`` is what
render_tile does outside the stages, ``encode`` the wire encoding (common.codec) of the
tiles. Both hooks cost nothing when off (the product's default).

Start-up (``startup``, a fresh Python process each): importing the worker, then loading every
compiled kernel from numba's on-disk cache (``worker.kernels.warm.warm_up``, minus the same
call once loaded: what the cache costs), and compiling them all with an empty cache (what the
first run on a machine, e.g. CI, pays); the same for the master's kernels (a tiny frame's
assembly, filter and accumulation, minus the same once loaded).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from igi.common.loader import load_scene
from igi.common.params import make_params

from .report import git_commit, machine_info, md_table

ROUNDS = 3  # pipeline / replay rounds, interleaved; each timed by its fastest
STAGES = ("eye paths", "VPL set", "BSDF rays", "lensed chains", "final gather points", "VPL gather", "BSDF direct",
          "photon set", "photon gather")


def add_arguments(p) -> None:
    p.add_argument("scenes", nargs="+", help="scene files, or names of shared scenes (cornell-box, ...)")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--frames", type=int, default=2)
    p.add_argument("--no-startup", action="store_true", help="skip the start-up (compile / cache-load) runs")
    p.add_argument("--compile-one-process", action="store_true",
                   help="also time a cold compile without the helper processes (one process, as before stop 49)")
    p.add_argument("--out", default="artifacts/bench_rays.json")


def run(args) -> int:
    from .paths import shared_scene

    results = {}
    for s in args.scenes:
        path = s if Path(s).exists() or not shared_scene(s).exists() else str(shared_scene(s))
        print(f"rays: {s} ...", file=sys.stderr)
        results[s] = measure(path, args.width, args.height, args.frames, None)
    doc = {"benchmark": "rays", "machine": machine_info(), "commit": git_commit(),
           "settings": {"width": args.width, "height": args.height, "frames": args.frames,
                        "params": next(iter(results.values()))["settings"]["params"]},
           "scenes": results}
    if not args.no_startup:
        print("rays: start-up (fresh processes) ...", file=sys.stderr)
        doc["startup"] = startup(args.compile_one_process)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(doc, indent=2))
    print("\n".join(markdown(doc)))
    return 0


class _StageBook(dict):
    """Renderer.stage_times that also splits each stage's Embree time: the renderer writes a
    stage's seconds when it ends; the Embree seconds since the previous stage ended belong to
    it (render_tile calls Embree only inside stages)."""

    def __init__(self, counters: dict):
        super().__init__()
        self.counters = counters
        self.embree: dict[str, list[float]] = {}
        self._last = self._now()

    def _now(self) -> tuple[float, float]:
        return self.counters.get("intersect_seconds", 0.0), self.counters.get("occluded_seconds", 0.0)

    def __setitem__(self, name, value):
        now = self._now()
        e = self.embree.setdefault(name, [0.0, 0.0])
        e[0] += now[0] - self._last[0]
        e[1] += now[1] - self._last[1]
        self._last = now
        super().__setitem__(name, value)

    def sync(self) -> None:
        self._last = self._now()


def _frame(r, spec, tiles, hooks: bool = True) -> dict:
    """Render one frame's tiles; with the ``hooks`` on, seconds per stage (Embree split out:
    the Geometry's Embree timer must be on too); off: the render and encode seconds only."""
    from igi.common.codec import encode

    book = _StageBook(r.geom.counters)
    r.stage_times = book if hooks else None
    total = enc = 0.0
    for t in tiles:
        book.sync()
        t0 = time.perf_counter()
        buf = r.render_tile(spec, t)
        t1 = time.perf_counter()
        encode(buf)
        enc += time.perf_counter() - t1
        total += t1 - t0
    r.stage_times = None
    if not hooks:
        return {"render_seconds": total, "encode_seconds": enc}
    stages = {}
    for name in STAGES:
        if name in book:
            ei, eo = book.embree.get(name, (0.0, 0.0))
            stages[name] = {"seconds": book[name], "embree_intersect": ei, "embree_occluded": eo,
                            "other": book[name] - ei - eo}
    stages["buffers"] = {"seconds": total - sum(book.values())}
    stages["encode"] = {"seconds": enc}
    ei = sum(v[0] for v in book.embree.values())
    eo = sum(v[1] for v in book.embree.values())
    return {"render_seconds": total, "encode_seconds": enc, "embree_intersect_seconds": ei,
            "embree_occluded_seconds": eo, "stages": stages}


def _scaled(d: dict, f: float) -> dict:
    return {k: (_scaled(v, f) if isinstance(v, dict) else v * f) for k, v in d.items()}


def measure(scene_path: str, width: int | None = None, height: int | None = None, frames: int = 2,
            out: str | None = None, **param_overrides) -> dict:
    from igi.master.accumulation import sequence_spec
    from igi.master.frame_assembly import task_tiles
    from igi.common.camera import resolve_camera
    from igi.common.params import params_to_dict
    from igi.common.gc_policy import settle_long_lived
    from igi.worker.kernels.warm import warm_up
    from igi.worker.renderer import Renderer

    warm_up()  # kernels loaded here, so the first frame measures rendering only
    t0 = time.perf_counter()
    scene = load_scene(scene_path)
    params = make_params(**param_overrides)
    cam, fov_x, w, h = resolve_camera(scene, None, width, height)
    r = Renderer(scene)
    init_s = time.perf_counter() - t0
    # As a worker does once its scene is installed (worker.node): the long-lived objects out of
    # the collector's view, so no ~10 ms full collection lands inside a timed frame.
    settle_long_lived()
    tiles = task_tiles(w, h, params.interleave)
    pd = params_to_dict(params)
    spec = sequence_spec(0, 0, cam, fov_x, w, h, pd)
    r.geom.time_embree(True)
    first = _frame(r, spec, tiles)  # builds the sets: what a user waits for after HELLO
    r.geom.counters.update({"intersect_rays": 0, "occluded_rays": 0, "intersect_seconds": 0.0,
                            "occluded_seconds": 0.0})
    r.geom.record = []
    steady = [_frame(r, spec, tiles) for _ in range(frames)]
    counted = dict(r.geom.counters)  # the steady frames' rays (the accumulating ones add theirs)
    batches, r.geom.record = r.geom.record, None
    # Accumulating frames (camera still): each has its own seed, so every set is rebuilt.
    acc = [_frame(r, sequence_spec(i, i, cam, fov_x, w, h, pd), tiles) for i in range(1, frames + 1)]
    r.geom.time_embree(False)
    acc_frame = _scaled(_sum_frames(acc), 1.0 / max(1, frames))
    set_s = sum(acc_frame["stages"].get(n, {}).get("seconds", 0.0) for n in ("VPL set", "photon set"))
    # The headline times are the product's path: no timers, no recording (the gather then
    # traces its shadow rays from inside its kernel, which neither hook can see into). The same
    # frames as the instrumented ones, so the same rays as those recorded and replayed.
    # Pipeline and replays interleaved, ROUNDS times, each timed by its fastest round: a busy
    # neighbour on the machine slows one round, not the ratio (min, as timeit takes it).
    plain, raws, owns = [], [], []
    for _ in range(ROUNDS):
        plain.append(min(_frame(r, spec, tiles, hooks=False)["render_seconds"] for _ in range(frames)))
        raws.append(r.geom.replay(batches))
        # the same rays on the BVHs the product's gather takes (the walls skipped where it may:
        # common.hull_culling); ``raw`` is Embree on the scene's full BVH
        owns.append(r.geom.replay(batches, own=True))
    pipeline = frames * min(plain)
    raw, raw_own = min(raws), min(owns)
    acc_plain = [_frame(r, sequence_spec(i, i, cam, fov_x, w, h, pd), tiles, hooks=False)
                 for i in range(frames + 1, 2 * frames + 1)]
    acc_seconds = sum(f["render_seconds"] + f["encode_seconds"] for f in acc_plain) / max(1, frames)
    prim = counted["intersect_rays"]
    shadow = counted["occluded_rays"]
    raw_prim = r.geom.replay([b for b in batches if b[0] == "intersect"])
    raw_shadow = r.geom.replay([b for b in batches if b[0] == "occluded"])
    raw_shadow_embreex = _replay_shadow_embreex(r.geom, batches)
    per_frame = _scaled(_sum_frames(steady), 1.0 / max(1, frames))
    result = {
        "benchmark": "rays",
        "machine": machine_info(),
        "scene": str(scene_path),
        "settings": {"width": w, "height": h, "frames": frames, "params": pd},
        "rays": {"primary_and_secondary": prim, "shadow": shadow},
        "pipeline_seconds": pipeline,  # frames × the fastest frame of ROUNDS rounds
        "rounds": ROUNDS,
        "raw_embree_seconds": raw,
        "pipeline_rays_per_s": (prim + shadow) / pipeline,
        "raw_rays_per_s": (prim + shadow) / raw,
        "raw_primary_rays_per_s": prim / max(raw_prim, 1e-9),
        "raw_shadow_rays_per_s": shadow / max(raw_shadow, 1e-9),
        # the shadow BVH answers in Embree packets (common.ray_packets); embreex's one ray per
        # call on the same rays, for reference
        "shadow_engine": type(r.geom.shadow_bvh()).__name__,
        "raw_embreex_shadow_rays_per_s": shadow / max(raw_shadow_embreex, 1e-9),
        "raw_embreex_seconds": raw_prim + raw_shadow_embreex,
        "pipeline_over_raw_embreex": (raw_prim + raw_shadow_embreex) / pipeline,
        "pipeline_over_raw": raw / pipeline,
        "raw_own_bvh_seconds": raw_own,
        "pipeline_over_raw_own_bvh": raw_own / pipeline,
        "frame_seconds": pipeline / frames,
        "renderer_init_seconds": init_s,
        "first_frame_seconds": first["render_seconds"] + first["encode_seconds"],
        "stages": {"first_frame": first, "steady_frame": per_frame, "accumulating_frame": acc_frame},
        # what rebuilding the sets costs while frames accumulate (issue 16: < 10% of a task)
        "accumulating_frame_seconds": acc_seconds,
        "set_share_accumulating": set_s / max(acc_frame["render_seconds"], 1e-12),
        "sets_built": r.stats["sets_built"],
    }
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=2))
    return result


def _replay_shadow_embreex(geom, batches: list) -> float:
    """Seconds embreex's own scene (one ray per Embree call, not robust, as the shadow BVH)
    takes for the recorded occlusion batches."""
    from embreex import rtcore as rtc
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    scene = rtcs.EmbreeScene(rtc.EmbreeDevice(), robust=False)
    mesh = TriangleMesh(scene, geom._local)
    scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED",
              dists=np.zeros(1, np.float32))  # the BVH is built on the first query
    t0 = time.perf_counter()
    for kind, o, d, dist, _interior in batches:
        if kind == "occluded":
            scene.run(o, d, query="OCCLUDED", dists=dist.copy())
    seconds = time.perf_counter() - t0
    del mesh  # (held until the scene is done with its triangles)
    return seconds


def _sum_frames(frames: list[dict]) -> dict:
    def add(a, b):
        return {k: (add(a[k], b[k]) if isinstance(a[k], dict) else a[k] + b[k]) for k in a}

    out = frames[0]
    for f in frames[1:]:
        out = add(out, f)
    return out


_STARTUP_SCRIPT = r"""
import json, os, time
t0 = time.perf_counter()
import igi.worker.renderer, igi.worker.node  # the worker's imports (numba, embreex, the kernel modules)
t1 = time.perf_counter()
from igi.worker.kernels.warm import warm_up
a = warm_up(parallel=os.environ.get("IGI_BENCH_COMPILE_ONE_PROCESS") != "1")
b = warm_up()
import numpy as np
from igi.common.codec import encode
from igi.common.frame import TileBuffers
from igi.master.frame_assembly import FrameAssembler, task_tiles
def master_frame():  # the master's kernels: wire decode, filter + compose, accumulation sums
    from igi.master.accumulation import Accumulator
    t = time.perf_counter()
    asm = FrameAssembler(8, 6, 3)
    for tile in task_tiles(8, 6, 3):
        px = len(tile.pixels(3, 8, 6)[0])
        z = np.zeros((px, 3), np.float32)
        asm.add_wire(tile, encode(TileBuffers(z, z, z, np.ones(px, np.float32), z)))
    Accumulator().add(asm.image({"filter_window": -1, "depth_threshold": 0.05, "normal_threshold": 0.9}))
    return time.perf_counter() - t
m1, m2 = master_frame(), master_frame()
print(json.dumps({"import_seconds": t1 - t0, "warm_up_seconds": a["seconds"],
                  "warm_up_again_seconds": b["seconds"], "kernels": a["kernels"], "cold": a["cold"],
                  "parallel_compile": a["parallel"],
                  "master_first_frame_seconds": m1, "master_second_frame_seconds": m2}))
"""


def _startup_run(env: dict) -> dict:
    from .paths import REPO_ROOT

    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _STARTUP_SCRIPT], cwd=REPO_ROOT, env=env, capture_output=True,
                       text=True, timeout=900)
    if p.returncode != 0:
        return {"error": p.stderr[-2000:]}
    res = json.loads(p.stdout.strip().splitlines()[-1])
    res["process_seconds"] = time.perf_counter() - t0
    # loading (or compiling) the kernels: the first warm_up minus the same work once loaded
    res["kernels_seconds"] = res["warm_up_seconds"] - res["warm_up_again_seconds"]
    res["master_kernels_seconds"] = res["master_first_frame_seconds"] - res["master_second_frame_seconds"]
    return res


def startup(one_process: bool = False) -> dict:
    """Kernel cache-load and cold-compile time, each in a fresh process (the cold compile with
    its helper processes, and with ``one_process`` also without them)."""
    from .paths import REPO_ROOT

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    _startup_run(env)  # make sure numba's on-disk cache is filled
    cached = _startup_run(env)
    with tempfile.TemporaryDirectory(prefix="igi-numba-") as d:
        cold = _startup_run(dict(env, NUMBA_CACHE_DIR=d))
    out = {"cache_load": cached, "cold_compile": cold}
    if one_process:
        with tempfile.TemporaryDirectory(prefix="igi-numba-") as d:
            out["cold_compile_one_process"] = _startup_run(dict(env, NUMBA_CACHE_DIR=d, IGI_BENCH_COMPILE_ONE_PROCESS="1"))
    return out


def markdown(doc: dict) -> list[str]:
    """The docs/benchmarks.md tables of a run: ratios, then the steady frame's stages."""
    lines = []
    rows = []
    for name, r in doc["scenes"].items():
        st = r["settings"]
        rows.append([name, f"{st['width']}×{st['height']}", f"{r['frame_seconds']:.2f}",
                     f"{r['first_frame_seconds']:.2f}", f"{r['pipeline_rays_per_s'] / 1e6:.2f}",
                     f"{r['raw_rays_per_s'] / 1e6:.2f}", f"{r['pipeline_over_raw']:.2f}",
                     f"{r['pipeline_over_raw_embreex']:.2f}" if "pipeline_over_raw_embreex" in r else "–",
                     f"{r['pipeline_over_raw_own_bvh']:.2f}" if "pipeline_over_raw_own_bvh" in r else "–"])
    lines += md_table(["scene", "size", "frame s", "first frame s", "pipeline Mrays/s", "raw Mrays/s",
                       "pipeline/raw", "pipeline/raw embreex", "pipeline/raw own BVHs"], rows)
    lines.append("")
    lines.append("raw: the recorded rays replayed on the scene's full BVHs (shadow rays in Embree "
                 "packets where at hand); raw embreex: the shadow rays one per Embree call, as embreex "
                 "traces them; raw own BVHs: the shadow rays on the BVHs the product's gather takes "
                 "(without the walls where it may: common.hull_culling).")
    lines.append("")
    lines.append("Accumulating (camera still, every set rebuilt): " + "; ".join(
        f"{n} {r['accumulating_frame_seconds']:.2f} s a frame, sets {r['set_share_accumulating']:.1%}"
        for n, r in doc["scenes"].items() if "accumulating_frame_seconds" in r) + ".")
    lines.append("")
    names = list(doc["scenes"])
    stage_names = list(STAGES) + ["buffers", "encode"]
    rows = []
    for s in stage_names:
        row = [s]
        for n in names:
            st = doc["scenes"][n]["stages"]["steady_frame"]["stages"].get(s)
            if st is None:
                row.append("–")
                continue
            e = st.get("embree_intersect", 0.0) + st.get("embree_occluded", 0.0)
            row.append(f"{st['seconds'] * 1e3:.0f}" + (f" ({e * 1e3:.0f} Embree)" if e > 0 else ""))
        rows.append(row)
    rows.append(["total"] + [f"{doc['scenes'][n]['stages']['steady_frame']['render_seconds'] * 1e3 + doc['scenes'][n]['stages']['steady_frame']['encode_seconds'] * 1e3:.0f}"
                             for n in names])
    lines += md_table(["stage, ms per steady frame"] + names, rows)
    su = doc.get("startup")
    if su:
        lines.append("")
        c, k = su["cache_load"], su["cold_compile"]
        if "error" not in c and "error" not in k:
            lines.append(f"Start-up (fresh process): worker imports {c['import_seconds']:.2f} s; its {c['kernels']} "
                         f"kernels from numba's cache {c['kernels_seconds']:.2f} s, compiled from scratch "
                         f"{k['kernels_seconds']:.2f} s; the master's kernels {c['master_kernels_seconds']:.2f} s "
                         f"from the cache, {k['master_kernels_seconds']:.2f} s compiled.")
            helpers = k.get("parallel_compile")
            if helpers:
                lines[-1] += f" The cold compile ran {helpers['processes']} helper processes ({helpers['seconds']:.1f} s)"
                one = su.get("cold_compile_one_process")
                if one and "error" not in one:
                    lines[-1] += f"; in one process it took {one['kernels_seconds']:.2f} s"
                lines[-1] += "."
    return lines
