"""Worker links: the master's ROUTER socket, who is connected, and the scene they hold.

Everything here runs on the broker's loop thread (``master/broker.py``).
Reliability (ZeroMQ guide, Paranoid Pirate over the data socket; ``common/protocol.py``):

- A worker registers with HELLO and gets WELCOME, then the scene (SCENE: the content-hashed
  blob only when the worker does not list the hash as cached, plus the edits on top of it).
  Workers already in step get EDITs naming the blob they were brought up from.
- Heartbeats: the master sends HEARTBEAT to a worker it has sent nothing else to for one
  interval; a worker silent for ``liveness`` intervals is expired. A send that ZeroMQ refuses
  (ROUTER_MANDATORY: the peer's connection is gone) expires it at once.
- Tasks of an expired, disconnected or departing (BYE) worker go back to the front of the queue
  (the frame loop's :meth:`reclaim`); a worker that says HELLO again loses its tasks as a fault.
- Garbage, oversize and invalid messages are dropped and counted, with rate-limited warnings
  (``common/ratelimit_log.py``); a peer speaking another protocol version gets a REFUSE naming
  both versions. With CURVE, denied peers are logged at INFO (``common/curve_log.py``).
- Per-worker fault accounting (issue 20): the :class:`scheduler.FaultLedger` lives here, with
  the workers; the frame loop reports the task faults to it.

RESULTs and task ERRORs go to the frame loop (:attr:`Links.tasks`, set by the broker), which
also owns every task a worker holds.
"""
from __future__ import annotations

import collections
import logging
import time
from dataclasses import dataclass, field
from typing import Callable

import zmq

from igi.common import protocol as P
from igi.common.ratelimit_log import RateLimitedLog

from . import scheduler
from .scene_state import SceneState

log = logging.getLogger("igi.master")

RECEIVE_BATCH = 256  # messages handled before timers and commands get their turn


@dataclass
class Worker:
    ident: bytes
    name: str
    host: str
    pid: int
    threads: int
    credit: int
    scenes: set
    last_seen: float
    last_sent: float = 0.0
    inflight: dict = field(default_factory=dict)  # (frame, task) -> epoch
    cached: set = field(default_factory=set)  # set keys (scene_version, seed, k)
    frames_sent: collections.OrderedDict = field(default_factory=collections.OrderedDict)
    scene_state: tuple | None = None  # (hash, version) the worker was brought to
    done: int = 0
    rays: int = 0  # last cumulative ray count reported
    busy_s: float = 0.0  # sum of reported render time
    # its recent reported set-build seconds (scheduler.TaskCost: task timeouts)
    set_builds: collections.deque = field(
        default_factory=lambda: collections.deque(maxlen=scheduler.TIMEOUT_WINDOW))
    joined: float = 0.0
    first_task_s: float | None = None  # HELLO -> first TASK sent (a joiner gets work within a second)

    def info(self, now: float) -> dict:
        return {"id": self.ident.decode("ascii", "replace"), "name": self.name, "host": self.host,
                "pid": self.pid, "threads": self.threads, "credit": self.credit,
                "inflight": len(self.inflight), "load": len(self.inflight) / self.credit,
                "tasks_done": self.done, "busy": self.busy_s / max(1e-9, now - self.joined) / self.threads,
                "first_task_s": self.first_task_s, "last_seen_s": now - self.last_seen}


