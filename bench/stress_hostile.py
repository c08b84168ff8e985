"""Issue 20's hostile cases for ``igi bench stress --cases ...``: what a rogue worker or a hostile
viewer client does to a master, measured with real processes and sockets on loopback.

Each case returns ``{"name", "passed", "figure", "unit", "detail", "seconds"}``: ``figure`` is the
one number the case is about (a longest frame gap, a count of refusals, ...). Cases:

- ``rogue-silent`` / ``rogue-wrong``: a render (the broker ``igi render`` uses) with one good worker
  and a rogue (:mod:`bench.rogue_peer`: credit 4,096 and silent, or wrong-sized RESULTs) that
  registered first; it must finish with the image of a clean render (bit-identical). Figure: the
  tasks the rogue was offered.
- ``serve-rogue``: ``igi serve`` with one local worker streams; a silent rogue joins; frames on
  the ZeroMQ feed must keep coming: the longest gap after the rogue joined must stay within
  ``max(2 s, 5 x the median frame interval before it)``. Figure: that longest gap (s).
- ``moves-5000``: 5,000 object moves (the viewer's ``move`` edit) on a streaming master, then a
  worker joins: it must render frames of scene version 5,000 with no ``scene_mismatch``. Figure:
  seconds from the worker's start to its first frame.
- ``viewer-validation``: absurd sizes, degenerate cameras and bad JSON through the viewer's
  WebSocket each get an error reply, and frames keep coming. Figure: messages answered with an
  error.
- ``host-rebinding``: a loopback viewer answers a DNS-rebinding-shaped request (``Host:
  evil.example:PORT``, matching ``Origin``) with 403, HTTP and WebSocket. Figure: requests refused.
- ``scene-root``: scenes naming ``/etc/passwd``, ``../../x.obj``, a symlink out of the root, an
  ``mtllib`` or ``map_Kd`` outside it are refused with the path in the message; ``root=`` widening
  to a sibling folder loads. Figure: refusals.
"""
from __future__ import annotations

import logging
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .rogue_peer import REPO, rogue_report, start_rogue

W, H = 64, 48
PARAMS = {"photons": 0}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), e.get("PYTHONPATH", "")) if p)
    e["OMP_NUM_THREADS"] = "1"
    return e


def stop_processes(procs) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        for s in (p.stdout, p.stderr):
            if s:
                s.close()


def _wait_until(pred, timeout: float, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(step)
    return bool(pred())


class _Lines(logging.Handler):
    """Collects the messages of a logger while a case runs."""

    def __init__(self, *names: str):
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []
        self.loggers = [logging.getLogger(n) for n in names]

    def emit(self, record):
        self.lines.append(record.getMessage())

    def __enter__(self):
        for lg in self.loggers:
            lg.addHandler(self)
        return self

    def __exit__(self, *exc):
        for lg in self.loggers:
            lg.removeHandler(self)


def _good_worker(endpoint: str, name: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "igi.worker.node", "--connect", endpoint, "--threads", "1",
                             "--name", name, "--heartbeat", "0.5", "--parent-pid", str(os.getpid()), "--quiet",
                             "--exit-with-master"], cwd=REPO, env=_env(), stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _case(name: str, passed: bool, figure, unit: str, t0: float, **detail) -> dict:
    return {"name": name, "passed": bool(passed), "figure": figure, "unit": unit,
            "seconds": round(time.perf_counter() - t0, 3), "detail": detail}


# ----------------------------------------------------------------------------- rogue workers

def case_rogue_render(mode: str) -> dict:
    """A render with a rogue (``silent`` or ``wrong``) and a good worker equals a clean render."""
    from igi.master.broker import Broker
    from igi.master.inprocess import render_local

    from .stress_scenes import mini_cornell

    t0 = time.perf_counter()
    reference = render_local(mini_cornell(W, H), PARAMS, frames=3)
    procs: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory(prefix="igi-rogue-") as tmp:
        report = Path(tmp) / "rogue.json"
        try:
            with Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.5) as broker:
                procs.append(start_rogue(broker.endpoint, mode, report))
                if not _wait_until(lambda: any(w["name"].startswith("rogue") for w in broker.workers()), 60):
                    return _case(f"rogue-{mode}", False, None, "tasks offered to the rogue", t0,
                                 error="the rogue did not register")
                procs.append(_good_worker(broker.endpoint, "good"))
                if not broker.wait_for_workers(2, 180):
                    return _case(f"rogue-{mode}", False, None, "tasks offered to the rogue", t0,
                                 error="the good worker did not register")
                t1 = time.perf_counter()
                image = broker.render_sequence(PARAMS, frames=3, timeout=300)
                render_s = time.perf_counter() - t1
                stats = broker.stats()
        except Exception as e:  # a FrameFailed is the failure this case looks for
            return _case(f"rogue-{mode}", False, None, "tasks offered to the rogue", t0,
                         error=f"{type(e).__name__}: {e}")
        finally:
            stop_processes(procs)
        got = rogue_report(report)
    same = bool(np.array_equal(image, reference))
    offered = int(got.get("tasks", 0))
    return _case(f"rogue-{mode}", same and offered > 0, offered, "tasks offered to the rogue", t0,
                 identical_to_clean_render=same, render_seconds=round(render_s, 3),
                 quarantined=stats.get("quarantined", []))


