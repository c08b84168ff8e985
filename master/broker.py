"""The master: a ZeroMQ ROUTER that hands tasks to workers and assembles their results.

Threads
-------
One *loop thread* owns the ROUTER socket and every piece of scheduling state (workers, task
queue, open frames). Public methods, callable from any thread, post small closures to it
through a queue and a wake-up socketpair, and wait on a Future where they need an answer.
Filtering and accumulation never run on the loop thread: ``render_frame`` callers filter in
their own thread, streaming frames are filtered by a *finisher* thread — so heartbeats and
dispatch keep flowing while the master merges.

Reliability (ZeroMQ guide, Paranoid Pirate over the data socket; ``common/protocol.py``)
------------------------------------------------------------------------------------------
- A worker registers with HELLO and gets WELCOME, then the scene (SCENE: the content-hashed
  blob only when the worker does not list the hash as cached, plus the edits on top of it).
- Heartbeats: the master sends HEARTBEAT to a worker it has sent nothing else to for one
  interval (default 1 s); a worker silent for ``liveness`` (3) intervals is expired. A send
  that ZeroMQ refuses (ROUTER_MANDATORY: the peer's connection is gone) expires it at once.
- Tasks of an expired, disconnected or departing (BYE) worker go back to the FRONT of the
  queue. Every assignment has a fresh epoch; a RESULT counts only for the task's current epoch
  and the worker it was given to, in an open frame — stale and duplicate results are dropped.
- Garbage, oversize and invalid messages are dropped and counted, with rate-limited warnings
  (``common/ratelimit_log.py``: one line per kind per 10 s, the next one carries the count of
  those not shown); a peer speaking another protocol version gets a REFUSE naming both
  versions. Nothing a peer sends can raise out of the loop. With CURVE, denied peers are
  logged at INFO (``common/curve_log.py``).
- Credit-based flow control and task choice come from the pure policy in
  ``master/scheduler.py`` (set-aware since issue 19), over the whole queue.
- Per-worker fault accounting (issue 20, ``scheduler.FaultLedger``): a worker's effective
  credit starts at 2 and grows with the results it delivers (a worker advertising 4,096 slots
  that never answers holds 2 tasks); a task that failed or timed out on a worker goes to
  another worker first; a worker with 3 consecutive task faults is quarantined (logged once,
  with the reason; it stays connected but gets no tasks). Task timeouts follow the measured
  task times (``scheduler.task_timeout``: max(8 × median, 2 s), at most ``task_timeout``).
- Scene edits are folded into a new content-hashed blob every :data:`FOLD_EDITS` edits, so the
  SCENE a joining worker gets never carries more than that many edits (issue 20); workers
  already in step keep their blob and get EDITs naming it.

API (thread-safe)
-----------------
    Broker(scene=None, bind="tcp://127.0.0.1:5555", heartbeat=1.0, liveness=3, task_pixels=4096,
           pipeline=3, task_timeout=60, configure_socket=None)   # configure_socket(sock): before bind
    .start() -> Broker / .stop() / context manager; .endpoint (the bound address)
    .set_scene(scene) / .apply_edit(edit) -> version / .scene / .scene_version
    .submit_frame(spec) -> Future[FrameResult];  .render_frame(spec) -> FrameResult
    .render_sequence(params, frames, camera, width, height, on_frame) -> image (= render_local)
    .frame_spec(index, params=None, ...) -> FrameSpec of the current view
    streaming (viewer): .start_stream() / .stop_stream() / .set_camera(to_world, fov_x)
        / .set_resolution(w, h) / .set_params(**overrides) / .latest_frame() -> StreamFrame
        / .wait_frame(after_seq, timeout) / .add_frame_listener(cb) / .reset_accumulation()
    .stats() -> dict;  .workers() -> list[dict];  .wait_for_workers(n, timeout) -> bool
"""
from __future__ import annotations

import collections
import concurrent.futures as cf
import dataclasses
import logging
import queue
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import zmq

from common import protocol as P
from common.frame import FrameSpec, Tile, accumulation_index
from common.params import make_params, params_to_dict
from common.ratelimit_log import RateLimitedLog
from common.scene import Scene

from . import scheduler
from .accumulation import Accumulator, accumulation_key, sequence_spec
from .frame_assembly import DEFAULT_TASK_PIXELS, FrameAssembler, task_tiles, tile_pixel_count

log = logging.getLogger("igi.master")

DEFAULT_BIND = "tcp://127.0.0.1:5555"
MAX_TASK_FAILURES = 3  # a task that fails this often fails its frame
FOLD_EDITS = 64  # edits on top of the scene blob before they are folded into a new blob (issue 20)
LATENCY_WINDOW = 2000  # task latencies kept for the stats


class FrameCancelled(Exception):
    """The frame was dropped before completion (scene edit, new camera in streaming, stop)."""


class FrameFailed(RuntimeError):
    """A task of the frame failed on the workers repeatedly."""


@dataclass
class FrameResult:
    """A completed frame: its spec and the assembled full-frame buffers (not yet filtered)."""

    spec: FrameSpec
    assembler: FrameAssembler
    bytes: int  # wire bytes of the accepted RESULT payloads
    tasks: int
    started: float  # time.monotonic() at submission
    finished: float

    @property
    def buffers(self) -> dict[str, np.ndarray]:
        return self.assembler.buffers

    def image(self) -> np.ndarray:
        """Filtered + composed image (discontinuity buffer), computed in the caller's thread."""
        return self.assembler.image(self.spec.params, accumulation_index(self.spec))


@dataclass
class StreamFrame:
    """What the viewer shows: the accumulated image of the current view."""

    seq: int  # increases with every published frame
    image: np.ndarray  # (H, W, 3) float32 linear radiance, the accumulated mean
    frame_image: np.ndarray  # the last frame alone (filtered)
    accumulated: int  # frames in the mean
    spec: FrameSpec
    relative_error: float | None  # even/odd halves estimate (None before 2 frames)
    time: float  # time.monotonic() when published
    generation: int = 0  # bumps with every change of view / params / scene
    view_time: float = 0.0  # time.monotonic() of that change: time - view_time = input-to-photon latency


@dataclass
class _Worker:
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
    joined: float = 0.0
    first_task_s: float | None = None  # HELLO -> first TASK sent (a joiner gets work within a second)


