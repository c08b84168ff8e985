"""`igi bench rays`: ray throughput of the whole pipeline against raw embreex on the same rays.

One frame is rendered through ``Renderer.render_tile`` with the Geometry recording every ray
batch; the batches are then replayed on the bare Embree scene. The ratio says how much of
the pipeline's time is ray tracing (1.0 would be a renderer that is all Embree).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from common.loader import load_scene
from common.params import make_params

from .report import machine_info


def add_arguments(p) -> None:
    p.add_argument("scene", help="scene file")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--frames", type=int, default=2)
    p.add_argument("--out", default="artifacts/bench_rays.json")


def run(args) -> int:
    res = measure(args.scene, args.width, args.height, args.frames, args.out)
    print(json.dumps({k: v for k, v in res.items() if k not in ("machine", "settings")}, indent=2))
    return 0


def measure(scene_path: str, width: int | None = None, height: int | None = None, frames: int = 2,
            out: str | None = None, **param_overrides) -> dict:
    from master.accumulation import sequence_spec
    from master.frame_assembly import task_tiles
    from common.camera import resolve_camera
    from worker.renderer import Renderer

    scene = load_scene(scene_path)
    params = make_params(**param_overrides)
    cam, fov_x, w, h = resolve_camera(scene, None, width, height)
    r = Renderer(scene)
    tiles = task_tiles(w, h, params.interleave)
    from common.params import params_to_dict
    pd = params_to_dict(params)
    # Warm up: builds the sets once so the timed frame measures steady-state rendering.
    spec = sequence_spec(0, 0, cam, fov_x, w, h, pd)
    for t in tiles:
        r.render_tile(spec, t)
    r.geom.counters = {"intersect_rays": 0, "occluded_rays": 0}
    r.geom.record = []
    t0 = time.perf_counter()
    for f in range(frames):
        for t in tiles:
            r.render_tile(spec, t)
    pipeline = time.perf_counter() - t0
    batches = r.geom.record
    r.geom.record = None
    raw = r.geom.replay(batches)
    prim = r.geom.counters["intersect_rays"]
    shadow = r.geom.counters["occluded_rays"]
    raw_prim = r.geom.replay([b for b in batches if b[0] == "intersect"])
    raw_shadow = r.geom.replay([b for b in batches if b[0] == "occluded"])
    result = {
        "benchmark": "rays",
        "machine": machine_info(),
        "scene": str(scene_path),
        "settings": {"width": w, "height": h, "frames": frames, "params": pd},
        "rays": {"primary_and_secondary": prim, "shadow": shadow},
        "pipeline_seconds": pipeline,
        "raw_embree_seconds": raw,
        "pipeline_rays_per_s": (prim + shadow) / pipeline,
        "raw_rays_per_s": (prim + shadow) / raw,
        "raw_primary_rays_per_s": prim / max(raw_prim, 1e-9),
        "raw_shadow_rays_per_s": shadow / max(raw_shadow, 1e-9),
        "pipeline_over_raw": raw / pipeline,
        "frame_seconds": pipeline / frames,
    }
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=2))
    return result
