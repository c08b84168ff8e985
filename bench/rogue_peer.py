"""A misbehaving registered worker, as a process (issue 20: ``igi bench stress`` and the tests):
raw ZeroMQ DEALER that speaks just enough protocol to register.

    python -m igi.bench.rogue_peer ENDPOINT MODE REPORT

:func:`start_rogue` starts one (the checkout on PYTHONPATH) and :func:`rogue_report` reads its
report.

MODE ``silent``: HELLO with credit 4,096, heartbeats, never answers a task. MODE ``wrong``:
answers every TASK at once with a RESULT of the wrong size (one pixel too many, junk data).
ENDPOINT ``find:PID`` waits for the process PID to listen on a 127.0.0.1 TCP port and connects
there (``igi render`` binds a port chosen by the OS and does not print it). The rogue writes the
number of TASKs it got (and the endpoint) to REPORT, a JSON file, as they come.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import subprocess

import zmq

from igi.common import protocol as P

REPO = Path(__file__).resolve().parents[1]


def start_rogue(endpoint: str, mode: str, report: str | Path) -> subprocess.Popen:
    """A rogue worker process (``mode`` ``silent`` or ``wrong``) against ``endpoint`` (or
    ``find:PID``), writing what it got to ``report``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return subprocess.Popen([sys.executable, "-m", "igi.bench.rogue_peer", endpoint, mode, str(report)], cwd=REPO,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def rogue_report(path: str | Path) -> dict:
    """The rogue's report so far (``{}`` before it wrote one)."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}


def listening_ports(pid: int) -> list[int]:
    """TCP ports process ``pid`` listens on at 127.0.0.1 (Linux /proc)."""
    inodes = set()
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if link.startswith("socket:["):
                inodes.add(link[8:-1])
    except OSError:
        return []
    ports = []
    with open("/proc/net/tcp") as f:
        next(f)
        for line in f:
            parts = line.split()
            local, state, inode = parts[1], parts[3], parts[9]
            ip, port = local.split(":")
            if state == "0A" and inode in inodes and ip == "0100007F":
                ports.append(int(port, 16))
    return ports


def find_endpoint(pid: int, timeout: float = 120.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ports = listening_ports(pid)
        if ports:
            return f"tcp://127.0.0.1:{ports[0]}"
        time.sleep(0.02)
    raise SystemExit(f"process {pid} did not listen within {timeout} s")


def main() -> int:
    endpoint, mode, report = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    if endpoint.startswith("find:"):
        endpoint = find_endpoint(int(endpoint[5:]))
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.IDENTITY, f"rogue-{mode}/{os.getpid()}".encode())
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, P.MAX_SCENE_MESSAGE_SIZE)
    sock.connect(endpoint)
    sock.send(P.encode(P.HELLO, {"name": f"rogue-{mode}", "host": "rogue", "pid": os.getpid(), "threads": 1,
                                 "credit": 4096, "scenes": []}))
    stats = {"endpoint": endpoint, "tasks": 0, "results_sent": 0, "welcomed": False}

    def save():  # atomically: the test may read it at any time
        tmp = report.with_suffix(".tmp")
        tmp.write_text(json.dumps(stats))
        os.replace(tmp, report)
    save()
    last_hb = 0.0
    frames = {}
    while True:
        now = time.monotonic()
        if now - last_hb >= 0.2:
            sock.send(P.encode(P.HEARTBEAT, {}))
            last_hb = now
        if not sock.poll(100):
            continue
        try:
            msg = P.decode(sock.recv(), max_size=P.MAX_SCENE_MESSAGE_SIZE)
        except P.ProtocolError:
            continue
        if msg.kind == P.WELCOME:
            stats["welcomed"] = True
        elif msg.kind == P.BYE:
            save()
            return 0
        elif msg.kind == P.FRAME:
            frames[msg.body["frame"]] = msg.body
        elif msg.kind == P.TASK:
            stats["tasks"] += 1
            if mode == "wrong":
                b = msg.body
                sx0, sy0, sx1, sy1 = b["tile"]
                count = (sx1 - sx0) * (sy1 - sy0) + 1  # at least one pixel too many
                sock.send(P.encode(P.RESULT, {"frame": b["frame"], "task": b["task"], "epoch": b["epoch"],
                                              "count": count, "data": os.urandom(64)}))
                stats["results_sent"] += 1
        save()


if __name__ == "__main__":
    sys.exit(main())