class Links:
    """The ROUTER socket and the registered workers (see the module docstring)."""

    def __init__(self, scene: SceneState, *, bind: str, heartbeat: float, liveness: int,
                 context: zmq.Context, configure_socket: Callable[[zmq.Socket], None] | None):
        self.bind_address = bind
        self.heartbeat = float(heartbeat)
        self.liveness = int(liveness)
        self.scene = scene
        self._configure_socket = configure_socket  # e.g. CURVE server keys (issue 8), before bind
        self._ctx = context
        self.sock: zmq.Socket | None = None
        self.monitor = None  # CURVE handshake failures (common/curve_log.py)
        self.endpoint: str | None = None
        self.workers: dict[bytes, Worker] = {}
        self.departed: set[bytes] = set()  # told BYE by say_bye: what they still send is expected
        self.faults = scheduler.FaultLedger()
        self.counters = collections.Counter()
        self.rl = RateLimitedLog(log)  # one line per kind of junk per interval, counted
        self.tasks = None  # the frame loop: on_result, on_task_error, dispatch, reclaim, re_registered

    # ------------------------------------------------------------------ socket
    def open(self) -> None:
        """Create and bind the ROUTER socket (OSError when the address cannot be bound)."""
        sock = self._ctx.socket(zmq.ROUTER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.ROUTER_MANDATORY, 1)
        sock.setsockopt(zmq.ROUTER_HANDOVER, 1)
        sock.setsockopt(zmq.MAXMSGSIZE, P.MAX_MESSAGE_SIZE)
        sock.setsockopt(zmq.SNDHWM, 10000)
        sock.setsockopt(zmq.RCVHWM, 10000)
        if self._configure_socket is not None:
            self._configure_socket(sock)
        try:
            sock.bind(self.bind_address)
        except zmq.ZMQError as e:
            sock.close(0)
            raise OSError(f"cannot bind master to {self.bind_address}: {e}") from None
        self.sock = sock
        self.endpoint = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.monitor = _handshake_monitor(sock)

    def register(self, poller: zmq.Poller) -> None:
        poller.register(self.sock, zmq.POLLIN)
        if self.monitor is not None:
            poller.register(self.monitor.socket, zmq.POLLIN)

    def drain_monitor(self, events: dict) -> None:
        if self.monitor is not None and self.monitor.socket in events:
            self.monitor.drain()  # CURVE denials: INFO, rate-limited

    def close(self) -> None:
        if self.monitor is not None:
            self.monitor.close()
        self.sock.close(linger=500)  # let the BYEs of say_bye leave

    def receive(self, events: dict) -> bool:
        """Handle a bounded batch of incoming messages; False when the socket had none."""
        if self.sock not in events:
            return False
        for _ in range(RECEIVE_BATCH):
            try:
                parts = self.sock.recv_multipart(zmq.NOBLOCK, copy=True)
            except zmq.Again:
                break
            except zmq.ZMQError as e:  # pragma: no cover
                log.warning("receive failed: %s", e)
                break
            try:
                self.on_message(parts)
            except Exception:  # a bug must never take the master down
                self.counters["dropped"] += 1
                log.exception("dropped a message that raised in its handler")
        return True

    # ------------------------------------------------------------------ sending
    def send(self, w: Worker, frame: bytes, expire_on_fail: bool = True) -> bool:
        try:
            self.sock.send_multipart([w.ident, frame], zmq.NOBLOCK, copy=False)
        except zmq.ZMQError as e:
            if expire_on_fail and w.ident in self.workers:
                reason = "disconnected" if e.errno == zmq.EHOSTUNREACH else f"send failed ({e})"
                self.drop_worker(w, reason)
            return False
        w.last_sent = time.monotonic()
        return True

    def send_raw(self, ident: bytes, frame: bytes) -> None:
        try:
            self.sock.send_multipart([ident, frame], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass

    def say_bye(self) -> None:
        """BYE to every worker, and forget them (the master shuts down)."""
        bye = P.encode(P.BYE, {"reason": "master shutting down"})
        for w in list(self.workers.values()):
            self.send(w, bye, expire_on_fail=False)
        self.departed.update(self.workers)
        self.workers.clear()

    # ------------------------------------------------------------------ receiving
    def on_message(self, parts: list[bytes]) -> None:
        if len(parts) != 2:
            self._drop(parts[0] if parts else b"?", f"{len(parts) - 1} frames, expected 1")
            return
        ident, frame = parts
        try:
            msg = P.decode(frame)
        except P.VersionMismatch as e:
            self._refuse(ident, e)
            return
        except P.ProtocolError as e:
            self._drop(ident, str(e))
            return
        w = self.workers.get(ident)
        if w is not None:
            w.last_seen = time.monotonic()
        if msg.kind == P.HELLO:
            self._on_hello(ident, msg.body)
        elif w is None:
            self._from_stranger(ident, msg.kind)
        else:
            self._from_worker(w, msg.kind, msg.body)

    def _from_worker(self, w: Worker, kind: str, body: dict) -> None:
        if kind == P.RESULT:
            self.tasks.on_result(w, body)
        elif kind == P.HEARTBEAT:
            pass
        elif kind == P.ERROR:
            self._on_error(w, body)
        elif kind == P.BYE:
            self.drop_worker(w, f"said BYE ({body.get('reason', '')})")
        elif kind == P.REFUSE:
            self.drop_worker(w, f"refused us: {body['message']}")
        else:
            self._drop(w.ident, f"{kind} is not a message a worker sends")

    def _from_stranger(self, ident: bytes, kind: str) -> None:
        if kind in (P.BYE, P.REFUSE):
            return
        if ident in self.departed:  # a result or heartbeat that crossed our BYE: no fault of theirs
            self.counters["after_bye"] += 1
            return
        self._drop(ident, f"{kind} from an unregistered peer; asked it to send HELLO")
        self.send_raw(ident, P.encode(P.ERROR, {"code": "unregistered",
                                                "message": "unknown worker: send HELLO"}))

    def _refuse(self, ident: bytes, e: P.VersionMismatch) -> None:
        self.counters["refused"] += 1
        self.warn("refused", "refused peer %s: %s", _peer(ident), e)
        self.send_raw(ident, P.refusal(e.theirs))
        w = self.workers.get(ident)
        if w is not None:
            self.drop_worker(w, "protocol version mismatch")

    def _drop(self, ident: bytes, why: str) -> None:
        self.counters["dropped"] += 1
        self.warn("dropped", "dropped message from %s: %s", _peer(ident), why)

    def warn(self, kind: str, msg: str, *args) -> None:
        """A warning about what a peer did: rate-limited per kind, every one counted."""
        self.rl.warning(kind, msg, *args)

    def _on_hello(self, ident: bytes, body: dict) -> None:
        self.departed.discard(ident)
        old = self.workers.get(ident)
        if old is not None:
            self.tasks.re_registered(old)
            self.drop_worker(old, "said HELLO again", forget=False)
        now = time.monotonic()
        w = Worker(ident=ident, name=body["name"], host=body["host"], pid=body["pid"],
                   threads=body["threads"], credit=body["credit"], scenes=set(body["scenes"]),
                   last_seen=now, joined=now)
        self.workers[ident] = w
        log.info("worker %s joined (%s, pid %d, %d threads, credit %d)", w.name, w.host, w.pid,
                 w.threads, w.credit)
        if self.send(w, P.encode(P.WELCOME, {"worker": ident.decode("ascii", "replace")[:128],
                                             "heartbeat": self.heartbeat, "liveness": self.liveness})):
            self.send_scene(w)
        self.tasks.dispatch()

    def _on_error(self, w: Worker, body: dict) -> None:
        if "frame" in body and "task" in body and "epoch" in body:
            self.tasks.on_task_error(w, body)
            return
        if body["code"] == "scene_unavailable":
            w.scenes.discard(self.scene.hash)
            self.send_scene(w)
            return
        log.warning("worker %s reports %s: %s", w.name, body["code"], body["message"])

    # ------------------------------------------------------------------ liveness
    def keep_alive(self, now: float) -> None:
        """Expire the workers silent for ``liveness`` heartbeats; HEARTBEAT to the others that
        were sent nothing for about one interval."""
        hb = None
        for w in list(self.workers.values()):
            if now - w.last_seen > self.heartbeat * self.liveness:
                self.drop_worker(w, f"expired (silent for {now - w.last_seen:.1f} s)")
                continue
            if now - w.last_sent >= self.heartbeat * 0.9:
                hb = hb or P.encode(P.HEARTBEAT, {})
                self.send(w, hb)

    def drop_worker(self, w: Worker, reason: str, forget: bool = True) -> None:
        if self.workers.pop(w.ident, None) is None:
            return
        lost = self.tasks.reclaim(w)  # to other workers first; trusted ones if w never delivered
        if forget:
            self.faults.forget(w.ident)
        log.warning("worker %s left: %s; %d task(s) back to the front of the queue", w.name, reason, lost)
        self.tasks.dispatch()

    # ------------------------------------------------------------------ scene distribution
    def send_scene(self, w: Worker) -> None:
        """SCENE: the blob (unless the worker has it cached) and the edits since."""
        s = self.scene
        if s.hash is None:
            return
        cached = s.hash in w.scenes
        body = {"hash": s.hash, "blob": None if cached else s.blob,
                "base_version": s.base_version, "edits": list(s.edits)}
        if self.send(w, P.encode(P.SCENE, body, check=False)):
            w.scenes.add(s.hash)
            w.scene_state = (s.hash, s.base_version + len(s.edits))
            w.cached.clear()
            w.frames_sent.clear()
            if not cached:
                self.counters["scene_blobs_sent"] += 1

    def send_edit(self, w: Worker, edit: dict, version: int) -> None:
        """EDIT to a worker one version behind (on whatever blob it was brought up from: a
        fold changes the master's blob, not the workers'), else the whole SCENE."""
        st = w.scene_state
        if st is not None and st[1] == version - 1:
            if self.send(w, P.encode(P.EDIT, {"hash": st[0], "version": version, "edit": edit})):
                w.scene_state = (st[0], version)
        else:
            self.send_scene(w)

    def broadcast_scene(self) -> None:
        for w in list(self.workers.values()):
            self.send_scene(w)

    def broadcast_edit(self, edit: dict, version: int) -> None:
        for w in list(self.workers.values()):
            self.send_edit(w, edit, version)

    # ------------------------------------------------------------------ stats
    def infos(self, now: float) -> list[dict]:
        return [w.info(now) for w in self.workers.values()]

    def stats(self, now: float) -> dict:
        ws = self.workers.values()
        return {
            "workers": len(self.workers),
            "threads": sum(w.threads for w in ws),
            "inflight_tasks": sum(len(w.inflight) for w in ws),
            "messages_dropped": self.counters["dropped"],
            "refused": self.counters["refused"],
            "quarantined": [w.name for w in ws if self.faults.quarantined(w.ident)],
            "warnings_suppressed": sum(self.rl.counts.values()) - sum(self.rl.written.values()),
            "per_worker": self.infos(now),
        }


def _handshake_monitor(sock: zmq.Socket):
    """A CURVE server socket's handshake-failure monitor (common/curve_log.py), else None."""
    try:
        if not sock.getsockopt(zmq.CURVE_SERVER):
            return None
        from igi.common.curve_log import HandshakeMonitor

        return HandshakeMonitor(sock)
    except zmq.ZMQError:  # pragma: no cover - monitoring unsupported
        return None


def _peer(ident: bytes) -> str:
    try:
        s = ident.decode("ascii")
        if s.isprintable():
            return s[:64]
    except UnicodeDecodeError:
        pass
    return "0x" + ident[:16].hex()