@dataclass
class _Task:
    frame: int
    task: int
    tile: Tile
    set_key: tuple
    epoch: int = 0
    worker: bytes | None = None
    sent: float = 0.0
    failures: int = 0
    avoid: frozenset = frozenset()  # workers this task failed or timed out on (issue 20)
    trusted_only: bool = False  # lost by a worker that never delivered: to trusted workers first
    pending: Any = None  # its scheduler.PendingTask (rebuilt when ``avoid`` changes)

    def as_pending(self, key) -> scheduler.PendingTask:
        if self.pending is None:
            self.pending = scheduler.PendingTask(key, self.set_key, self.avoid, self.trusted_only)
        return self.pending

    def avoid_worker(self, ident: bytes) -> None:
        self.avoid = self.avoid | {ident}
        self.pending = None

    def lost_by(self, ident: bytes, trusted: bool) -> None:
        """The worker ``ident`` gave this task back without a result (left, timed out, failed)."""
        self.avoid_worker(ident)
        if not trusted:
            self.trusted_only = True


@dataclass
class _Frame:
    spec: FrameSpec
    assembler: FrameAssembler
    future: cf.Future
    tasks: dict  # task id -> _Task (open tasks only)
    total: int
    started: float
    bytes: int = 0
    stream_gen: int | None = None  # generation of the stream view, None for one-shot frames


