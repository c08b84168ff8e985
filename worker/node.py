"""The worker: a DEALER that connects to the master, renders tasks and returns their buffers.

Threads
-------
- The *socket thread* (the one calling :meth:`WorkerNode.run`) owns the DEALER socket: it
  receives, validates (``common/protocol.py``) and routes messages, sends results from the
  outbox, heartbeats, and reconnects.
- A *scene thread* decodes scene blobs and builds renderers (BVH builds take time; the socket
  thread keeps heartbeating meanwhile).
- ``threads`` *render threads* run ``Renderer.render_tile`` + ``codec.encode`` (Embree releases
  the GIL, numpy mostly too).

Protocol behaviour
------------------
- HELLO advertises threads, credit (default 3 per thread: the master never sends more tasks
  than that before results come back — credit-based flow control) and the scene hashes held in
  the blob cache (LRU of :attr:`cache_size` blobs), so a reconnecting worker is not sent the
  scene again.
- Heartbeat: HEARTBEAT after ``interval`` s without sending; the master is considered gone after
  ``liveness`` intervals without any message from it — then the socket is closed and reopened
  (new identity) after a backoff of 1, 2, 4 … ``max_backoff`` s, each attempt logged with why.
- REFUSE from the master (e.g. another protocol version): logged and the worker exits with
  status 2 (retrying cannot help). BYE from the master: reconnect with backoff, or exit when
  ``exit_with_master`` (local workers started by ``igi render``/``igi serve``).
- SIGTERM / Ctrl-C: BYE to the master, then exit 0.
"""
from __future__ import annotations

import argparse
import collections
import concurrent.futures as cf
import logging
import os
import queue
import signal
import socket
import sys
import threading
import time
import traceback
import uuid
import weakref

import zmq

from igi.common import protocol as P
from igi.common.frame import Tile
from igi.common.gc_policy import settle_long_lived
from igi.common.malloc_policy import reuse_freed_blocks
from igi.common.ratelimit_log import RateLimitedLog

log = logging.getLogger("igi.worker")


class _SceneState:
    """One (hash, version) of the scene: a Future of (scene, renderer)."""

    def __init__(self, h: str, version: int, future: cf.Future):
        self.hash, self.version, self.future = h, version, future


