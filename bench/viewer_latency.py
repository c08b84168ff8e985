"""Input-to-frame latency: from a camera input to the first published frame that shows it.

:func:`measure_latency` drives a streaming :class:`master.broker.Broker` directly
(``set_camera`` → the first ``StreamFrame`` whose spec carries that camera): the master +
workers part of the latency. :func:`ws_latency` does the same through a running viewer's
WebSocket (camera message → first JPEG frame whose header carries that camera), adding the
viewer's tone mapping, encoding and transfer. Before every input the view has been static long
enough to publish one frame (the situation of a user who starts moving), and the inputs
alternate between two nearby cameras (a sideways step of 0.5 % of the scene diagonal), so
each is a real change that restarts the frame.

``igi bench scaling`` reports :func:`stream_latency` per point; standalone:

    igi bench viewer-latency SCENE [--workers 2] [--size 96x96] [--inputs 10] [--ws]
    python -m igi.bench.viewer_latency SCENE ...       (the same)
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def summarize(samples_s: list[float]) -> dict:
    a = np.asarray(samples_s, np.float64) * 1e3
    if a.size == 0:
        return {"inputs": 0}
    return {"inputs": int(a.size), "mean_ms": float(a.mean()), "p50_ms": float(np.percentile(a, 50)),
            "p95_ms": float(np.percentile(a, 95)), "min_ms": float(a.min()), "max_ms": float(a.max())}


def _step_cameras(to_world, diagonal: float, fraction: float = 0.005) -> list[np.ndarray]:
    m = np.asarray(to_world, np.float64).reshape(4, 4)
    left = m[:3, 0] / (np.linalg.norm(m[:3, 0]) or 1.0)
    out = []
    for sign in (1.0, -1.0):
        c = m.copy()
        c[:3, 3] = m[:3, 3] + sign * fraction * diagonal * left
        out.append(c)
    return out


def measure_latency(broker, inputs: int = 10, timeout: float = 60.0) -> dict:
    """Latency over ``inputs`` camera inputs on a broker that is streaming with workers.

    Returns {inputs, mean_ms, p50_ms, p95_ms, min_ms, max_ms} measured from just before
    ``set_camera`` to the moment the frame is handed to ``wait_frame`` (what a viewer sees), plus
    ``publish``: the same statistics from the view change on the master's loop thread to the
    frame's publication (``StreamFrame.time - view_time``), and ``frame_ms``: the static frame
    interval for comparison."""
    v = broker.view()
    if not v:
        raise ValueError("the stream was not started")
    cams = _step_cameras(v["camera"], broker.scene.diagonal())
    f = broker.wait_frame(0, timeout)
    if f is None:
        raise TimeoutError("no stream frame (are workers connected?)")
    seen, publish, intervals = [], [], []
    for i in range(max(1, inputs)):
        f0 = broker.wait_frame(f.seq, timeout)  # one frame of the static view first
        if f0 is None:
            raise TimeoutError("the stream stopped")
        intervals.append(f0.time - f.time)
        cam = cams[i % 2]
        target = tuple(float(x) for x in cam.reshape(16))
        t0 = time.monotonic()
        broker.set_camera(cam)
        f = f0
        while True:
            g = broker.wait_frame(f.seq, max(0.0, t0 + timeout - time.monotonic()))
            if g is None:
                raise TimeoutError(f"input {i}: no frame with the new camera in {timeout:g} s")
            f = g
            if g.spec.camera_to_world == target:
                seen.append(time.monotonic() - t0)
                publish.append(g.time - g.view_time)
                break
    broker.set_camera(np.asarray(v["camera"], np.float64))
    out = summarize(seen)
    out["publish"] = summarize(publish)
    out["frame_ms"] = float(np.median(intervals) * 1e3) if intervals else None
    return out


def stream_latency(broker, params=None, width: int | None = None, height: int | None = None,
                   inputs: int = 5, timeout: float = 120.0) -> dict:
    """Start a stream (params, resolution), measure :func:`measure_latency`, stop the stream."""
    broker.start_stream(params, width=width, height=height)
    try:
        return measure_latency(broker, inputs, timeout)
    finally:
        broker.stop_stream()


async def _ws_latency(url: str, inputs: int, timeout: float, token: str | None) -> dict:
    import asyncio
    import struct

    import aiohttp

    ws_url = url.split("?", 1)[0].rstrip("/") + "/ws"
    ws_url = ws_url.replace("http://", "ws://", 1).replace("https://", "wss://", 1)
    headers = {"X-IGI-Token": token} if token else {}
    loop = asyncio.get_running_loop()
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(ws_url, headers=headers, max_msg_size=1 << 28) as ws:
            init = None
            while init is None:
                m = await ws.receive(timeout)
                if m.type == aiohttp.WSMsgType.TEXT and '"type":"init"' in m.data:
                    init = json.loads(m.data)
            cams = _step_cameras(init["view"]["camera"], init["scene"]["diagonal"])

            async def next_frame(deadline):
                while True:
                    m = await ws.receive(max(0.01, deadline - loop.time()))
                    if m.type == aiohttp.WSMsgType.BINARY:
                        n = struct.unpack(">I", m.data[:4])[0]
                        h = json.loads(m.data[4:4 + n])
                        await ws.send_str(json.dumps({"type": "ack", "seq": h["seq"]}))
                        return h
                    if m.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                        raise ConnectionError("viewer closed the WebSocket")

            seen = []
            await next_frame(loop.time() + timeout)
            for i in range(max(1, inputs)):
                await next_frame(loop.time() + timeout)  # a frame of the static view
                cam = cams[i % 2]
                target = cam.reshape(16)
                t0 = loop.time()
                await ws.send_str(json.dumps({"type": "camera", "to_world": target.tolist()}))
                while True:
                    h = await next_frame(t0 + timeout)
                    if np.allclose(h["camera"], target, rtol=0, atol=1e-12):
                        seen.append(loop.time() - t0)
                        break
            await ws.send_str(json.dumps({"type": "camera", "to_world": list(init["view"]["camera"])}))
    return summarize(seen)


def ws_latency(url: str, inputs: int = 10, timeout: float = 60.0, token: str | None = None) -> dict:
    """:func:`measure_latency` through the viewer at ``url`` (camera message → JPEG frame)."""
    import asyncio

    return asyncio.run(_ws_latency(url, inputs, timeout, token))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--size", default="96x96")
    p.add_argument("--inputs", type=int, default=10)
    p.add_argument("--ws", action="store_true", help="also through the viewer's WebSocket")
    p.add_argument("--photons", type=int, default=None)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m igi.bench.viewer_latency", description=__doc__.split("\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


def run(a: argparse.Namespace) -> int:
    from igi.master.cli import load_scene_file
    from igi.master.local_workers import local_cluster

    w, h = (int(x) for x in a.size.lower().split("x"))
    scene = load_scene_file(a.scene)
    params = {} if a.photons is None else {"photons": a.photons}
    with local_cluster(scene, a.workers) as cluster:
        broker = cluster.broker
        broker.start_stream(params, width=w, height=h)
        res = {"scene": a.scene, "size": a.size, "workers": a.workers,
               "broker": measure_latency(broker, a.inputs)}
        if a.ws:
            from igi.master import viewer

            v = viewer.start(broker, "127.0.0.1", 0, None, pub=None, quiet=True)
            try:
                res["websocket"] = ws_latency(v.url, a.inputs)
            finally:
                v.stop()
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
