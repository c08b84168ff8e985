"""Micro-benchmark: the master loop thread's cost per RESULT (issue 19).

Drives a real :class:`master.broker.Broker` (not started: no sockets, its sends are no-ops)
with ``workers`` registered fake workers and ``pipeline`` open 640x480 frames, and feeds it
RESULT frames exactly as the loop would (``Links.on_message``: protocol decode + validation,
bookkeeping, the tile's validate + lz4 + store, then one ``FrameLoop.dispatch`` round of the
set-aware scheduler over the whole queue). Two cases: RESULTs that carry no set list (what a
worker sends now, unless its list changed) and RESULTs that list 64 cached sets (what every
RESULT carried before). ZeroMQ's own receive is not included (see scaling_model's
``_zmq_message_cost``).

    python -m igi.bench.result_cost            # JSON on stdout

CPU time of this thread (``time.thread_time``), best of ``reps``; on a loaded machine the
figures are upper bounds.
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np


def _quad_scene(width: int, height: int):
    from igi.common.camera import look_at
    from igi.common.scene import AREA, DIFFUSE, NULL, Camera, Emitter, Material, Mesh, Scene, Texture

    v = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    lv = np.array([[0.8, 1.9, 0.8], [1.2, 1.9, 0.8], [1.2, 1.9, 1.2], [0.8, 1.9, 1.2]], float)
    mats = [Material("white", DIFFUSE, diffuse=Texture.constant(0.7)), Material("light", NULL)]
    meshes = [Mesh("wall", v, f, 0), Mesh("light", lv, f, 1, emitter=0)]
    cam = Camera(look_at([1.0, 1.0, 4.0], [1.0, 1.0, 0.0], [0, 1, 0]), fov=45, width=width, height=height)
    return Scene(meshes, mats, [Emitter(AREA, radiance=np.full(3, 5.0), mesh=1, name="light")], cam,
                 source="result-cost")


def measure(width: int = 640, height: int = 480, workers: int = 16, results: int = 600,
            sets: int = 64, reps: int = 3) -> dict:
    """Per-RESULT CPU µs on the loop thread: {"no_sets": ..., "sets_64": ..., "dispatch": ...}."""
    from igi.common import protocol as P
    from igi.common.codec import encode
    from igi.common.frame import TileBuffers

    from igi.master import broker as B
    from igi.master.frame_assembly import tile_pixel_count
    from igi.master.links import Worker

    out = {}
    for case, listed in (("no_sets", None), (f"sets_{sets}", sets)):
        best = float("inf")
        best_dispatch = float("inf")
        for _ in range(max(1, reps)):
            br = B.Broker(_quad_scene(width, height), bind="tcp://127.0.0.1:0")
            links, loop = br._links, br._frame_loop
            links.send = lambda w, frame, expire_on_fail=True: True  # no sockets
            now = time.monotonic()
            ws = []
            for i in range(workers):
                ident = f"bench{i}".encode()
                w = Worker(ident=ident, name=f"bench{i}", host="h", pid=1, threads=1, credit=3,
                           scenes=set(), last_seen=now, joined=now)
                w.scene_state = (br.scene_hash, br.scene_version)
                links.workers[ident] = w
                ws.append(w)
                for _ in range(20):
                    links.faults.delivered(ident)  # full credit
            payloads = {}
            frames_open = [0]

            def open_frames():
                while len(loop.frames) < br.pipeline:
                    br.submit_frame(br.frame_spec(frames_open[0], {"photons": 0}))
                    frames_open[0] += 1
            open_frames()
            set_list = [[s, k] for s in range(max(1, (listed or 0) // 9 + 1)) for k in range(9)][:listed or 0]
            handled = 0
            cpu = 0.0
            dispatch_before = len(loop.meters.dispatch_times)
            while handled < results:
                progressed = False
                for w in ws:
                    if not w.inflight:
                        continue
                    key, epoch = next(iter(w.inflight.items()))
                    f = loop.frames[key[0]]
                    t = f.tasks[key[1]]
                    n = f.assembler.n
                    count = tile_pixel_count(t.tile, n, width, height)
                    data = payloads.get(count)
                    if data is None:
                        z = np.zeros((count, 3), np.float32)
                        data = payloads[count] = encode(TileBuffers(z, z, z, np.ones(count, np.float32),
                                                                    np.tile(np.float32([0, 0, 1]), (count, 1))))
                    body = {"frame": key[0], "task": key[1], "epoch": epoch, "count": count, "data": data,
                            "rays": 1, "timings": {"render": 0.03, "encode": 0.001}}
                    if listed:
                        body["sets"] = set_list
                    msg = P.encode(P.RESULT, body, check=False)
                    c0 = time.thread_time()
                    links.on_message([w.ident, msg])
                    loop.dispatch()
                    cpu += time.thread_time() - c0
                    handled += 1
                    progressed = True
                    open_frames()  # completed frames are replaced, as render_sequence does
                    if handled >= results:
                        break
                if not progressed:
                    loop.dispatch()
                    open_frames()
            best = min(best, cpu / handled)
            d = list(loop.meters.dispatch_times)[dispatch_before:]
            if d:
                best_dispatch = min(best_dispatch, float(np.median(d)))
        out[case] = {"per_result_us": best * 1e6, "dispatch_us_median": best_dispatch * 1e6}
    out["config"] = {"width": width, "height": height, "workers": workers, "results": results,
                     "pipeline": br.pipeline, "sets_listed": sets}
    return out


def main(argv=None) -> int:
    res = measure()
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