def serve_with_rogue(scene: str = "cornell-box", width: int = W, height: int = H, baseline_s: float = 5.0,
                     window_s: float = 10.0, mode: str = "silent", start_timeout: float = 240.0,
                     verbose: bool = False) -> dict:
    """``igi serve SCENE --workers 1`` streaming; a rogue (``mode``) joins; frames on the ZeroMQ
    feed are timed for ``baseline_s`` before and ``window_s`` after it joins.

    Returns {frames_before, frames_after, median_interval_s (before), longest_gap_s (after the
    rogue's HELLO, counting from its start to the first frame and from the last frame to the end
    of the window), bound_s = max(2, 5 x median), rogue (its report), requeued_from_rogue (the serve log's
    lines re-queuing tasks the rogue held), serve_log}."""
    import msgpack
    import zmq

    http, bind, pub = free_port(), free_port(), free_port()
    cmd = [sys.executable, "-m", "igi.master.cli"] + (["-v"] if verbose else []) + ["serve", scene, "--workers", "1", "--width", str(width),
           "--height", str(height), "--http", f"127.0.0.1:{http}", "--bind", f"tcp://127.0.0.1:{bind}",
           "--pub", f"tcp://127.0.0.1:{pub}", "--stats-interval", "0", "--photons", "0"]
    procs: list[subprocess.Popen] = []
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.RCVHWM, 4)
    sub.setsockopt(zmq.SUBSCRIBE, b"frame.f16")
    log_path = None
    with tempfile.TemporaryDirectory(prefix="igi-serve-rogue-") as tmp:
        log_path = Path(tmp) / "serve.log"
        report = Path(tmp) / "rogue.json"
        with open(log_path, "w") as log_file:
            serve = subprocess.Popen(cmd, cwd=REPO, env=_env(), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=log_file)
        procs.append(serve)
        try:
            sub.connect(f"tcp://127.0.0.1:{pub}")

            def next_frame(timeout: float):
                if not sub.poll(int(max(0.0, timeout) * 1000)):
                    return None
                parts = sub.recv_multipart()
                return time.monotonic(), msgpack.unpackb(parts[1])

            deadline = time.monotonic() + start_timeout
            first = None
            while first is None and time.monotonic() < deadline and serve.poll() is None:
                first = next_frame(1.0)
            if first is None:
                raise RuntimeError("igi serve published no frame:\n" + log_path.read_text()[-2000:])
            before: list[float] = [first[0]]
            end = time.monotonic() + baseline_s
            while time.monotonic() < end:
                f = next_frame(end - time.monotonic())
                if f is not None:
                    before.append(f[0])
            procs.append(start_rogue(f"tcp://127.0.0.1:{bind}", mode, report))
            if not _wait_until(lambda: rogue_report(report).get("welcomed"), 60, 0.01):
                raise RuntimeError("the rogue was not welcomed")
            t_join = time.monotonic()
            after: list[float] = []
            end = t_join + window_s
            while time.monotonic() < end:
                f = next_frame(end - time.monotonic())
                if f is not None:
                    after.append(f[0])
            t_end = time.monotonic()
            got = rogue_report(report)
            state = _api_state(http)
            alive = serve.poll() is None
        finally:
            sub.close()
            ctx.term()
            stop_processes(procs)
        serve_log = log_path.read_text()
    intervals = np.diff(before)
    median = float(statistics.median(intervals)) if len(intervals) else float("nan")
    marks = [t_join] + after + [t_end]
    longest = float(max(np.diff(marks)))
    return {"frames_before": len(before), "frames_after": len(after), "median_interval_s": median,
            "longest_gap_s": longest, "bound_s": max(2.0, 5.0 * median) if median == median else 2.0,
            "rogue": got, "serve_alive": alive, "state_after": state,
            "requeued_from_rogue": sum(1 for ln in serve_log.splitlines() if "re-queued" in ln and "rogue" in ln),
            "serve_log": serve_log[-(200_000 if verbose else 4000):]}


