"""`igi bench plan`: wall time with the render plan against every pass forced on, at equal error.

Per scene, the same frames (same seeds, tiles and filter) are rendered in-process twice: with
the plan (passes a scene does not need are skipped) and with ``Renderer(use_plan=False)``
(caustic photons attempted, every VPL through the full BSDF, uv interpolation on hits). Both
images are compared with the reference; the relMSE difference must stay ≤ 1e-4. A third
measurement renders a frame after a camera-only move: it must build no VPL or photon set.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from igi.common.image_io import read_image
from igi.common.loader import load_scene
from igi.common.metrics import block_average, relmse

from .paths import SHARED
from .report import machine_info


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenes", nargs="*", default=None, help="shared scene names (default: all)")
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--scale", type=float, default=0.25, help="fraction of the film size (1/integer)")
    p.add_argument("--out", default="artifacts/bench_plan.json")

def measure(names: list[str], frames: int, scale: float) -> dict:
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer

    block = int(round(1 / scale))
    rows = []
    for name in names:
        scene = load_scene(SHARED / "scenes" / name / "scene.xml")
        ref = block_average(read_image(SHARED / "references" / f"{name}.exr"), block)
        h, w = ref.shape[:2]
        row = {"scene": name, "size": [w, h], "frames": frames}
        for label, use_plan in (("plan", True), ("forced", False)):
            r = Renderer(scene, use_plan=use_plan)
            # Warm-up (BSDF tables, texture means, set caches of seed 99) so neither variant
            # pays one-time costs inside the timing.
            render_local(scene, {"seed": 99}, 1, width=w, height=h, renderer=r)
            t0 = time.perf_counter()
            img = render_local(scene, {}, frames, width=w, height=h, renderer=r)
            row[f"{label}_seconds"] = time.perf_counter() - t0
            row[f"{label}_relmse"] = relmse(img, ref)
            if use_plan:
                row["plan"] = r.plan.to_dict()
                # Camera-only motion: same seed, cached sets, no preprocessing.
                built = r.stats["sets_built"]
                cam = scene.camera.to_world.copy()
                cam[:3, 3] += 0.01 * r.geom.diagonal
                t1 = time.perf_counter()
                render_local(scene, {"accumulate": False}, 1, camera=cam, width=w, height=h, renderer=r)
                row["camera_move_seconds"] = time.perf_counter() - t1
                row["camera_move_sets_built"] = r.stats["sets_built"] - built
        row["speedup"] = row["forced_seconds"] / row["plan_seconds"]
        row["relmse_difference"] = abs(row["plan_relmse"] - row["forced_relmse"])
        rows.append(row)
    return {"benchmark": "plan", "machine": machine_info(), "scale": scale, "rows": rows}

def run(args) -> int:
    names = args.scenes or sorted(p.name for p in (SHARED / "scenes").iterdir() if (p / "scene.xml").exists())
    doc = measure(names, args.frames, args.scale)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))
    print("| scene | plan s | forced s | speedup | relMSE plan | relMSE forced | |Δ| | camera-move sets built |")
    print("|---|---|---|---|---|---|---|---|")
    for r in doc["rows"]:
        print(f"| {r['scene']} | {r['plan_seconds']:.1f} | {r['forced_seconds']:.1f} | {r['speedup']:.2f} | "
              f"{r['plan_relmse']:.5f} | {r['forced_relmse']:.5f} | {r['relmse_difference']:.1e} | "
              f"{r['camera_move_sets_built']} |")
    return 0 if all(r["relmse_difference"] <= 1e-4 for r in doc["rows"]) else 1
