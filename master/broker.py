"""The master: a ZeroMQ ROUTER that hands tasks to workers and assembles their results.

:class:`Broker` is a facade over the master's roles, one module each:

- ``master/links.py`` — worker links: the ROUTER socket, HELLO, heartbeats and liveness,
  garbage and version handling, the fault ledger, scene distribution (SCENE / EDIT);
- ``master/scene_state.py`` — the scene, its content-hashed blob, the edits on top of it and
  their folding into a new blob every :data:`FOLD_EDITS` edits (issue 20);
- ``master/frame_loop.py`` — one frame: tasks, the scheduler's assignments
  (``master/scheduler.py``), results, re-queueing, timeouts, completion (what a frame and a
  task hold, and how a frame ends: ``master/frames.py``);
- ``master/stream.py`` — the viewer's stream: pipeline, finisher thread, accumulation,
  publishing, view changes;
- ``master/mailbox.py`` and ``master/meters.py`` — closures for the loop thread; what is
  measured for :meth:`Broker.stats`.

Threads
-------
One *loop thread* owns the ROUTER socket and every piece of scheduling state (workers, task
queue, open frames). Public methods, callable from any thread, post small closures to it
through the mailbox, and wait on a Future where they need an answer. Filtering and
accumulation never run on the loop thread: ``render_frame`` callers filter in their own thread,
streaming frames are filtered by the stream's *finisher* thread — so heartbeats and dispatch
keep flowing while the master merges.

API (thread-safe)
-----------------
    Broker(scene=None, bind="tcp://127.0.0.1:5555", heartbeat=1.0, liveness=3, task_pixels=16384,
           pipeline=3, task_timeout=60, configure_socket=None)   # configure_socket(sock): before bind;
           # task_pixels None: sized per frame for the connected threads (frame_assembly.task_pixels_for;
           # the image then depends on the cluster's size, so it is opt-in)
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
import logging
import threading
import time
from typing import Any, Callable

import numpy as np
import zmq

from igi.common import protocol as P
from igi.common.frame import FrameSpec
from igi.common.malloc_policy import reuse_freed_blocks
from igi.common.scene import Scene

from . import scene_state
from .accumulation import Accumulator, accumulation_key, sequence_spec
from .edge_stopping import EdgeStoppingGuide
from .frame_assembly import DEFAULT_TASK_PIXELS
from .frame_loop import MAX_TASK_FAILURES, FrameLoop
from .frames import FrameCancelled, FrameFailed, FrameResult, params_dict
from .links import Links
from .kernels.warm import warm_up_master_in_background
from .mailbox import Mailbox
from .meters import LATENCY_WINDOW
from .scene_state import FOLD_EDITS, SceneState
from .stream import Stream, StreamFrame

__all__ = ["Broker", "DEFAULT_BIND", "FOLD_EDITS", "LATENCY_WINDOW", "MAX_TASK_FAILURES", "FrameCancelled",
           "FrameFailed", "FrameResult", "StreamFrame"]

log = logging.getLogger("igi.master")
EXPIRY_CHECK = 0.1  # seconds between checks for tasks past their timeout

DEFAULT_BIND = "tcp://127.0.0.1:5555"
# the order of the figures of Broker.stats()
STATS_KEYS = ("workers", "threads", "fps", "rays_per_s", "frames_completed", "open_frames", "queued_tasks",
              "inflight_tasks", "tasks_done", "tasks_requeued", "results_stale", "messages_dropped", "refused",
              "scene_blobs_sent", "scene_folds", "bytes_per_frame", "task_latency_ms", "task_render_ms",
              "task_encode_ms", "task_merge_ms", "task_bytes", "result_handle_us", "dispatch_us", "task_timeout_s",
              "quarantined", "warnings_suppressed", "accumulated", "relative_error", "scene_version", "per_worker")


class _Delegated:
    """An attribute of the broker that lives on one of its parts (read and write)."""

    def __init__(self, part: str, name: str):
        self.part, self.name = part, name

    def __get__(self, obj, owner=None):
        return self if obj is None else getattr(getattr(obj, self.part), self.name)

    def __set__(self, obj, value) -> None:
        setattr(getattr(obj, self.part), self.name, value)


class Broker:
    """The master (see the module docstring)."""

    bind_address = _Delegated("_links", "bind_address")
    heartbeat = _Delegated("_links", "heartbeat")
    liveness = _Delegated("_links", "liveness")
    endpoint = _Delegated("_links", "endpoint")
    task_pixels = _Delegated("_frame_loop", "task_pixels")
    task_timeout = _Delegated("_frame_loop", "task_timeout")
    pipeline = _Delegated("_stream", "pipeline")

    def __init__(self, scene: Scene | None = None, bind: str = DEFAULT_BIND, *,
                 heartbeat: float = P.HEARTBEAT_INTERVAL, liveness: int = P.HEARTBEAT_LIVENESS,
                 task_pixels: int | None = DEFAULT_TASK_PIXELS, pipeline: int = 3,
                 task_timeout: float = 60.0, context: zmq.Context | None = None,
                 configure_socket: Callable[[zmq.Socket], None] | None = None):
        self._scene_state = SceneState()
        self._links = Links(self._scene_state, bind=bind, heartbeat=heartbeat, liveness=liveness,
                            context=context or zmq.Context.instance(), configure_socket=configure_socket)
        self._frame_loop = FrameLoop(self._links, self._scene_state, task_pixels=task_pixels,
                                     task_timeout=task_timeout, frames_in_flight=lambda: self._stream.pipeline)
        self._mailbox = Mailbox()
        self._stream = Stream(self._frame_loop, self._scene_state, self._call, max(1, int(pipeline)))
        self._links.tasks = self._frame_loop
        self._frame_loop.on_stream_frame_closed = self._stream.fill
        self._thread: threading.Thread | None = None
        self._running = False
        self._stop_lock = threading.Lock()
        if scene is not None:
            self._install_scene(scene, *scene_state.encode(scene))

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> "Broker":
        if self._thread is not None:
            return self
        self._links.open()
        warm_up_master_in_background()  # the kernels load while the workers start
        reuse_freed_blocks()  # each tile's decompressed payload in reused heap, not fresh pages
        self._running = True
        self._mailbox.inline = False
        self._thread = threading.Thread(target=self._loop, name="igi-master-loop", daemon=True)
        self._thread.start()
        self._stream.start_finisher()
        log.info("master listening on %s (protocol %d)", self.endpoint, P.PROTOCOL_VERSION)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Say BYE to every worker, cancel open frames and close the socket (idempotent,
        callable from any thread)."""
        with self._stop_lock:
            if self._thread is None or self._mailbox.closed:
                return
            self._stream.on = False
            try:
                self._call(self._shutdown, timeout=timeout)
            except Exception:  # pragma: no cover - loop already gone
                pass
            self._mailbox.closed = True
            self._running = False
            self._mailbox.wake()
            self._thread.join(timeout)
            self._stream.stop_finisher(timeout)
            if not self._thread.is_alive():
                self._mailbox.close()

    def __enter__(self) -> "Broker":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _call(self, fn: Callable[[], Any], timeout: float | None = 30.0) -> Any:
        """Run ``fn`` on the loop thread (inline before start) and return its result."""
        return self._mailbox.call(fn, timeout)

    # ------------------------------------------------------------------ the loop thread
    def _loop(self) -> None:
        poller = zmq.Poller()
        self._links.register(poller)
        poller.register(self._mailbox.fileno(), zmq.POLLIN)
        self._next_tick = time.monotonic() + self.heartbeat
        self._next_expiry = time.monotonic() + EXPIRY_CHECK
        while self._running:
            wake = min(self._next_tick, self._next_expiry)
            timeout_ms = max(0, int((wake - time.monotonic()) * 1000))
            try:
                events = dict(poller.poll(timeout_ms))
            except zmq.ZMQError as e:  # pragma: no cover - interrupted
                log.debug("poll: %s", e)
                continue
            if self._mailbox.fileno() in events:
                self._mailbox.drain_wake()
            self._links.drain_monitor(events)
            try:
                self._mailbox.run_pending()
                self._service(events)
            except Exception:  # a bug must never take the master down
                log.exception("master loop error (continuing)")
        self._links.close()

    def _service(self, events: dict) -> None:
        if self._links.receive(events):
            self._frame_loop.dispatch()
        now = time.monotonic()
        if now >= self._next_expiry:
            # Lost tasks are found within EXPIRY_CHECK of their deadline, not at the next
            # heartbeat tick: a silent worker stalls a stream for ~ the task timeout only.
            self._next_expiry = now + EXPIRY_CHECK
            if self._frame_loop.expire_tasks(now):
                self._frame_loop.dispatch()
        if now >= self._next_tick:
            self._next_tick = now + self.heartbeat
            self._tick(now)

    def _tick(self, now: float) -> None:
        self._frame_loop.expire_tasks(now)
        self._links.keep_alive(now)
        self._frame_loop.dispatch()

    def _shutdown(self) -> None:
        self._links.say_bye()
        self._frame_loop.cancel_frames(lambda f: True, FrameCancelled("master stopped"))

    # ------------------------------------------------------------------ scene
    @property
    def scene(self) -> Scene | None:
        return self._scene_state.current()

    @property
    def scene_version(self) -> int:
        return self._scene_state.version

    @property
    def scene_hash(self) -> str | None:
        return self._scene_state.current_hash()

    def set_scene(self, scene: Scene) -> int:
        """Load a new scene (new blob, new version); open frames are cancelled. Returns the version."""
        blob, h = scene_state.encode(scene)  # outside the loop thread: may take a while
        return self._call(lambda: self._install_scene(scene, blob, h))

    def apply_edit(self, edit: dict) -> int:
        """Apply a scene edit (``common.scene_codec`` delta) on the master and every worker.
        Raises ValueError for an invalid edit. Returns the new scene version.

        Every :data:`FOLD_EDITS` edits the edited scene becomes the new content-hashed blob
        (encoded here, in the caller's thread): a worker that joins later gets that blob and
        the few edits since, never an ever-growing log (issue 20). Workers already in step
        keep their blob and get the edits one by one, as before."""
        from igi.common.scene_codec import apply_edit

        P.validate(P.EDIT, {"hash": "0" * 64, "version": 1, "edit": edit})  # wire shape
        version, fold = self._call(lambda: self._apply_edit(edit, apply_edit))
        if fold is not None:
            scene, fold_version, base_hash = fold
            blob, h = scene_state.encode(scene)
            self._call(lambda: self._install_fold(fold_version, base_hash, blob, h))
        return version

    def _install_scene(self, scene: Scene, blob: bytes, h: str) -> int:
        """Loop thread: a new scene; open frames are cancelled, every worker gets it."""
        version = self._scene_state.install(scene, blob, h)
        self._frame_loop.cancel_frames(lambda f: True, FrameCancelled("scene replaced"))
        self._links.broadcast_scene()
        self._stream.changed(reset_index=True)
        log.info("scene %s… version %d (%d bytes, %d triangles)", h[:12], version, len(blob),
                 scene.triangle_count)
        return version

    def _apply_edit(self, edit: dict, apply_fn) -> tuple:
        """Loop thread: (new version, None or (scene, version, hash) to fold into a blob)."""
        new_scene, version = self._scene_state.edit(edit, apply_fn)  # ValueError on a bad edit
        self._frame_loop.cancel_frames(lambda f: f.spec.scene_version != version, FrameCancelled("scene edited"))
        self._links.broadcast_edit(edit, version)
        self._stream.changed(reset_index=True)
        fold = (new_scene, version, self._scene_state.hash) if self._scene_state.fold_due() else None
        return version, fold

    def _install_fold(self, version: int, base_hash: str, blob: bytes, h: str) -> None:
        """Loop thread: ``blob`` (hash ``h``) is the scene at ``version``; it becomes the base
        that SCENE messages send, with the edits made since. Skipped when the scene was
        replaced meanwhile."""
        if self._scene_state.fold(version, base_hash, blob, h):
            self._links.counters["scene_folds"] += 1
            log.info("scene edits folded: version %d is scene %s… (%d bytes)", version, h[:12], len(blob))

    # ------------------------------------------------------------------ one-shot frames
    def frame_spec(self, index: int = 0, params=None, camera=None, width: int | None = None,
                   height: int | None = None, frame: int | None = None) -> FrameSpec:
        """FrameSpec of the current scene version: accumulation index ``index``; camera and
        resolution from the scene unless given (see ``common.camera.resolve_camera``)."""
        from igi.common.camera import resolve_camera

        scene = self.scene
        if scene is None:
            raise ValueError("no scene loaded")
        pdict = params_dict(params)
        cam, fov_x, w, h = resolve_camera(scene, camera, width, height)
        return sequence_spec(self._frame_loop.alloc_frame() if frame is None else frame, index, cam, fov_x,
                             w, h, pdict, self.scene_version)

    def submit_frame(self, spec: FrameSpec) -> cf.Future:
        """Queue a frame; the Future resolves to a FrameResult (or FrameCancelled/FrameFailed)."""
        out: cf.Future = cf.Future()

        def failed(posted: cf.Future) -> None:  # e.g. the master stopped: never leave `out` pending
            if posted.exception() is not None and not out.done():
                out.set_exception(posted.exception())
        self._mailbox.post(lambda: self._frame_loop.open_frame(spec, out, None)).add_done_callback(failed)
        return out

    def render_frame(self, spec: FrameSpec, timeout: float | None = None) -> FrameResult:
        return self.submit_frame(spec).result(timeout)

    def render_sequence(self, params=None, frames: int = 1, camera=None, width: int | None = None,
                        height: int | None = None,
                        on_frame: Callable[[int, np.ndarray], object] | None = None,
                        timeout: float | None = None,
                        on_plain_mean: Callable[[int, np.ndarray], object] | None = None) -> np.ndarray:
        """Same contract as ``master.inprocess.render_local`` (same specs, tiles, filter and
        accumulation, ``on_frame`` and ``on_plain_mean``), rendered by the workers with ``pipeline``
        frames in flight."""
        pdict = params_dict(params)
        frames = max(1, int(frames))
        acc = Accumulator()
        guide = EdgeStoppingGuide()
        futures: collections.deque = collections.deque()
        nxt = 0
        image = None
        for i in range(frames):
            while nxt < frames and len(futures) < self.pipeline:  # specs made as sent: frames may be huge
                futures.append(self.submit_frame(self.frame_spec(nxt, pdict, camera, width, height)))
                nxt += 1
            res = futures.popleft().result(timeout)
            key = accumulation_key(res.spec)
            acc.add(res.image(guide.track(key)), key)
            if on_plain_mean is not None:
                on_plain_mean(i, acc.mean())
            image = acc.mean(guide)
            if on_frame is not None:
                on_frame(i, image)
        return image

    def current_task_timeout(self) -> float:
        """Seconds a task may stay unanswered: from the measured task times (issue 20), at most
        the configured ``task_timeout``."""
        return self._frame_loop.current_task_timeout()

    # ------------------------------------------------------------------ streaming (viewer API)
    def start_stream(self, params=None, camera=None, width: int | None = None,
                     height: int | None = None) -> None:
        """Render frames continuously for the viewer: progressive accumulation while nothing
        changes; any change of camera / params / resolution / scene resets it."""
        self._stream.start(params, camera, width, height)

    def stop_stream(self) -> None:
        self._stream.stop()

    def set_camera(self, camera_to_world, fov_x: float | None = None) -> None:
        """New view matrix (4×4 or 16 floats, Mitsuba camera-to-world) and optional fov_x."""
        self._stream.set_camera(camera_to_world, fov_x)

    def set_resolution(self, width: int, height: int) -> None:
        self._stream.set_resolution(width, height)

    def set_params(self, params=None, **overrides) -> dict:
        """Replace (``params``) and/or override render parameters of the stream; returns them."""
        return self._stream.set_params(params, **overrides)

    def view(self) -> dict:
        """The stream's current camera, fov_x, width, height and params."""
        return self._stream.view()

    def reset_accumulation(self) -> None:
        self._stream.reset_accumulation()

    def latest_frame(self) -> StreamFrame | None:
        return self._stream.latest_frame()

    def wait_frame(self, after_seq: int = 0, timeout: float | None = None) -> StreamFrame | None:
        """The first published frame with seq > ``after_seq`` (None on timeout)."""
        return self._stream.wait_frame(after_seq, timeout)

    def add_frame_listener(self, callback: Callable[[StreamFrame], object]) -> None:
        """``callback(StreamFrame)`` after every published stream frame (finisher thread)."""
        self._stream.add_frame_listener(callback)

    def remove_frame_listener(self, callback) -> None:
        self._stream.remove_frame_listener(callback)

    # ------------------------------------------------------------------ stats
    def stats(self) -> dict:
        """Counters and rates for the viewer overlay and the benchmarks."""
        return self._call(self._stats)

    def _stats(self) -> dict:
        now = time.monotonic()
        c = self._links.counters
        figures = {**self._links.stats(now), **self._frame_loop.stats(now), **self._stream.stats(),
                   "frames_completed": c["frames"], "tasks_done": c["tasks_done"],
                   "tasks_requeued": c["tasks_requeued"], "results_stale": c["results_stale"],
                   "scene_blobs_sent": c["scene_blobs_sent"], "scene_folds": c["scene_folds"],
                   "scene_version": self._scene_state.version}
        return {k: figures[k] for k in STATS_KEYS}

    def workers(self) -> list[dict]:
        return self._call(lambda: self._links.infos(time.monotonic()))

    def wait_for_workers(self, count: int, timeout: float = 30.0) -> bool:
        """Block until at least ``count`` workers are registered (False on timeout)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._call(lambda: len(self._links.workers)) >= count:
                return True
            time.sleep(0.05)
        return False

    # ------------------------------------------------------------------ for tests and benchmarks
    @property
    def _workers(self) -> dict:
        return self._links.workers

    @property
    def _base_version(self) -> int:
        return self._scene_state.base_version

    @property
    def _edits(self) -> list[dict]:
        return self._scene_state.edits