def _api_state(port: int) -> dict:
    """The viewer's /api/state (stats of the stream), or {"error": ...}."""
    import json
    import urllib.request

    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/state", timeout=10) as r:
            return json.loads(r.read())
    except Exception as e:
        return {"error": f"{type(e).__name__}: {e}"}


def case_serve_rogue() -> dict:
    t0 = time.perf_counter()
    try:
        r = serve_with_rogue()
    except Exception as e:
        return _case("serve-rogue", False, None, "longest frame gap after the rogue joined (s)", t0,
                     error=f"{type(e).__name__}: {e}"[:2000])
    ok = r["serve_alive"] and r["frames_after"] > 0 and r["longest_gap_s"] <= r["bound_s"] \
        and r["rogue"].get("tasks", 0) > 0
    detail = {k: v for k, v in r.items() if k != "serve_log"}
    detail["traceback_in_log"] = "Traceback" in r["serve_log"]
    return _case("serve-rogue", ok and not detail["traceback_in_log"], round(r["longest_gap_s"], 3),
                 "longest frame gap after the rogue joined (s)", t0, **detail)


# ----------------------------------------------------------------------------- many moves

def case_moves(moves: int = 5000) -> dict:
    """``moves`` viewer moves on a streaming master without workers, then a worker joins and
    renders the edited scene."""
    from igi.master.broker import Broker
    from igi.master.viewer import move_edit

    from .stress_scenes import mini_cornell

    t0 = time.perf_counter()
    scene = mini_cornell(W, H)
    block = next(i for i, m in enumerate(scene.meshes) if m.name == "block_top")
    procs: list[subprocess.Popen] = []
    with _Lines("igi.master") as lines:
        try:
            with Broker(scene, bind="tcp://127.0.0.1:*", heartbeat=0.5) as broker:
                broker.start_stream(PARAMS)
                t1 = time.perf_counter()
                for i in range(moves):
                    d = 0.001 if i % 2 == 0 else -0.001  # back and forth
                    broker.apply_edit(move_edit(broker, {"mesh": block}, [d, 0.0, 0.0]))
                moves_s = time.perf_counter() - t1
                version = broker.scene_version
                t2 = time.perf_counter()
                procs.append(_good_worker(broker.endpoint, "late"))
                frames, seq, first_s = [], 0, None
                deadline = time.monotonic() + 240
                while len(frames) < 3 and time.monotonic() < deadline:
                    f = broker.wait_frame(seq, max(0.1, deadline - time.monotonic()))
                    if f is None:
                        break
                    seq = f.seq
                    frames.append(f.spec.scene_version)
                    first_s = first_s if first_s is not None else time.perf_counter() - t2
                done = {w["name"]: w["tasks_done"] for w in broker.workers()}
        except Exception as e:
            return _case("moves-5000", False, None, "seconds from the late worker's start to its first frame", t0,
                         error=f"{type(e).__name__}: {e}")
        finally:
            stop_processes(procs)
    mismatch = sum("scene_mismatch" in ln for ln in lines.lines)
    ok = version == moves and len(frames) == 3 and all(v == moves for v in frames) and mismatch == 0 \
        and done.get("late", 0) > 0
    return _case("moves-5000", ok, None if first_s is None else round(first_s, 3),
                 "seconds from the late worker's start to its first frame", t0, moves=moves, scene_version=version,
                 moves_seconds=round(moves_s, 3), frame_versions=frames, scene_mismatch_lines=mismatch,
                 late_worker_tasks=done.get("late", 0))