class Broker:
    """The master (see the module docstring)."""

    def __init__(self, scene: Scene | None = None, bind: str = DEFAULT_BIND, *,
                 heartbeat: float = P.HEARTBEAT_INTERVAL, liveness: int = P.HEARTBEAT_LIVENESS,
                 task_pixels: int = DEFAULT_TASK_PIXELS, pipeline: int = 3,
                 task_timeout: float = 60.0, context: zmq.Context | None = None,
                 configure_socket: Callable[[zmq.Socket], None] | None = None):
        self.bind_address = bind
        self.heartbeat = float(heartbeat)
        self.liveness = int(liveness)
        self.task_pixels = int(task_pixels)
        self.pipeline = max(1, int(pipeline))
        self.task_timeout = float(task_timeout)
        self._configure_socket = configure_socket  # e.g. CURVE server keys (issue 8), before bind
        self._ctx = context or zmq.Context.instance()
        self._sock: zmq.Socket | None = None
        self._monitor = None  # CURVE handshake failures (common/curve_log.py)
        self.endpoint: str | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._closed = False
        self._stop_lock = threading.Lock()
        self._cmds: queue.SimpleQueue = queue.SimpleQueue()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_lock = threading.Lock()
        self._lock = threading.Lock()  # guards the small shared snapshots below

        # loop-thread state
        self._workers: dict[bytes, _Worker] = {}
        self._queue: collections.deque = collections.deque()  # (frame, task) keys, front first
        self._frames: collections.OrderedDict[int, _Frame] = collections.OrderedDict()
        self._epoch = 0
        self._next_frame = 0
        self._latencies: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._render_times: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._encode_times: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._merge_times: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)  # decode + scatter
        self._task_bytes: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._counters = collections.Counter()
        self._faults = scheduler.FaultLedger()  # per-worker fault accounting (issue 20)
        self._rl = RateLimitedLog(log)  # one line per kind of junk per interval, counted
        self._result_times: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)  # _on_result
        self._dispatch_times: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._frame_times: collections.deque = collections.deque(maxlen=64)  # completion times
        self._frame_bytes: collections.deque = collections.deque(maxlen=64)
        self._rays: collections.deque = collections.deque(maxlen=4096)  # (time, rays traced)

        # scene state (written by the loop thread, read under _lock)
        self._scene: Scene | None = None
        self._scene_hash: str | None = None
        self._scene_blob: bytes | None = None
        self._base_version = 0
        self._edits: list[dict] = []

        # streaming state
        self._stream_on = False
        self._stream_gen = 0
        self._gen_time = time.monotonic()
        self._stream_index = 0
        self._view: dict[str, Any] = {}
        self._finisher_q: queue.SimpleQueue = queue.SimpleQueue()
        self._finisher: threading.Thread | None = None
        self._acc = Accumulator()
        self._latest: StreamFrame | None = None
        self._latest_cond = threading.Condition()
        self._seq = 0
        self._listeners: list[Callable[[StreamFrame], object]] = []
        self._stream_held: dict[int, FrameResult] = {}  # stream frames completed out of order

        if scene is not None:
            self._install_scene(scene)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> "Broker":
        if self._thread is not None:
            return self
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
        self._sock = sock
        self.endpoint = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self._monitor = _handshake_monitor(sock)
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="igi-master-loop", daemon=True)
        self._thread.start()
        self._finisher = threading.Thread(target=self._finish_loop, name="igi-master-finish", daemon=True)
        self._finisher.start()
        log.info("master listening on %s (protocol %d)", self.endpoint, P.PROTOCOL_VERSION)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Say BYE to every worker, cancel open frames and close the socket (idempotent,
        callable from any thread)."""
        with self._stop_lock:
            if self._thread is None or self._closed:
                return
            self._stream_on = False
            try:
                self._call(self._shutdown, timeout=timeout)
            except Exception:  # pragma: no cover - loop already gone
                pass
            self._closed = True
            self._running = False
            self._wake()
            self._thread.join(timeout)
            self._finisher_q.put(None)
            if self._finisher is not None:
                self._finisher.join(timeout)
            if not self._thread.is_alive():
                for s in (self._wake_r, self._wake_w):
                    s.close()

    def __enter__(self) -> "Broker":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ cross-thread plumbing
    def _wake(self) -> None:
        with self._wake_lock:
            try:
                self._wake_w.send(b"\0")
            except (BlockingIOError, OSError):
                pass

    def _post(self, fn: Callable[[], Any]) -> cf.Future:
        fut: cf.Future = cf.Future()
        if self._closed:
            fut.set_exception(FrameCancelled("master stopped"))
            return fut
        if self._thread is None or not self._running:
            # Not started: run inline (single-threaded use before start()).
            try:
                fut.set_result(fn())
            except BaseException as e:
                fut.set_exception(e)
            return fut
        self._cmds.put((fn, fut))
        self._wake()
        return fut

    def _call(self, fn: Callable[[], Any], timeout: float | None = 30.0) -> Any:
        return self._post(fn).result(timeout)

    # ------------------------------------------------------------------ scene
    @property
    def scene(self) -> Scene | None:
        with self._lock:
            return self._scene

    @property
    def scene_version(self) -> int:
        with self._lock:
            return self._base_version + len(self._edits)

    @property
    def scene_hash(self) -> str | None:
        with self._lock:
            return self._scene_hash

    def set_scene(self, scene: Scene) -> int:
        """Load a new scene (new blob, new version); open frames are cancelled. Returns the version."""
        from common.scene_codec import encode_scene, scene_hash

        blob = encode_scene(scene)  # encode outside the loop thread: may take a while
        h = scene_hash(blob)
        return self._call(lambda: self._install_scene(scene, blob, h))

    def apply_edit(self, edit: dict) -> int:
        """Apply a scene edit (``common.scene_codec`` delta) on the master and every worker.
        Raises ValueError for an invalid edit. Returns the new scene version.

        Every :data:`FOLD_EDITS` edits the edited scene becomes the new content-hashed blob
        (encoded here, in the caller's thread): a worker that joins later gets that blob and
        the few edits since, never an ever-growing log (issue 20). Workers already in step
        keep their blob and get the edits one by one, as before."""
        from common.scene_codec import apply_edit

        P.validate(P.EDIT, {"hash": "0" * 64, "version": 1, "edit": edit})  # wire shape
        version, fold = self._call(lambda: self._apply_edit(edit, apply_edit))
        if fold is not None:
            self._fold_edits(*fold)
        return version

    def _fold_edits(self, scene: Scene, version: int, base_hash: str) -> None:
        from common.scene_codec import encode_scene, scene_hash

        blob = encode_scene(scene)
        h = scene_hash(blob)
        self._call(lambda: self._install_fold(scene, version, base_hash, blob, h))

    def _install_fold(self, scene: Scene, version: int, base_hash: str, blob: bytes, h: str) -> None:
        """Loop thread: ``blob`` (hash ``h``) is the scene at ``version``; it becomes the base
        that SCENE messages send, with the edits made since. Skipped when the scene was
        replaced meanwhile."""
        if self._scene_hash != base_hash or not self._base_version <= version <= self.scene_version:
            return
        with self._lock:
            self._edits = self._edits[version - self._base_version:]
            self._base_version = version
            self._scene_blob, self._scene_hash = blob, h
        self._counters["scene_folds"] += 1
        log.info("scene edits folded: version %d is scene %s… (%d bytes)", version, h[:12], len(blob))

    def _install_scene(self, scene: Scene, blob: bytes | None = None, h: str | None = None) -> int:
        from common.scene_codec import encode_scene, scene_hash

        if blob is None:
            blob = encode_scene(scene)
            h = scene_hash(blob)
        with self._lock:
            first = self._scene is None
            self._base_version = 0 if first else self._base_version + len(self._edits) + 1
            self._edits = []
            self._scene, self._scene_blob, self._scene_hash = scene, blob, h
            version = self._base_version
        self._cancel_frames(lambda f: True, FrameCancelled("scene replaced"))
        for w in list(self._workers.values()):
            self._send_scene(w)
        self._stream_changed(reset_index=True)
        log.info("scene %s… version %d (%d bytes, %d triangles)", h[:12], version, len(blob),
                 scene.triangle_count)
        return version

    def _apply_edit(self, edit: dict, apply_fn) -> tuple:
        """Loop thread: (new version, None or (scene, version, hash) to fold into a blob)."""
        if self._scene is None:
            raise ValueError("no scene loaded")
        new_scene = apply_fn(self._scene, edit)  # ValueError on a bad edit
        with self._lock:
            self._scene = new_scene
            self._edits.append(edit)
            version = self._base_version + len(self._edits)
        self._cancel_frames(lambda f: f.spec.scene_version != version, FrameCancelled("scene edited"))
        for w in list(self._workers.values()):
            self._send_edit(w, edit, version)
        self._stream_changed(reset_index=True)
        fold = (new_scene, version, self._scene_hash) if len(self._edits) >= FOLD_EDITS else None
        return version, fold

    def _send_edit(self, w: _Worker, edit: dict, version: int) -> None:
        """EDIT to a worker one version behind (on whatever blob it was brought up from: a
        fold changes the master's blob, not the workers'), else the whole SCENE."""
        st = w.scene_state
        if st is not None and st[1] == version - 1:
            if self._send(w, P.encode(P.EDIT, {"hash": st[0], "version": version, "edit": edit})):
                w.scene_state = (st[0], version)
        else:
            self._send_scene(w)

    def _send_scene(self, w: _Worker) -> None:
        if self._scene_hash is None:
            return
        cached = self._scene_hash in w.scenes
        body = {"hash": self._scene_hash, "blob": None if cached else self._scene_blob,
                "base_version": self._base_version, "edits": list(self._edits)}
        if self._send(w, P.encode(P.SCENE, body, check=False)):
            w.scenes.add(self._scene_hash)
            w.scene_state = (self._scene_hash, self._base_version + len(self._edits))
            w.cached.clear()
            w.frames_sent.clear()
            if not cached:
                self._counters["scene_blobs_sent"] += 1

    # ------------------------------------------------------------------ one-shot frames
    def frame_spec(self, index: int = 0, params=None, camera=None, width: int | None = None,
                   height: int | None = None, frame: int | None = None) -> FrameSpec:
        """FrameSpec of the current scene version: accumulation index ``index``; camera and
        resolution from the scene unless given (see ``common.camera.resolve_camera``)."""
        from common.camera import resolve_camera

        scene = self.scene
        if scene is None:
            raise ValueError("no scene loaded")
        pdict = _params_dict(params)
        cam, fov_x, w, h = resolve_camera(scene, camera, width, height)
        return sequence_spec(self._alloc_frame() if frame is None else frame, index, cam, fov_x, w, h,
                             pdict, self.scene_version)

    def _alloc_frame(self) -> int:
        with self._lock:
            f = self._next_frame
            self._next_frame += 1
            return f

    def submit_frame(self, spec: FrameSpec) -> cf.Future:
        """Queue a frame; the Future resolves to a FrameResult (or FrameCancelled/FrameFailed)."""
        out: cf.Future = cf.Future()

        def failed(posted: cf.Future) -> None:  # e.g. the master stopped: never leave `out` pending
            if posted.exception() is not None and not out.done():
                out.set_exception(posted.exception())
        self._post(lambda: self._open_frame(spec, out, None)).add_done_callback(failed)
        return out

    def render_frame(self, spec: FrameSpec, timeout: float | None = None) -> FrameResult:
        return self.submit_frame(spec).result(timeout)

    def render_sequence(self, params=None, frames: int = 1, camera=None, width: int | None = None,
                        height: int | None = None,
                        on_frame: Callable[[int, np.ndarray], object] | None = None,
                        timeout: float | None = None) -> np.ndarray:
        """Same contract as ``master.inprocess.render_local`` (same specs, tiles, filter and
        accumulation), rendered by the workers with ``pipeline`` frames in flight."""
        pdict = _params_dict(params)
        frames = max(1, int(frames))
        specs = [self.frame_spec(i, pdict, camera, width, height) for i in range(frames)]
        acc = Accumulator()
        futures: collections.deque = collections.deque()
        nxt = 0
        image = None
        for i in range(frames):
            while nxt < frames and len(futures) < self.pipeline:
                futures.append(self.submit_frame(specs[nxt]))
                nxt += 1
            res = futures.popleft().result(timeout)
            acc.add(res.image(), accumulation_key(res.spec))
            image = acc.mean()
            if on_frame is not None:
                on_frame(i, image)
        return image

    def _open_frame(self, spec: FrameSpec, fut: cf.Future, stream_gen: int | None) -> None:
        if not fut.set_running_or_notify_cancel():
            return
        try:
            if self._scene_hash is None:
                raise ValueError("no scene loaded")
            if spec.scene_version != self._base_version + len(self._edits):
                raise FrameCancelled(f"frame {spec.frame} is for scene version {spec.scene_version}, "
                                     f"current is {self._base_version + len(self._edits)}")
            if spec.frame in self._frames:
                raise ValueError(f"frame {spec.frame} is already open")
            P.validate(P.FRAME, P.frame_body(spec, self._scene_hash))
        except Exception as e:
            fut.set_exception(e)
            return
        n = int(spec.params["interleave"])
        tiles = task_tiles(spec.width, spec.height, n, self.task_pixels)
        tasks = {}
        for i, t in enumerate(tiles):
            tasks[i] = _Task(spec.frame, i, t, (spec.scene_version, spec.seed, t.k))
            self._queue.append((spec.frame, i))
        self._frames[spec.frame] = _Frame(spec, FrameAssembler(spec.width, spec.height, n), fut,
                                          tasks, len(tiles), time.monotonic(), stream_gen=stream_gen)
        self._dispatch()

    def _cancel_frames(self, pred: Callable[[_Frame], bool], exc: Exception) -> None:
        gone = [num for num, f in self._frames.items() if pred(f)]
        if not gone:
            return
        for num in gone:
            f = self._frames.pop(num)
            if not f.future.done():
                f.future.set_exception(exc)
        gone_set = set(gone)
        self._queue = collections.deque(k for k in self._queue if k[0] not in gone_set)

    # ------------------------------------------------------------------ streaming (viewer API)
    def start_stream(self, params=None, camera=None, width: int | None = None,
                     height: int | None = None) -> None:
        """Render frames continuously for the viewer: progressive accumulation while nothing
        changes; any change of camera / params / resolution / scene resets it."""
        from common.camera import resolve_camera

        scene = self.scene
        if scene is None:
            raise ValueError("no scene loaded")
        cam, fov_x, w, h = resolve_camera(scene, camera, width, height)
        view = {"camera": cam, "fov_x": fov_x, "width": w, "height": h, "params": _params_dict(params)}

        def go():
            self._view = view
            self._stream_on = True
            self._stream_changed(reset_index=True)
        self._call(go)

    def stop_stream(self) -> None:
        def go():
            self._stream_on = False
            self._cancel_frames(lambda f: f.stream_gen is not None, FrameCancelled("stream stopped"))
        self._call(go)

    def set_camera(self, camera_to_world, fov_x: float | None = None) -> None:
        """New view matrix (4×4 or 16 floats, Mitsuba camera-to-world) and optional fov_x."""
        cam = tuple(float(x) for x in np.asarray(camera_to_world, np.float64).reshape(16))
        if not all(np.isfinite(cam)) or (fov_x is not None and not 0 < float(fov_x) < 180):
            raise ValueError("camera must be finite and 0 < fov_x < 180")
        self._update_view(camera=cam, **({} if fov_x is None else {"fov_x": float(fov_x)}))

    def set_resolution(self, width: int, height: int) -> None:
        if not (1 <= int(width) <= P.MAX_IMAGE_SIDE and 1 <= int(height) <= P.MAX_IMAGE_SIDE):
            raise ValueError(f"resolution {width}x{height} out of range")
        self._update_view(width=int(width), height=int(height))

    def set_params(self, params=None, **overrides) -> dict:
        """Replace (``params``) and/or override render parameters of the stream; returns them."""
        base = _params_dict(params) if params is not None else dict(self._view.get("params") or _params_dict(None))
        base.update(overrides)
        pdict = params_to_dict(make_params(**base))  # ValueError on a bad value
        self._update_view(params=pdict)
        return pdict

    def view(self) -> dict:
        """The stream's current camera, fov_x, width, height and params."""
        return dict(self._view)

    def reset_accumulation(self) -> None:
        self._call(lambda: self._stream_changed(reset_index=True))

    def _update_view(self, **changes) -> None:
        def go():
            if not self._view:
                raise ValueError("the stream was not started")
            self._view = {**self._view, **changes}
            self._stream_changed(reset_index=True)
        self._call(go)

    def _stream_changed(self, reset_index: bool) -> None:
        """Loop thread: the view changed — drop outdated stream frames, start over."""
        if reset_index:
            self._stream_gen += 1
            self._stream_index = 0
            self._gen_time = time.monotonic()
        gen = self._stream_gen
        self._cancel_frames(lambda f: f.stream_gen is not None and f.stream_gen != gen,
                            FrameCancelled("view changed"))
        if reset_index:
            self._stream_held = {}
        self._fill_stream()

    def _fill_stream(self) -> None:
        """Loop thread: keep ``pipeline`` stream frames open."""
        if not self._stream_on or not self._view or self._scene_hash is None:
            return
        gen = self._stream_gen
        open_stream = sum(1 for f in self._frames.values() if f.stream_gen == gen)
        v = self._view
        while open_stream < self.pipeline:
            spec = sequence_spec(self._alloc_frame(), self._stream_index, v["camera"], v["fov_x"],
                                 v["width"], v["height"], v["params"], self._base_version + len(self._edits))
            self._stream_index += 1
            fut: cf.Future = cf.Future()
            fut.add_done_callback(lambda f, g=gen: self._stream_frame_done(f, g))
            self._open_frame(spec, fut, gen)
            if fut.done() and fut.exception() is not None:
                log.warning("stream frame not started: %s", fut.exception())
                self._stream_on = False
                return
            open_stream += 1

    def _stream_frame_done(self, fut: cf.Future, gen: int) -> None:
        """Loop thread (future callback): hand completed stream frames to the finisher, in
        frame order — a frame goes once no older frame of its view is still open."""
        if fut.cancelled() or fut.exception() is not None or gen != self._stream_gen:
            return
        res = fut.result()
        self._stream_held[res.spec.frame] = res
        while self._stream_held:
            first = min(self._stream_held)
            if any(num < first and f.stream_gen == gen for num, f in self._frames.items()):
                break
            self._finisher_q.put((gen, self._stream_held.pop(first)))

    def _finish_loop(self) -> None:
        """Finisher thread: filter, accumulate and publish stream frames."""
        while True:
            item = self._finisher_q.get()
            if item is None:
                return
            gen, res = item
            if gen != self._stream_gen:
                continue  # outdated view
            try:
                self._publish(res, gen)
            except Exception:  # pragma: no cover - a bug in filtering must not kill the thread
                log.exception("publishing frame %d failed", res.spec.frame)

    def _publish(self, res: FrameResult, gen: int) -> None:
        img = res.image()
        if gen != self._stream_gen:
            return
        count = self._acc.add(img, (gen, accumulation_key(res.spec)))
        with self._latest_cond:
            self._seq += 1
            sf = StreamFrame(seq=self._seq, image=self._acc.mean(), frame_image=img, accumulated=count,
                             spec=res.spec, relative_error=self._acc.relative_error(),
                             time=time.monotonic(), generation=gen, view_time=self._gen_time)
            self._latest = sf
            self._latest_cond.notify_all()
        for cb in list(self._listeners):
            try:
                cb(sf)
            except Exception:
                log.exception("frame listener failed")

    def latest_frame(self) -> StreamFrame | None:
        with self._latest_cond:
            return self._latest

    def wait_frame(self, after_seq: int = 0, timeout: float | None = None) -> StreamFrame | None:
        """The first published frame with seq > ``after_seq`` (None on timeout)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._latest_cond:
            while self._latest is None or self._latest.seq <= after_seq:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._latest_cond.wait(remaining)
            return self._latest

    def add_frame_listener(self, callback: Callable[[StreamFrame], object]) -> None:
        """``callback(StreamFrame)`` after every published stream frame (finisher thread)."""
        self._listeners.append(callback)

    def remove_frame_listener(self, callback) -> None:
        if callback in self._listeners:
            self._listeners.remove(callback)

    # ------------------------------------------------------------------ stats
    def stats(self) -> dict:
        """Counters and rates for the viewer overlay and the benchmarks."""
        return self._call(self._stats)

    def _stats(self) -> dict:
        now = time.monotonic()
        ft = list(self._frame_times)
        fps = (len(ft) - 1) / (ft[-1] - ft[0]) if len(ft) >= 2 and ft[-1] > ft[0] else 0.0
        lat = np.array(self._latencies) if self._latencies else None
        recent = [(t, r) for t, r in self._rays if now - t <= 5.0]
        span = (now - recent[0][0]) if len(recent) >= 2 else 0.0
        rays_per_s = sum(r for _, r in recent[1:]) / span if span > 0 else 0.0
        latest = self._latest
        return {
            "workers": len(self._workers),
            "threads": sum(w.threads for w in self._workers.values()),
            "fps": fps,
            "rays_per_s": rays_per_s,
            "frames_completed": self._counters["frames"],
            "open_frames": len(self._frames),
            "queued_tasks": len(self._queue),
            "inflight_tasks": sum(len(w.inflight) for w in self._workers.values()),
            "tasks_done": self._counters["tasks_done"],
            "tasks_requeued": self._counters["tasks_requeued"],
            "results_stale": self._counters["results_stale"],
            "messages_dropped": self._counters["dropped"],
            "refused": self._counters["refused"],
            "scene_blobs_sent": self._counters["scene_blobs_sent"],
            "scene_folds": self._counters["scene_folds"],
            "bytes_per_frame": float(np.mean(self._frame_bytes)) if self._frame_bytes else 0.0,
            "task_latency_ms": None if lat is None else {
                "mean": float(lat.mean() * 1e3), "p50": float(np.percentile(lat, 50) * 1e3),
                "p95": float(np.percentile(lat, 95) * 1e3)},
            "task_render_ms": float(np.mean(self._render_times) * 1e3) if self._render_times else None,
            "task_encode_ms": float(np.mean(self._encode_times) * 1e3) if self._encode_times else None,
            "task_merge_ms": float(np.mean(self._merge_times) * 1e3) if self._merge_times else None,
            "task_bytes": float(np.mean(self._task_bytes)) if self._task_bytes else None,
            # the loop thread's cost per RESULT (issue 19): handling it (decode excluded) and
            # one dispatch round, in µs
            "result_handle_us": _us_stats(self._result_times),
            "dispatch_us": _us_stats(self._dispatch_times),
            "task_timeout_s": self.current_task_timeout(),
            "quarantined": [w.name for w in self._workers.values() if self._faults.quarantined(w.ident)],
            "warnings_suppressed": sum(self._rl.counts.values()) - sum(self._rl.written.values()),
            "accumulated": latest.accumulated if latest else 0,
            "relative_error": latest.relative_error if latest else None,
            "scene_version": self._base_version + len(self._edits),
            "per_worker": [self._worker_info(w, now) for w in self._workers.values()],
        }

    def _worker_info(self, w: _Worker, now: float) -> dict:
        return {"id": w.ident.decode("ascii", "replace"), "name": w.name, "host": w.host, "pid": w.pid,
                "threads": w.threads, "credit": w.credit, "inflight": len(w.inflight),
                "load": len(w.inflight) / w.credit, "tasks_done": w.done,
                "busy": w.busy_s / max(1e-9, now - w.joined) / w.threads,
                "first_task_s": w.first_task_s,
                "last_seen_s": now - w.last_seen}

    def workers(self) -> list[dict]:
        return self._call(lambda: [self._worker_info(w, time.monotonic()) for w in self._workers.values()])

    def wait_for_workers(self, count: int, timeout: float = 30.0) -> bool:
        """Block until at least ``count`` workers are registered (False on timeout)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._call(lambda: len(self._workers)) >= count:
                return True
            time.sleep(0.05)
        return False

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._wake_r.fileno(), zmq.POLLIN)
        if self._monitor is not None:
            poller.register(self._monitor.socket, zmq.POLLIN)
        self._next_tick = time.monotonic() + self.heartbeat
        while self._running:
            timeout_ms = max(0, int((self._next_tick - time.monotonic()) * 1000))
            try:
                events = dict(poller.poll(timeout_ms))
            except zmq.ZMQError as e:  # pragma: no cover - interrupted
                log.debug("poll: %s", e)
                continue
            if self._wake_r.fileno() in events:
                try:
                    while self._wake_r.recv(4096):
                        pass
                except (BlockingIOError, OSError):
                    pass
            if self._monitor is not None and self._monitor.socket in events:
                self._monitor.drain()  # CURVE denials: INFO, rate-limited
            try:
                self._run_commands()
                self._service(events)
            except Exception:  # a bug must never take the master down
                log.exception("master loop error (continuing)")
        if self._monitor is not None:
            self._monitor.close()
        self._sock.close(linger=500)  # let the BYEs of _shutdown leave

    def _service(self, events: dict) -> None:
        if self._sock in events:
            for _ in range(256):  # bounded batch, then service timers and commands
                try:
                    parts = self._sock.recv_multipart(zmq.NOBLOCK, copy=True)
                except zmq.Again:
                    break
                except zmq.ZMQError as e:  # pragma: no cover
                    log.warning("receive failed: %s", e)
                    break
                try:
                    self._on_message(parts)
                except Exception:  # a bug must never take the master down
                    self._counters["dropped"] += 1
                    log.exception("dropped a message that raised in its handler")
            self._dispatch()
        now = time.monotonic()
        if now >= self._next_tick:
            self._next_tick = now + self.heartbeat
            self._tick(now)

    def _run_commands(self) -> None:
        while True:
            try:
                fn, fut = self._cmds.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn())
            except BaseException as e:
                fut.set_exception(e)

    def _shutdown(self) -> None:
        bye = P.encode(P.BYE, {"reason": "master shutting down"})
        for w in list(self._workers.values()):
            self._send(w, bye, expire_on_fail=False)
        self._workers.clear()
        self._cancel_frames(lambda f: True, FrameCancelled("master stopped"))

    # ------------------------------------------------------------------ sending
    def _send(self, w: _Worker, frame: bytes, expire_on_fail: bool = True) -> bool:
        try:
            self._sock.send_multipart([w.ident, frame], zmq.NOBLOCK, copy=False)
        except zmq.ZMQError as e:
            if expire_on_fail and w.ident in self._workers:
                reason = "disconnected" if e.errno == zmq.EHOSTUNREACH else f"send failed ({e})"
                self._drop_worker(w, reason)
            return False
        w.last_sent = time.monotonic()
        return True

    def _send_raw(self, ident: bytes, frame: bytes) -> None:
        try:
            self._sock.send_multipart([ident, frame], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass

    # ------------------------------------------------------------------ receiving
    def _on_message(self, parts: list[bytes]) -> None:
        if len(parts) != 2:
            self._drop(parts[0] if parts else b"?", f"{len(parts) - 1} frames, expected 1")
            return
        ident, frame = parts
        try:
            msg = P.decode(frame)
        except P.VersionMismatch as e:
            self._counters["refused"] += 1
            self._warn("refused", "refused peer %s: %s", _peer(ident), e)
            self._send_raw(ident, P.refusal(e.theirs))
            w = self._workers.get(ident)
            if w is not None:
                self._drop_worker(w, "protocol version mismatch")
            return
        except P.ProtocolError as e:
            self._drop(ident, str(e))
            return
        w = self._workers.get(ident)
        if w is not None:
            w.last_seen = time.monotonic()
        kind, body = msg.kind, msg.body
        if kind == P.HELLO:
            self._on_hello(ident, body)
        elif w is None:
            if kind in (P.BYE, P.REFUSE):
                return
            self._drop(ident, f"{kind} from an unregistered peer; asked it to send HELLO")
            self._send_raw(ident, P.encode(P.ERROR, {"code": "unregistered",
                                                     "message": "unknown worker: send HELLO"}))
        elif kind == P.RESULT:
            self._on_result(w, body)
        elif kind == P.HEARTBEAT:
            pass
        elif kind == P.ERROR:
            self._on_error(w, body)
        elif kind == P.BYE:
            self._drop_worker(w, f"said BYE ({body.get('reason', '')})")
        elif kind == P.REFUSE:
            self._drop_worker(w, f"refused us: {body['message']}")
        else:
            self._drop(ident, f"{kind} is not a message a worker sends")

    def _drop(self, ident: bytes, why: str) -> None:
        self._counters["dropped"] += 1
        self._warn("dropped", "dropped message from %s: %s", _peer(ident), why)

    def _warn(self, kind: str, msg: str, *args) -> None:
        """A warning about what a peer did: rate-limited per kind, every one counted."""
        self._rl.warning(kind, msg, *args)

    def _on_hello(self, ident: bytes, body: dict) -> None:
        old = self._workers.get(ident)
        if old is not None:
            self._re_registered(old)
        now = time.monotonic()
        w = _Worker(ident=ident, name=body["name"], host=body["host"], pid=body["pid"],
                    threads=body["threads"], credit=body["credit"], scenes=set(body["scenes"]),
                    last_seen=now, joined=now)
        self._workers[ident] = w
        log.info("worker %s joined (%s, pid %d, %d threads, credit %d)", w.name, w.host, w.pid,
                 w.threads, w.credit)
        if self._send(w, P.encode(P.WELCOME, {"worker": ident.decode("ascii", "replace")[:128],
                                              "heartbeat": self.heartbeat, "liveness": self.liveness})):
            self._send_scene(w)
        self._dispatch()

    def _on_result(self, w: _Worker, body: dict) -> None:
        t0 = time.perf_counter()
        self._handle_result(w, body)
        self._result_times.append(time.perf_counter() - t0)

    def _handle_result(self, w: _Worker, body: dict) -> None:
        key = (body["frame"], body["task"])
        now = time.monotonic()
        answered = w.inflight.get(key) == body["epoch"]
        if answered:
            del w.inflight[key]  # the slot is free again whatever happens to the result
        f = self._frames.get(body["frame"])
        t = f.tasks.get(body["task"]) if f is not None else None
        if t is None or t.epoch != body["epoch"] or t.worker != w.ident:
            if answered and self._faults.answered(w.ident):  # late, not silent
                log.warning("worker %s answers again (late): quarantine lifted", w.name)
            self._counters["results_stale"] += 1
            log.debug("stale/duplicate result %s epoch %d from %s", key, body["epoch"], w.name)
            return
        if "rays" in body:
            r = body["rays"]
            delta = r - w.rays if r >= w.rays else r  # a new renderer restarts its counter
            w.rays = r
            self._rays.append((now, delta))
        timings = body.get("timings", {})
        if "render" in timings:
            w.busy_s += timings["render"]
            self._render_times.append(timings["render"])
        if "encode" in timings:
            self._encode_times.append(timings["encode"])
        t_merge = time.perf_counter()
        try:
            count = tile_pixel_count(t.tile, f.assembler.n, f.spec.width, f.spec.height)
            if body["count"] != count:
                raise ValueError(f"{body['count']} pixels, tile has {count}")
            # validated and decompressed here; float conversion, scatter and filter happen
            # once per frame, in parallel stripes, when the frame's image is made
            f.assembler.add_wire(t.tile, body["data"])
        except Exception as e:
            self._warn("bad_result", "bad result for task %s from %s: %s; re-queued", key, w.name, e)
            self._task_failed(f, t, f"bad result: {e}", w)
            return
        self._faults.delivered(w.ident)
        if "sets" in body:
            v = f.spec.scene_version
            w.cached = {(v, s, k) for s, k in body["sets"]}
        else:
            w.cached.add(t.set_key)
        self._merge_times.append(time.perf_counter() - t_merge)
        self._task_bytes.append(len(body["data"]))
        del f.tasks[body["task"]]
        w.done += 1
        self._counters["tasks_done"] += 1
        self._latencies.append(now - t.sent)
        f.bytes += len(body["data"])
        if f.assembler.complete:
            self._complete_frame(f)

    def _on_error(self, w: _Worker, body: dict) -> None:
        if "frame" in body and "task" in body and "epoch" in body:
            key = (body["frame"], body["task"])
            if w.inflight.get(key) == body["epoch"]:
                del w.inflight[key]
            f = self._frames.get(body["frame"])
            t = f.tasks.get(body["task"]) if f is not None else None
            if t is not None and t.epoch == body["epoch"] and t.worker == w.ident:
                self._warn("task_failed", "task %s failed on %s: %s: %s", key, w.name, body["code"], body["message"])
                self._task_failed(f, t, f"{body['code']}: {body['message']}", w)
            return
        if body["code"] == "scene_unavailable":
            w.scenes.discard(self._scene_hash)
            self._send_scene(w)
            return
        log.warning("worker %s reports %s: %s", w.name, body["code"], body["message"])

    def _task_failed(self, f: _Frame, t: _Task, why: str, w: _Worker | None = None) -> None:
        t.failures += 1
        t.worker = None
        if w is not None:
            t.lost_by(w.ident, self._faults.trusted(w.ident))  # another worker first
            self._worker_fault(w, self._faults.failed(w.ident, why))
        if t.failures >= MAX_TASK_FAILURES:
            self._frames.pop(f.spec.frame, None)
            self._queue = collections.deque(k for k in self._queue if k[0] != f.spec.frame)
            log.error("frame %d failed: task %d failed %d times (%s)", f.spec.frame, t.task, t.failures, why)
            if not f.future.done():
                f.future.set_exception(FrameFailed(f"frame {f.spec.frame}: task {t.task} failed "
                                                   f"{t.failures} times ({why})"))
            if f.stream_gen is not None:
                self._fill_stream()
            return
        self._queue.appendleft((t.frame, t.task))
        self._counters["tasks_requeued"] += 1

    def _complete_frame(self, f: _Frame) -> None:
        self._frames.pop(f.spec.frame, None)
        now = time.monotonic()
        self._counters["frames"] += 1
        self._frame_times.append(now)
        self._frame_bytes.append(f.bytes)
        if not f.future.done():
            f.future.set_result(FrameResult(f.spec, f.assembler, f.bytes, f.total, f.started, now))
        if f.stream_gen is not None:
            self._fill_stream()

    # ------------------------------------------------------------------ dispatch and liveness
    def _dispatch(self) -> None:
        if not self._queue or not self._workers:
            return
        t0 = time.perf_counter()
        free = sum(max(0, self._faults.credit(w.ident, w.credit) - len(w.inflight))
                   for w in self._workers.values())
        if free == 0:
            return
        pending = self._pending_tasks(free)
        views = self._worker_views({t.set_key for t in pending})
        assigned = scheduler.assign(pending, views)
        if assigned:
            self._apply_assignments(assigned)
        self._dispatch_times.append(time.perf_counter() - t0)

    def _worker_views(self, queued_sets: set) -> list:
        """What the policy sees of every worker that may get tasks: its effective credit
        (bounded by what it delivered), tasks in flight, and which of the ``queued_sets`` it
        holds or builds (the others do not matter to the policy)."""
        views = []
        for w in self._workers.values():
            if w.scene_state is None or self._faults.quarantined(w.ident):
                continue
            building = {self._set_of(key) for key in w.inflight}
            sets = frozenset(k for k in queued_sets if k in w.cached or k in building)
            views.append(scheduler.WorkerView(w.ident, self._faults.credit(w.ident, w.credit),
                                              len(w.inflight), sets, self._faults.trusted(w.ident)))
        return views

    def _set_of(self, key) -> tuple | None:
        f = self._frames.get(key[0])
        t = f.tasks.get(key[1]) if f is not None else None
        return t.set_key if t is not None else None

    def _pending_tasks(self, free: int) -> list:
        """The queue as the policy sees it: the whole queue (set-aware choice looks past the
        front), but at most the first ``free`` tasks of each set — no more can be assigned.
        Tasks of frames gone meanwhile are dropped from the queue."""
        pending = []
        per_set: collections.Counter = collections.Counter()
        stale = 0
        for key in self._queue:
            f = self._frames.get(key[0])
            t = f.tasks.get(key[1]) if f is not None else None
            if t is None:
                stale += 1
                continue
            if per_set[t.set_key] < free:
                per_set[t.set_key] += 1
                pending.append(t.as_pending(key))
        if stale:
            self._queue = collections.deque(k for k in self._queue
                                            if k[0] in self._frames and k[1] in self._frames[k[0]].tasks)
        return pending

    def _apply_assignments(self, assigned: list) -> None:
        done = set()
        for key, wid in assigned:
            w = self._workers.get(wid)
            if w is None:
                continue
            f = self._frames[key[0]]
            t = f.tasks[key[1]]
            if not self._ensure_frame_sent(w, f):
                continue
            self._epoch += 1
            t.epoch, t.worker, t.sent = self._epoch, wid, time.monotonic()
            tl = t.tile
            msg = P.encode(P.TASK, {"frame": t.frame, "task": t.task, "epoch": t.epoch, "k": tl.k,
                                    "tile": [tl.sx0, tl.sy0, tl.sx1, tl.sy1]}, check=False)
            if self._send(w, msg):
                w.inflight[key] = t.epoch
                if w.first_task_s is None:
                    w.first_task_s = t.sent - w.joined
                done.add(key)
            else:
                t.worker = None
        if done:
            self._queue = collections.deque(k for k in self._queue if k not in done)

    def _ensure_frame_sent(self, w: _Worker, f: _Frame) -> bool:
        if f.spec.frame in w.frames_sent:
            return True
        # the hash of the blob this worker's scene came from (same content at this version)
        st = w.scene_state
        h = st[0] if st is not None and st[1] == f.spec.scene_version else self._scene_hash
        if not self._send(w, P.encode(P.FRAME, P.frame_body(f.spec, h), check=False)):
            return False
        w.frames_sent[f.spec.frame] = True
        while len(w.frames_sent) > 64:
            w.frames_sent.popitem(last=False)
        return True

    def _tick(self, now: float) -> None:
        self._expire_tasks(now)
        hb = None
        for w in list(self._workers.values()):
            if now - w.last_seen > self.heartbeat * self.liveness:
                self._drop_worker(w, f"expired (silent for {now - w.last_seen:.1f} s)")
                continue
            if now - w.last_sent >= self.heartbeat * 0.9:
                hb = hb or P.encode(P.HEARTBEAT, {})
                self._send(w, hb)
        self._dispatch()

    def _expire_tasks(self, now: float) -> None:
        """A task unanswered for ``task_timeout`` s (a wedged worker, results it cannot get
        through) goes back to the front of the queue. Its slot stays taken on that worker until
        something comes back, so a worker that never answers runs out of credit."""
        lost = []
        timeout = self.current_task_timeout()
        for f in self._frames.values():
            for t in f.tasks.values():
                if t.worker is not None and now - t.sent > timeout:
                    w = self._workers.get(t.worker)
                    self._warn("task_timeout", "task (%d, %d) unanswered for %.1f s on %s (timeout %.1f s); "
                               "re-queued", t.frame, t.task, now - t.sent, w.name if w else "?", timeout)
                    t.lost_by(t.worker, self._faults.trusted(t.worker))
                    t.worker = None
                    t.epoch = 0
                    lost.append((t.frame, t.task))
                    if w is not None:
                        self._worker_fault(w, self._faults.timed_out(w.ident, f"task unanswered for {now - t.sent:.1f} s"))
        if lost:
            self._queue = collections.deque(scheduler.requeue_front(list(self._queue), lost))
            self._counters["tasks_requeued"] += len(lost)

    def current_task_timeout(self) -> float:
        """Seconds a task may stay unanswered: from the measured task times (issue 20), at most
        the configured ``task_timeout``."""
        return scheduler.task_timeout(self._latencies, cap=self.task_timeout)

    def _worker_fault(self, w: _Worker, quarantined: str | None) -> None:
        """After a task fault on ``w``: when that quarantined it, say so once and give its
        tasks in flight to the others (it keeps its connection but gets no more tasks)."""
        if quarantined is None:
            return
        self._counters["quarantined"] += 1
        log.warning("worker %s (%s, pid %d) quarantined: %s", w.name, w.host, w.pid, quarantined)
        lost = self._take_back(w)
        if lost:
            self._queue = collections.deque(scheduler.requeue_front(list(self._queue), lost))
            self._counters["tasks_requeued"] += len(lost)

    def _take_back(self, w: _Worker) -> list:
        """The tasks in flight on ``w`` (current epoch), unassigned and avoiding ``w``. Its slots
        stay taken, so a late answer is still recognized as its own (see FaultLedger.answered)."""
        lost = []
        for key, epoch in w.inflight.items():
            f = self._frames.get(key[0])
            t = f.tasks.get(key[1]) if f is not None else None
            if t is not None and t.epoch == epoch and t.worker == w.ident:
                t.worker = None
                t.lost_by(w.ident, self._faults.trusted(w.ident))
                lost.append(key)
        return lost

    def _re_registered(self, w: _Worker) -> None:
        """A registered worker said HELLO again (a worker that restarts uses a new identity):
        the tasks it held go to other workers first and count as a fault, so a peer cannot
        keep the front of the queue by re-registering."""
        lost = self._take_back(w)
        w.inflight.clear()
        if lost:
            self._queue = collections.deque(scheduler.requeue_front(list(self._queue), lost))
            self._counters["tasks_requeued"] += len(lost)
            self._worker_fault(w, self._faults.timed_out(w.ident, f"said HELLO again with {len(lost)} task(s) in flight"))
        self._drop_worker(w, "said HELLO again", forget=False)

    def _drop_worker(self, w: _Worker, reason: str, forget: bool = True) -> None:
        if self._workers.pop(w.ident, None) is None:
            return
        lost = self._take_back(w)  # to other workers first; trusted ones if w never delivered
        w.inflight.clear()
        if forget:
            self._faults.forget(w.ident)
        if lost:
            self._queue = collections.deque(scheduler.requeue_front(list(self._queue), lost))
            self._counters["tasks_requeued"] += len(lost)
        log.warning("worker %s left: %s; %d task(s) back to the front of the queue", w.name, reason, len(lost))
        self._dispatch()


def _params_dict(params) -> dict:
    if params is None:
        return params_to_dict(make_params())
    if isinstance(params, dict):
        return params_to_dict(make_params(**params))
    if dataclasses.is_dataclass(params):
        return params_to_dict(params)
    raise TypeError("params must be a Params, a dict of overrides or None")


def _handshake_monitor(sock: zmq.Socket):
    """A CURVE server socket's handshake-failure monitor (common/curve_log.py), else None."""
    try:
        if not sock.getsockopt(zmq.CURVE_SERVER):
            return None
        from common.curve_log import HandshakeMonitor

        return HandshakeMonitor(sock)
    except zmq.ZMQError:  # pragma: no cover - monitoring unsupported
        return None


def _us_stats(times) -> dict | None:
    if not times:
        return None
    a = np.asarray(times) * 1e6
    return {"mean": float(a.mean()), "p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95))}


def _peer(ident: bytes) -> str:
    try:
        s = ident.decode("ascii")
        if s.isprintable():
            return s[:64]
    except UnicodeDecodeError:
        pass
    return "0x" + ident[:16].hex()