class WorkerNode:
    def __init__(self, connect: str, threads: int = 1, credit: int | None = None, name: str | None = None,
                 heartbeat: float = P.HEARTBEAT_INTERVAL, liveness: int = P.HEARTBEAT_LIVENESS,
                 max_backoff: float = 32.0, cache_size: int = 4, exit_with_master: bool = False,
                 parent_pid: int | None = None, renderer_factory=None,
                 context: zmq.Context | None = None, configure_socket=None):
        self.connect = connect
        self.threads = max(1, int(threads))
        self.credit = int(credit) if credit else self.threads * P.CREDIT_PER_THREAD
        self.name = name or f"{socket.gethostname()}:{os.getpid()}"
        self.heartbeat = float(heartbeat)
        self.liveness = int(liveness)
        self.max_backoff = float(max_backoff)
        self.cache_size = max(1, int(cache_size))
        self.exit_with_master = exit_with_master
        self.parent_pid = parent_pid
        self._renderer_factory = renderer_factory
        self._configure_socket = configure_socket  # e.g. CURVE client keys (issue 8), before connect
        self._ctx = context or zmq.Context.instance()
        self._blobs: collections.OrderedDict[str, bytes] = collections.OrderedDict()
        self._state: _SceneState | None = None
        self._prev_state: _SceneState | None = None
        self._frames: collections.OrderedDict[int, tuple] = collections.OrderedDict()  # frame -> (spec, hash)
        self._pool = cf.ThreadPoolExecutor(self.threads, thread_name_prefix="igi-render")
        self._scene_pool = cf.ThreadPoolExecutor(1, thread_name_prefix="igi-scene")
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_lock = threading.Lock()
        self._stopping = False
        self._stop_reason = ""
        self._queued = 0
        self._queued_lock = threading.Lock()
        self._session = 0  # bumps on every reconnect: results of older sessions are dropped
        self._pending: set[cf.Future] = set()  # render futures of the current session
        self.exit_code = 0
        self.tasks_done = 0
        self._rl = RateLimitedLog(log)  # junk from the master: one line per kind per interval
        self._sets_lock = threading.Lock()
        self._sets_sent: tuple | None = None  # (session, id(renderer), list) last sent in a RESULT
        self._sets_version: tuple | None = None  # (session, weakref(renderer), sets_version) last listed

    # ------------------------------------------------------------------ control
    def stop(self, reason: str = "stopped") -> None:
        """Thread- and signal-safe: leave the run loop after sending BYE."""
        self._stop_reason = reason
        self._stopping = True
        self._wake()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass

    # ------------------------------------------------------------------ main loop
    def run(self) -> int:
        backoff = 1.0
        try:
            while not self._stopping:
                outcome = self._session_loop()
                if outcome in ("stop", "refused"):
                    break
                if outcome == "bye" and self.exit_with_master:
                    log.info("master said BYE; exiting")
                    break
                if outcome == "welcomed":
                    backoff = 1.0
                log.warning("reconnecting to %s in %.0f s", self.connect, backoff)
                if self._sleep(backoff):
                    break
                backoff = min(self.max_backoff, backoff * 2)
        finally:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._scene_pool.shutdown(wait=False, cancel_futures=True)
            for s in (self._wake_r, self._wake_w):
                try:
                    s.close()
                except OSError:
                    pass
        return self.exit_code

    def _sleep(self, seconds: float) -> bool:
        """Interruptible sleep; True when asked to stop."""
        deadline = time.monotonic() + seconds
        while not self._stopping and time.monotonic() < deadline:
            if self._parent_gone():
                self._stopping = True
                break
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        return self._stopping

    def _parent_gone(self) -> bool:
        return self.parent_pid is not None and os.getppid() != self.parent_pid

    def _session_loop(self) -> str:
        """One connection: returns 'stop', 'refused', 'bye', 'silent' or 'welcomed' (lost after welcome)."""
        self._session += 1
        session = self._session
        ident = f"{self.name}/{uuid.uuid4().hex[:8]}".encode()[:255]
        sock = self._ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.IDENTITY, ident)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, P.MAX_SCENE_MESSAGE_SIZE)
        sock.setsockopt(zmq.SNDHWM, 10000)
        sock.setsockopt(zmq.RCVHWM, 10000)
        if self._configure_socket is not None:
            self._configure_socket(sock)
        try:
            sock.connect(self.connect)
        except zmq.ZMQError as e:
            log.error("cannot connect to %s: %s", self.connect, e)
            sock.close(0)
            self.exit_code = 2
            return "refused"
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        poller.register(self._wake_r.fileno(), zmq.POLLIN)
        # the socket monitor tells why the master does not answer (refused, unreachable, ...)
        monitor = None
        link = "no connection yet"
        try:
            monitor = sock.get_monitor_socket(zmq.EVENT_CONNECTED | zmq.EVENT_CONNECT_RETRIED
                                              | zmq.EVENT_DISCONNECTED | zmq.EVENT_CLOSED
                                              | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
                                              | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL)
            poller.register(monitor, zmq.POLLIN)
        except zmq.ZMQError:  # pragma: no cover - monitoring unsupported
            monitor = None
        welcomed = False
        last_recv = time.monotonic()
        last_sent = 0.0

        def send(frame: bytes) -> None:
            nonlocal last_sent
            try:
                sock.send(frame, zmq.NOBLOCK, copy=False)
                last_sent = time.monotonic()
            except zmq.Again:
                log.warning("send queue to the master is full; message dropped")

        send(self._hello())
        outcome = None
        try:
            while outcome is None:
                if self._stopping:
                    send(P.encode(P.BYE, {"reason": self._stop_reason or "stopping"}))
                    sock.close(linger=500)
                    sock = None
                    return "stop"
                now = time.monotonic()
                wait = min(self.heartbeat, max(0.0, last_sent + self.heartbeat - now)) if welcomed else 0.1
                events = dict(poller.poll(max(1, int(wait * 1000))))
                if self._wake_r.fileno() in events:
                    try:
                        while self._wake_r.recv(4096):
                            pass
                    except (BlockingIOError, OSError):
                        pass
                if monitor is not None and monitor in events:
                    link = self._monitor_events(monitor, link)
                if sock in events:
                    for _ in range(256):
                        try:
                            frame = sock.recv(zmq.NOBLOCK)
                        except zmq.Again:
                            break
                        last_recv = time.monotonic()
                        outcome = self._on_frame(frame, send, session)
                        if outcome == "welcome":
                            welcomed, outcome = True, None
                        if outcome is not None:
                            break
                # results from the render threads
                while True:
                    try:
                        sess, frame = self._outbox.get_nowait()
                    except queue.Empty:
                        break
                    if sess == session:
                        send(frame)
                now = time.monotonic()
                if welcomed and now - last_sent >= self.heartbeat:
                    send(P.encode(P.HEARTBEAT, {"queued": min(self._queued, 1 << 20)}))
                silent = now - last_recv
                if silent > self.heartbeat * self.liveness:
                    log.warning("master at %s silent for %.1f s (%s; %s)", self.connect, silent,
                                "connection lost" if welcomed else "no answer to HELLO", link)
                    outcome = "silent"
                if self._parent_gone():
                    log.info("parent process gone; stopping")
                    self.stop("parent gone")
        finally:
            # tasks of this connection not started yet are moot: the master re-queues them
            for fut in list(self._pending):
                if fut.cancel():
                    with self._queued_lock:
                        self._queued -= 1
            if monitor is not None:
                try:
                    sock.disable_monitor() if sock is not None else None
                except zmq.ZMQError:
                    pass
                monitor.close(0)
            if sock is not None:
                sock.close(0)
        if outcome in ("refused", "bye"):
            return outcome
        return "welcomed" if welcomed else outcome

    @staticmethod
    def _monitor_events(monitor, link: str) -> str:
        """Drain socket-monitor events; returns a short description of the link state."""
        from zmq.utils.monitor import recv_monitor_message

        names = {zmq.EVENT_CONNECTED: "connected", zmq.EVENT_CONNECT_RETRIED: "connection refused or unreachable",
                 zmq.EVENT_DISCONNECTED: "disconnected", zmq.EVENT_CLOSED: "closed",
                 zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: "ZeroMQ handshake failed",
                 zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: "ZeroMQ handshake failed (not a ZeroMQ peer?)"}
        while True:
            try:
                ev = recv_monitor_message(monitor, zmq.NOBLOCK)
            except zmq.Again:
                return link
            except zmq.ZMQError:
                return link
            name = names.get(ev.get("event"))
            if name is not None:
                if name != link:
                    log.debug("link to master: %s", name)
                link = name

    def _hello(self) -> bytes:
        from importlib import metadata

        try:
            version = metadata.version("igi")
        except Exception:
            version = "dev"
        return P.encode(P.HELLO, {"name": self.name[:128], "host": socket.gethostname()[:255],
                                  "pid": os.getpid(), "threads": self.threads, "credit": self.credit,
                                  "scenes": list(self._blobs)[-64:], "renderer": f"igi {version}",
                                  "cores": os.cpu_count() or 1})

    # ------------------------------------------------------------------ messages
    def _on_frame(self, frame: bytes, send, session: int) -> str | None:
        try:
            msg = P.decode(frame, max_size=P.MAX_SCENE_MESSAGE_SIZE)
        except P.VersionMismatch as e:
            log.error("master speaks another protocol: %s", e)
            send(P.refusal(e.theirs))
            self.exit_code = 2
            return "refused"
        except P.ProtocolError as e:
            self._rl.warning("dropped", "dropped message from the master: %s", e)
            return None
        kind, body = msg.kind, msg.body
        if kind == P.WELCOME:
            self.heartbeat, self.liveness = body["heartbeat"], body["liveness"]
            log.info("registered with master %s as %s", self.connect, body["worker"])
            return "welcome"
        if kind == P.TASK:
            self._on_task(body, send, session)
        elif kind == P.FRAME:
            self._frames[body["frame"]] = (P.spec_from_body(body), body["hash"])
            while len(self._frames) > 64:
                self._frames.popitem(last=False)
        elif kind == P.SCENE:
            self._on_scene(body, send)
        elif kind == P.EDIT:
            self._on_edit(body, send)
        elif kind == P.HEARTBEAT:
            pass
        elif kind == P.ERROR:
            if body["code"] == "unregistered":
                log.warning("master does not know this worker; registering again")
                send(self._hello())
            else:
                log.warning("master reports %s: %s", body["code"], body["message"])
        elif kind == P.REFUSE:
            log.error("master refused this worker: %s", body["message"])
            self.exit_code = 2
            return "refused"
        elif kind == P.BYE:
            (log.info if self.exit_with_master else log.warning)("master said BYE (%s)", body.get("reason", ""))
            return "bye"
        else:
            self._rl.warning("dropped", "dropped %s: not a message the master sends", kind)
        return None

    def _on_scene(self, body: dict, send) -> None:
        h = body["hash"]
        blob = body["blob"]
        if blob is None:
            blob = self._blobs.get(h)
            if blob is None:
                send(P.encode(P.ERROR, {"code": "scene_unavailable", "message": f"scene {h[:12]} not cached"}))
                return
        edits = body["edits"]
        version = body["base_version"] + len(edits)
        self._blobs[h] = blob
        self._blobs.move_to_end(h)
        while len(self._blobs) > self.cache_size:
            self._blobs.popitem(last=False)
        fut = self._scene_pool.submit(self._build_scene, h, blob, body["base_version"], edits)
        self._set_state(_SceneState(h, version, fut))

    def _build_scene(self, h: str, blob: bytes, base_version: int, edits: list):
        from igi.common.scene_codec import apply_edit, decode_scene

        t0 = time.perf_counter()
        scene = decode_scene(blob, expected_hash=h)
        for e in edits:
            scene = apply_edit(scene, e)
        renderer = self._make_renderer(scene, base_version + len(edits))
        settle_long_lived()  # the scene and its BVHs out of the frames' full collections
        log.info("scene %s… version %d ready in %.2f s", h[:12], base_version + len(edits),
                 time.perf_counter() - t0)
        return scene, renderer

    def _make_renderer(self, scene, version: int):
        if self._renderer_factory is not None:
            return self._renderer_factory(scene, version)
        from igi.worker.renderer import Renderer

        return Renderer(scene, scene_version=version)

    def _on_edit(self, body: dict, send) -> None:
        st = self._state
        if st is None or st.hash != body["hash"] or st.version != body["version"] - 1:
            send(P.encode(P.ERROR, {"code": "edit_out_of_order",
                                    "message": f"edit to version {body['version']} does not follow the scene held"}))
            return
        edit = body["edit"]

        def build(prev=st.future):
            from igi.common.scene_codec import apply_edit

            scene, _ = prev.result()
            new = apply_edit(scene, edit)
            return new, self._make_renderer(new, body["version"])
        self._set_state(_SceneState(st.hash, body["version"], self._scene_pool.submit(build)))

    def _set_state(self, st: _SceneState) -> None:
        self._prev_state, self._state = self._state, st

    def _renderer_for(self, h: str, version: int):
        for st in (self._state, self._prev_state):
            if st is not None and st.hash == h and st.version == version:
                return st.future.result()[1]
        return None

    def _on_task(self, body: dict, send, session: int) -> None:
        info = self._frames.get(body["frame"])
        if info is None:
            send(self._task_error(body, "unknown_frame", "no FRAME received for this task"))
            return
        with self._queued_lock:
            self._queued += 1
        fut = self._pool.submit(self._render, body, info[0], info[1], session)
        self._pending.add(fut)
        fut.add_done_callback(self._pending.discard)

    def _sets_to_send(self, renderer, session: int) -> list | None:
        """The renderer's cached (seed, k) sets when they differ from the list last sent on
        this connection (issue 19: RESULT.sets only on change), else None. Caller holds
        ``_sets_lock``."""
        cached = getattr(renderer, "cached_sets", None)
        if cached is None:
            return None
        # The list is only made when the renderer says its sets may have changed (sorting its
        # few hundred keys per task was ~1% of a worker's time at 320×240); a weak reference,
        # not id(): a new renderer may take a freed one's address.
        version = (session, weakref.ref(renderer), getattr(renderer, "sets_version", object()))
        if self._sets_version == version:
            return None
        self._sets_version = version
        sets = [[int(s), int(k)] for s, k in sorted(cached())][:4096]
        key = (session, id(renderer), sets)  # a new renderer (scene version) lists again
        if self._sets_sent == key:
            return None
        self._sets_sent = key
        return sets

    def _task_error(self, body: dict, code: str, message: str) -> bytes:
        return P.encode(P.ERROR, {"code": code, "message": message[:1024], "frame": body["frame"],
                                  "task": body["task"], "epoch": body["epoch"]})

    def _render(self, body: dict, spec, h: str, session: int) -> None:
        from igi.common.codec import encode

        try:
            t0 = time.perf_counter()
            renderer = self._renderer_for(h, spec.scene_version)
            if renderer is None:
                self._outbox.put((session, self._task_error(
                    body, "scene_mismatch", f"scene {h[:12]} version {spec.scene_version} not held")))
                return
            t1 = time.perf_counter()
            sx0, sy0, sx1, sy1 = body["tile"]
            tile = Tile(body["k"], sx0, sy0, sx1, sy1)
            built: dict = {}
            bufs = renderer.render_tile(spec, tile, built)
            t2 = time.perf_counter()
            data = encode(bufs)
            t3 = time.perf_counter()
            counters = getattr(getattr(renderer, "geom", None), "counters", None) or {}
            rays = int(sum(v for v in counters.values() if isinstance(v, int)))
            result = {"frame": body["frame"], "task": body["task"], "epoch": body["epoch"],
                      "count": len(bufs), "data": data, "rays": min(rays, P.INT53),
                      "timings": {"wait_scene": t1 - t0, "render": t2 - t1, "encode": t3 - t2, **built}}
            with self._sets_lock:  # the list goes out only when it changed, in outbox order
                sets = self._sets_to_send(renderer, session)
                if sets is not None:
                    result["sets"] = sets
                self._outbox.put((session, P.encode(P.RESULT, result, check=False)))
            self.tasks_done += 1
        except Exception as e:
            log.error("task %d of frame %d failed: %s", body["task"], body["frame"],
                      traceback.format_exc(limit=6))
            self._outbox.put((session, self._task_error(body, "task_failed", f"{type(e).__name__}: {e}")))
        finally:
            with self._queued_lock:
                self._queued -= 1
            self._wake()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--connect", default="tcp://127.0.0.1:5555",
                        help="master address (default: tcp://127.0.0.1:5555)")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                        help="render threads (default: one per core)")
    parser.add_argument("--credit", type=int, default=None,
                        help=f"tasks in flight granted to the master (default: {P.CREDIT_PER_THREAD} per thread)")
    parser.add_argument("--name", default=None, help="worker name shown by the master")
    parser.add_argument("--heartbeat", type=float, default=P.HEARTBEAT_INTERVAL, help=argparse.SUPPRESS)
    parser.add_argument("--exit-with-master", action="store_true",
                        help="exit when the master says BYE instead of waiting for it to come back")
    parser.add_argument("--parent-pid", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only")
    parser.add_argument("--curve-keys", default=os.environ.get("IGI_KEYS_DIR") or None, metavar="DIR",
                        help="CURVE authentication + encryption with the keys made by `igi keys DIR` "
                             "(default: $IGI_KEYS_DIR; none: plain TCP)")
    parser.add_argument("--key-name", default="worker", help="this worker's keypair in DIR (default: worker)")


def run_from_args(args: argparse.Namespace) -> int:
    if args.threads < 1:
        print("igi worker: --threads must be >= 1", file=sys.stderr)
        return 2
    configure = None
    if getattr(args, "curve_keys", None):
        try:
            configure = P.CurveClient(args.curve_keys, args.key_name)
        except (OSError, ValueError) as e:
            print(f"igi worker: CURVE keys: {e}", file=sys.stderr)
            return 2
    node = WorkerNode(args.connect, threads=args.threads, credit=args.credit, name=args.name,
                      heartbeat=args.heartbeat, exit_with_master=args.exit_with_master,
                      parent_pid=args.parent_pid, configure_socket=configure)

    def on_signal(signum, _frame):
        node.stop(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    from .kernels.warm import warm_up_before_hello  # compile / load every kernel before HELLO (issue 16)
    warm_up_before_hello(log)
    settle_long_lived()  # the kernels' objects out of later full collections
    reuse_freed_blocks()  # each task's buffers in reused heap, not fresh pages
    log.info("worker %s: %d render thread(s), connecting to %s", node.name, node.threads, node.connect)
    return node.run()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="igi worker", description="igi render worker")
    add_arguments(parser)
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO,
                        format="%(asctime)s %(name)s[%(process)d] %(levelname)s %(message)s")
    return run_from_args(args)


if __name__ == "__main__":
    sys.exit(main())