# ----------------------------------------------------------------------------- viewer

def _viewer_setup(with_worker: bool):
    from igi.master.broker import Broker
    from igi.master import viewer

    from .stress_scenes import mini_cornell

    broker = Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.5).start()
    broker.start_stream(PARAMS)
    procs = [_good_worker(broker.endpoint, "good")] if with_worker else []
    v = viewer.start(broker, "127.0.0.1", 0, None, pub=None, quiet=True)
    return broker, v, procs


HOSTILE_MESSAGES = [  # (message text, a word the error reply must contain)
    ("{not json", "not valid JSON"),
    ("[" * 100_000, "nested deeper"),
    ('"just a string"', "JSON object"),
    ('{"type": "resolution", "width": 100000, "height": 100000}', "16384"),
    ('{"type": "resolution", "width": 8192, "height": 8192}', "memory budget"),
    ('{"type": "resolution", "width": 2000000000, "height": 2}', "16384"),
    ('{"type": "resolution", "width": "x", "height": 5}', "integer"),
    ('{"type": "camera", "to_world": [' + ", ".join(["1e308"] * 16) + "]}", "beyond the limit"),
    ('{"type": "camera", "to_world": [' + ", ".join(["0.0"] * 15 + ["1.0"]) + "]}", "forward direction is zero"),
    ('{"type": "camera", "to_world": [' + ", ".join(["NaN"] * 16) + "]}", ""),
    ('{"type": "params", "values": {"photons": 1e12}}', "photons"),
]


async def _hostile_ws(url: str, messages) -> dict:
    import json
    import struct

    import aiohttp

    answered, missing = 0, []
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(url.replace("http://", "ws://") + "ws", max_msg_size=0) as ws:
            async def receive(deadline):
                m = await ws.receive(max(0.01, deadline - time.monotonic()))
                if m.type == aiohttp.WSMsgType.BINARY:
                    n = struct.unpack(">I", m.data[:4])[0]
                    h = json.loads(m.data[4:4 + n])
                    await ws.send_str(json.dumps({"type": "ack", "seq": h["seq"]}))
                    return "frame", h
                if m.type != aiohttp.WSMsgType.TEXT:
                    raise RuntimeError(f"WebSocket closed: {m.type}")
                return "text", json.loads(m.data)

            async def next_reply(timeout=60):
                deadline = time.monotonic() + timeout
                while True:
                    kind, d = await receive(deadline)
                    if kind == "text" and d.get("type") not in ("stats", "init"):
                        return d

            async def frame_after(seq, timeout=120):
                deadline = time.monotonic() + timeout
                while True:
                    kind, d = await receive(deadline)
                    if kind == "frame" and d["seq"] > seq:
                        return d

            h = await frame_after(0)
            for text, needle in messages:
                await ws.send_str(text)
                reply = await next_reply()
                if reply.get("type") == "error" and needle in reply.get("message", ""):
                    answered += 1
                else:
                    missing.append({"sent": text[:60], "reply": str(reply)[:200]})
            h2 = await frame_after(h["seq"])
    return {"answered": answered, "missing": missing, "frame_after": h2["seq"] > h["seq"],
            "size_after": [h2["width"], h2["height"]]}


