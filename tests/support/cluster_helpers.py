"""Shared by the cluster tests: fake workers speaking the protocol,
worker processes on loopback."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import zmq

from igi.common import protocol as P
from igi.common.frame import Tile, TileBuffers

from igi.bench.stress_hostile import stop_processes
from tests.support.paths import ROOT


def env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), e.get("PYTHONPATH", "")) if p)
    e["OMP_NUM_THREADS"] = "1"
    return e


def start_worker(endpoint: str, name: str, heartbeat: float = 1.0, threads: int = 1,
                 exit_with_master: bool = True) -> subprocess.Popen:
    """A real worker process (python -m worker.node) on loopback."""
    return subprocess.Popen([sys.executable, "-m", "igi.worker.node", "--connect", endpoint, "--threads", str(threads),
                             "--name", name, "--heartbeat", str(heartbeat), "--parent-pid", str(os.getpid()),
                             "--quiet"] + (["--exit-with-master"] if exit_with_master else []),
                            env=env(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def stop_procs(procs) -> None:
    """SIGTERM, wait, then SIGKILL what is left; close their pipes (bench.stress_hostile's)."""
    stop_processes(procs)


def wait_until(pred, timeout: float = 30.0, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(step)
    return pred()


class FakeWorker:
    """A DEALER speaking the protocol by hand: for precise broker tests without a renderer."""

    def __init__(self, endpoint: str, name: str = "fake", credit: int = 3, scenes=(), ctx=None,
                 threads: int = 1):
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.IDENTITY, f"{name}/{os.urandom(3).hex()}".encode())
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)
        self.name, self.credit, self.threads = name, credit, threads
        self.frames: dict[int, dict] = {}
        self.hello(scenes)

    def hello(self, scenes=()):
        self.send(P.HELLO, {"name": self.name, "host": "test", "pid": os.getpid(), "threads": self.threads,
                            "credit": self.credit, "scenes": list(scenes)})

    def send(self, kind, body, **kw):
        self.sock.send(P.encode(kind, body, **kw))

    def recv(self, timeout: float = 5.0):
        if not self.sock.poll(int(timeout * 1000)):
            return None
        return P.decode(self.sock.recv(), max_size=P.MAX_SCENE_MESSAGE_SIZE)

    def recv_kind(self, kind, timeout: float = 5.0):
        """Next message of ``kind`` (FRAME bodies are remembered on the way)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv(max(0.0, deadline - time.monotonic()))
            if m is None:
                return None
            if m.kind == P.FRAME:
                self.frames[m.body["frame"]] = m.body
            if m.kind == kind:
                return m
        return None

    def tasks(self, count: int, timeout: float = 5.0) -> list[dict]:
        out = []
        deadline = time.monotonic() + timeout
        while len(out) < count and time.monotonic() < deadline:
            m = self.recv_kind(P.TASK, max(0.0, deadline - time.monotonic()))
            if m is None:
                break
            out.append(m.body)
        return out

    def result(self, task: dict, epoch: int | None = None, value: float = 1.0, timings: dict | None = None):
        """Answer a TASK with constant buffers of the right size (and ``timings``, when given)."""
        from igi.common.codec import encode
        from igi.master.frame_assembly import tile_pixel_count

        fb = self.frames[task["frame"]]
        tile = Tile(task["k"], *task["tile"])
        n = fb["params"]["interleave"]
        count = tile_pixel_count(tile, n, fb["width"], fb["height"])
        ones = np.full((count, 3), value, np.float32)
        bufs = TileBuffers(reflectance=ones, irradiance=ones, unfiltered=np.zeros_like(ones),
                           depth=np.ones(count, np.float32),
                           normal=np.tile(np.array([0, 0, 1], np.float32), (count, 1)))
        body = {"frame": task["frame"], "task": task["task"], "epoch": task["epoch"] if epoch is None else epoch,
                "count": count, "data": encode(bufs)}
        if timings is not None:
            body["timings"] = timings
        self.send(P.RESULT, body)

    def close(self):
        self.sock.close(0)
