"""Master merge + filter + compose, before (numpy, tests/support/oracle_master.py) and after
(compiled kernels) in one process, on one core: ``PYTHONPATH=. python -m tests.support.master_speed``.

A frame's wire bytes (every task tile of ``--width`` x ``--height``, ``--interleave`` (default: the product default), encoded by
common.codec) go through ``add_wire`` (validate, lz4, decode/store) and ``image()`` (filter,
compose) ``--reps`` times each way; the best time of each is reported as Mpixel/s (wall and
CPU), and the two images are checked to be equal bit for bit. The frame is rendered from
``--scene`` (a shared scene name or path) or, by default, synthetic (walls, misses, noise).
Prints one JSON object; not a test (no timing thresholds anywhere)."""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def synthetic_frame(w: int, h: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    wall = (xx * 3 // w) + 3 * (yy * 2 // h)
    normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0], [0, 0, -1]], np.float32)
    nrm = normals[wall] + 0.01 * rng.standard_normal((h, w, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    irr = (1 + 0.3 * rng.standard_normal((h, w, 3))).astype(np.float32) * (wall[..., None] + 1)
    depth = (2 + 0.001 * xx + 0.05 * wall).astype(np.float32)
    depth[wall == 5] = np.inf
    unf = np.zeros((h, w, 3), np.float32)
    unf[: h // 10, w // 3: w // 2] = 17.0
    refl = np.repeat(rng.random((6, 3), dtype=np.float32)[wall], 1, 0)
    return {"reflectance": refl, "irradiance": irr, "unfiltered": unf, "depth": depth, "normal": nrm}


def rendered_frame(scene: str, w: int, h: int) -> dict:
    from igi.bench.stress_scenes import load_shared
    from igi.common.camera import resolve_camera
    from igi.common.params import make_params, params_to_dict
    from igi.master.accumulation import sequence_spec
    from igi.master.frame_assembly import FrameAssembler, task_tiles
    from igi.worker.renderer import Renderer

    sc = load_shared(scene)
    cam, fov, w, h = resolve_camera(sc, None, w, h)
    pd = params_to_dict(make_params())
    spec = sequence_spec(0, 0, cam, fov, w, h, pd)
    r = Renderer(sc)
    asm = FrameAssembler(w, h, int(pd["interleave"]))
    for t in task_tiles(w, h, int(pd["interleave"])):
        asm.add(t, r.render_tile(spec, t))
    return asm.buffers


def measure(buffers: dict, n: int = 3, reps: int = 5, params: dict | None = None) -> dict:
    from igi.common.codec import encode
    from igi.common.interleave import extract
    from igi.common.params import make_params, params_to_dict
    from igi.master import parallel
    from igi.master.frame_assembly import FrameAssembler, task_tiles

    from tests.support.oracle_master import OracleFrameAssembler

    H, W = buffers["depth"].shape
    pd = params or params_to_dict(make_params(interleave=n))
    wire = [(t, encode(extract(t, n, buffers))) for t in task_tiles(W, H, n)]
    prev = parallel.set_threads(1)
    out = {"width": W, "height": H, "interleave": n, "tasks": len(wire), "reps": reps, "threads": 1}
    try:
        images = {}
        for name, cls in (("numpy", OracleFrameAssembler), ("kernels", FrameAssembler)):
            best = {"merge_wall": 1e9, "finish_wall": 1e9, "merge_cpu": 1e9, "finish_cpu": 1e9}
            for _ in range(reps + 1):  # +1: the first run compiles / loads the kernels
                asm = cls(W, H, n)
                t0, c0 = time.perf_counter(), time.process_time()
                for t, d in wire:
                    asm.add_wire(t, d)
                t1, c1 = time.perf_counter(), time.process_time()
                images[name] = asm.image(pd)
                t2, c2 = time.perf_counter(), time.process_time()
                for k, v in (("merge_wall", t1 - t0), ("finish_wall", t2 - t1), ("merge_cpu", c1 - c0),
                             ("finish_cpu", c2 - c1)):
                    best[k] = min(best[k], v)
            px = W * H
            out[name] = {"merge_ms": best["merge_wall"] * 1e3, "filter_compose_ms": best["finish_wall"] * 1e3,
                         "mpixel_s": px / (best["merge_wall"] + best["finish_wall"]) / 1e6,
                         "mpixel_s_cpu": px / (best["merge_cpu"] + best["finish_cpu"]) / 1e6}
        out["speedup"] = out["kernels"]["mpixel_s"] / out["numpy"]["mpixel_s"]
        out["bit_identical"] = images["numpy"].tobytes() == images["kernels"].tobytes()
    finally:
        parallel.set_threads(prev)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--scene", default=None, help="render this shared scene instead of a synthetic frame")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--interleave", type=int, default=None, help="default: the product's default")
    args = ap.parse_args(argv)
    if args.scene:
        buffers = rendered_frame(args.scene, args.width, args.height)
    else:
        buffers = synthetic_frame(args.width, args.height)
    from igi.common.params import make_params

    res = measure(buffers, n=args.interleave or make_params().interleave, reps=args.reps)
    res["frame"] = args.scene or "synthetic"
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