def case_viewer_validation() -> dict:
    import asyncio

    t0 = time.perf_counter()
    broker = v = None
    procs: list = []
    try:
        broker, v, procs = _viewer_setup(with_worker=True)
        r = asyncio.run(_hostile_ws(v.url, HOSTILE_MESSAGES))
    except Exception as e:
        return _case("viewer-validation", False, None, "hostile messages answered with an error", t0,
                     error=f"{type(e).__name__}: {e}")
    finally:
        if v is not None:
            v.stop()
        if broker is not None:
            broker.stop()
        stop_processes(procs)
    ok = r["answered"] == len(HOSTILE_MESSAGES) and r["frame_after"] and r["size_after"] == [W, H]
    return _case("viewer-validation", ok, r["answered"], "hostile messages answered with an error", t0,
                 sent=len(HOSTILE_MESSAGES), **r)


def _http_status(url: str, headers: dict) -> int:
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as e:
        return e.code


async def _ws_status(port: int, host: str, origin: str) -> int:
    import aiohttp

    async with aiohttp.ClientSession() as s:
        try:
            async with s.ws_connect(f"ws://127.0.0.1:{port}/ws", headers={"Host": host, "Origin": origin}):
                return 101
        except aiohttp.WSServerHandshakeError as e:
            return e.status


def case_host_rebinding() -> dict:
    import asyncio

    t0 = time.perf_counter()
    broker = v = None
    try:
        broker, v, _ = _viewer_setup(with_worker=False)
        base = f"http://127.0.0.1:{v.port}/"
        evil = f"evil.example:{v.port}"
        refused = {
            "GET /api/state Host evil": _http_status(base + "api/state", {"Host": evil}),
            "GET / Host evil": _http_status(base, {"Host": evil}),
            "GET /api/state Host 127.0.0.1:other-port": _http_status(base + "api/state",
                                                                     {"Host": f"127.0.0.1:{v.port + 1}"}),
            "WS Host evil + Origin evil": asyncio.run(_ws_status(v.port, evil, f"http://{evil}")),
        }
        allowed = {f"GET /api/state Host {h}": _http_status(base + "api/state", {"Host": h})
                   for h in (f"127.0.0.1:{v.port}", f"localhost:{v.port}", f"[::1]:{v.port}")}
        allowed["WS Host localhost"] = asyncio.run(_ws_status(v.port, f"localhost:{v.port}",
                                                              f"http://localhost:{v.port}"))
    except Exception as e:
        return _case("host-rebinding", False, None, "rebinding-shaped requests refused (403)", t0,
                     error=f"{type(e).__name__}: {e}")
    finally:
        if v is not None:
            v.stop()
        if broker is not None:
            broker.stop()
    n = sum(s == 403 for s in refused.values())
    ok = n == len(refused) and all(s in (200, 101) for s in allowed.values())
    return _case("host-rebinding", ok, n, "rebinding-shaped requests refused (403)", t0, refused=refused,
                 allowed=allowed)


# ----------------------------------------------------------------------------- scene root

_TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"


def _xml(folder: Path, body: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "scene.xml"
    p.write_text('<?xml version="1.0"?>\n<scene version="3.0.0">\n' + body +
                 '\n<emitter type="point"><point name="position" x="0" y="0" z="2"/></emitter>\n</scene>\n')
    return p


def _mesh(fn: str, extra: str = "") -> str:
    return f'<shape type="obj"><string name="filename" value="{fn}"/>{extra}</shape>'


def scene_root_escapes(tmp: Path) -> list[tuple[str, Path, str]]:
    """(case, scene file, the path the refusal must name) for scenes that reach outside their
    folder; writes them under ``tmp``."""
    (tmp / "outside").mkdir(parents=True, exist_ok=True)
    (tmp / "outside" / "tri.obj").write_text(_TRI)
    (tmp / "outside" / "m.mtl").write_text("newmtl m\nKd 1 0 0\n")
    cases = []
    tex = '<bsdf type="diffuse"><texture type="bitmap" name="reflectance">' \
          '<string name="filename" value="/etc/passwd"/></texture></bsdf>'
    s = tmp / "etc-passwd-texture"
    s.mkdir()
    (s / "tri.obj").write_text(_TRI)
    cases.append(("etc-passwd-texture", _xml(s, _mesh("tri.obj", tex)), "/etc/passwd"))
    cases.append(("dotdot-mesh", _xml(tmp / "dotdot-mesh" / "a", _mesh("../../x.obj")), "../../x.obj"))
    s = tmp / "symlink-out"
    s.mkdir()
    os.symlink(tmp / "outside" / "tri.obj", s / "link.obj")
    cases.append(("symlink-out", _xml(s, _mesh("link.obj")), str(tmp / "outside" / "tri.obj")))
    cases.append(("include-out", _xml(tmp / "include-out", '<include filename="/etc/hostname"/>'), "/etc/hostname"))
    s = tmp / "mtllib-out"
    s.mkdir()
    (s / "scene.obj").write_text(f"mtllib ../outside/m.mtl\n{_TRI}")
    cases.append(("mtllib-out", s / "scene.obj", "../outside/m.mtl"))
    s = tmp / "map-kd-out"
    s.mkdir()
    (s / "m.mtl").write_text("newmtl m\nKd 1 0 0\nmap_Kd /etc/passwd\n")
    (s / "scene.obj").write_text(f"mtllib m.mtl\nusemtl m\n{_TRI}")
    cases.append(("map-kd-out", s / "scene.obj", "/etc/passwd"))
    return cases


def case_scene_root() -> dict:
    from igi.common.loader import load_scene
    from igi.common.scene_root import SceneRootError

    t0 = time.perf_counter()
    results, refused = {}, 0
    with tempfile.TemporaryDirectory(prefix="igi-scene-root-") as tmp:
        tmp = Path(tmp).resolve()
        for name, path, needle in scene_root_escapes(tmp):
            try:
                load_scene(path)
                results[name] = "LOADED (not refused)"
            except SceneRootError as e:
                ok = needle in str(e) and "\n" not in str(e)
                refused += ok
                results[name] = ("refused: " if ok else "refused without naming the path: ") + str(e)[:300]
            except Exception as e:
                results[name] = f"other error: {type(e).__name__}: {e}"[:300]
        (tmp / "meshes").mkdir()
        (tmp / "meshes" / "tri.obj").write_text(_TRI)
        sibling = _xml(tmp / "scenes" / "a", _mesh("../../meshes/tri.obj"))
        try:
            widened = len(load_scene(sibling, root=tmp).meshes) == 1
        except Exception as e:
            widened = False
            results["widened"] = f"{type(e).__name__}: {e}"[:300]
    n = len(results) - ("widened" in results)
    return _case("scene-root", refused == n and widened, refused, "scene-root escapes refused", t0,
                 cases=results, widened_root_loads_sibling=widened)


# ----------------------------------------------------------------------------- registry

CASES = {
    "rogue-silent": lambda: case_rogue_render("silent"),
    "rogue-wrong": lambda: case_rogue_render("wrong"),
    "serve-rogue": case_serve_rogue,
    "moves-5000": case_moves,
    "viewer-validation": case_viewer_validation,
    "host-rebinding": case_host_rebinding,
    "scene-root": case_scene_root,
}


def run_hostile(names=None, progress=None) -> dict:
    """Run the named cases (default: all) -> {"cases": [...], "passed": n, "failed": n}."""
    names = list(CASES) if names is None else list(names)
    out = []
    quiet = [logging.getLogger(n) for n in ("igi.master", "igi.viewer", "igi.scene")]
    null = logging.NullHandler()
    saved = [lg.propagate for lg in quiet]
    for lg in quiet:  # the warnings are the behaviour under test, not output (cases still see them)
        lg.propagate = False
        lg.addHandler(null)
    try:
        for n in names:
            rec = CASES[n]()
            out.append(rec)
            if progress:
                progress(rec)
    finally:
        for lg, p in zip(quiet, saved):
            lg.propagate = p
            lg.removeHandler(null)
    passed = sum(r["passed"] for r in out)
    return {"cases": out, "passed": passed, "failed": len(out) - passed}
