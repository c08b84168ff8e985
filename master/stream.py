"""The stream of frames the viewer shows: a pipeline of open frames of the current view, a
*finisher* thread that filters, accumulates and publishes them in frame order, and the view
changes (camera, resolution, params, scene) that start the accumulation over.

Threads: the view, the generation and the frames in flight belong to the broker's loop thread
(the public methods post their change to it through ``call``); filtering and accumulation run
on the finisher thread, so heartbeats and dispatch keep flowing while the master merges;
readers (:meth:`Stream.latest_frame`, :meth:`Stream.wait_frame`) may be on any thread.

Every change of view / params / scene bumps the *generation*: open frames of older generations
are cancelled, frames of an older generation that complete anyway are not published, and the
accumulation index restarts at 0 (``accumulation.sequence_spec``).
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from igi.common import protocol as P
from igi.common.frame import FrameSpec
from igi.common.params import make_params, params_to_dict

from .accumulation import Accumulator, accumulation_key, sequence_spec
from .edge_stopping import EdgeStoppingGuide
from .frame_loop import FrameLoop
from .frames import FrameCancelled, FrameResult, params_dict
from .scene_state import SceneState

log = logging.getLogger("igi.master")


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


class Stream:
    """Streaming for the viewer (see the module docstring). ``call(fn)`` runs ``fn`` on the
    broker's loop thread and returns its result."""

    def __init__(self, frames: FrameLoop, scene: SceneState, call: Callable[[Callable[[], Any]], Any],
                 pipeline: int):
        self.frames = frames
        self.scene = scene
        self.pipeline = pipeline
        self._call = call
        self.on = False
        self.gen = 0
        self._gen_time = time.monotonic()
        self._index = 0
        self._view: dict[str, Any] = {}
        self._held: dict[int, FrameResult] = {}  # stream frames completed out of order
        # finisher thread and what it publishes
        self._finisher_q: queue.SimpleQueue = queue.SimpleQueue()
        self._finisher: threading.Thread | None = None
        self._acc = Accumulator()
        self._guide = EdgeStoppingGuide()  # the finisher thread's alone
        self._latest: StreamFrame | None = None
        self._latest_cond = threading.Condition()
        self._seq = 0
        self._listeners: list[Callable[[StreamFrame], object]] = []

    # ------------------------------------------------------------------ view (any thread)
    def start(self, params=None, camera=None, width: int | None = None, height: int | None = None) -> None:
        from igi.common.camera import resolve_camera

        scene = self.scene.current()
        if scene is None:
            raise ValueError("no scene loaded")
        cam, fov_x, w, h = resolve_camera(scene, camera, width, height)
        view = {"camera": cam, "fov_x": fov_x, "width": w, "height": h, "params": params_dict(params)}

        def go():
            self._view = view
            self.on = True
            self.changed(reset_index=True)
        self._call(go)

    def stop(self) -> None:
        def go():
            self.on = False
            self.frames.cancel_frames(lambda f: f.stream_gen is not None, FrameCancelled("stream stopped"))
        self._call(go)

    def set_camera(self, camera_to_world, fov_x: float | None = None) -> None:
        cam = tuple(float(x) for x in np.asarray(camera_to_world, np.float64).reshape(16))
        if not all(np.isfinite(cam)) or (fov_x is not None and not 0 < float(fov_x) < 180):
            raise ValueError("camera must be finite and 0 < fov_x < 180")
        self._update_view(camera=cam, **({} if fov_x is None else {"fov_x": float(fov_x)}))

    def set_resolution(self, width: int, height: int) -> None:
        if not (1 <= int(width) <= P.MAX_IMAGE_SIDE and 1 <= int(height) <= P.MAX_IMAGE_SIDE):
            raise ValueError(f"resolution {width}x{height} out of range")
        self._update_view(width=int(width), height=int(height))

    def set_params(self, params=None, **overrides) -> dict:
        base = params_dict(params) if params is not None else dict(self._view.get("params") or params_dict(None))
        base.update(overrides)
        pdict = params_to_dict(make_params(**base))  # ValueError on a bad value
        self._update_view(params=pdict)
        return pdict

    def view(self) -> dict:
        return dict(self._view)

    def reset_accumulation(self) -> None:
        self._call(lambda: self.changed(reset_index=True))

    def _update_view(self, **changes) -> None:
        def go():
            if not self._view:
                raise ValueError("the stream was not started")
            self._view = {**self._view, **changes}
            self.changed(reset_index=True)
        self._call(go)

    # ------------------------------------------------------------------ frames (loop thread)
    def changed(self, reset_index: bool) -> None:
        """The view changed — drop outdated stream frames, start over."""
        if reset_index:
            self.gen += 1
            self._index = 0
            self._gen_time = time.monotonic()
        gen = self.gen
        self.frames.cancel_frames(lambda f: f.stream_gen is not None and f.stream_gen != gen,
                                  FrameCancelled("view changed"))
        if reset_index:
            self._held = {}
        self.fill()

    def fill(self) -> None:
        """Keep ``pipeline`` stream frames open."""
        if not self.on or not self._view or self.scene.hash is None:
            return
        gen = self.gen
        open_stream = self.frames.open_stream_frames(gen)
        while open_stream < self.pipeline:
            if not self._open_next(gen):
                self.on = False
                return
            open_stream += 1

    def _open_next(self, gen: int) -> bool:
        v = self._view
        # A frame at index 0 is one of a moving camera: it answers fast (no roulette walks, no
        # clamp compensation, moving_indirect_vpls); the frames that accumulate after it take them.
        params = v["params"] if self._index else dict(v["params"], consistent_first_frame=False, moving_camera=True)
        spec = sequence_spec(self.frames.alloc_frame(), self._index, v["camera"], v["fov_x"],
                             v["width"], v["height"], params, self.scene.version)
        self._index += 1
        fut: cf.Future = cf.Future()
        fut.add_done_callback(lambda f, g=gen: self._frame_done(f, g))
        self.frames.open_frame(spec, fut, gen)
        if fut.done() and fut.exception() is not None:
            log.warning("stream frame not started: %s", fut.exception())
            return False
        return True

    def _frame_done(self, fut: cf.Future, gen: int) -> None:
        """Future callback: hand completed stream frames to the finisher, in frame order — a
        frame goes once no older frame of its view is still open."""
        if fut.cancelled() or fut.exception() is not None or gen != self.gen:
            return
        res = fut.result()
        self._held[res.spec.frame] = res
        while self._held:
            first = min(self._held)
            if self.frames.older_stream_frame_open(first, gen):
                break
            self._finisher_q.put((gen, self._held.pop(first)))

    # ------------------------------------------------------------------ finisher thread
    def start_finisher(self) -> None:
        self._finisher = threading.Thread(target=self._finish_loop, name="igi-master-finish", daemon=True)
        self._finisher.start()

    def stop_finisher(self, timeout: float) -> None:
        self._finisher_q.put(None)
        if self._finisher is not None:
            self._finisher.join(timeout)

    def _finish_loop(self) -> None:
        """Filter, accumulate and publish stream frames."""
        while True:
            item = self._finisher_q.get()
            if item is None:
                return
            gen, res = item
            if gen != self.gen:
                continue  # outdated view
            try:
                self._publish(res, gen)
            except Exception:  # pragma: no cover - a bug in filtering must not kill the thread
                log.exception("publishing frame %d failed", res.spec.frame)

    def _publish(self, res: FrameResult, gen: int) -> None:
        key = (gen, accumulation_key(res.spec))
        img = res.image(self._guide.track(key))
        if gen != self.gen:
            return
        count = self._acc.add(img, key)
        image = self._acc.mean(self._guide)  # before the lock: readers need not wait for the blend
        with self._latest_cond:
            self._seq += 1
            sf = StreamFrame(seq=self._seq, image=image, frame_image=img, accumulated=count,
                             spec=res.spec, relative_error=self._acc.relative_error(),
                             time=time.monotonic(), generation=gen, view_time=self._gen_time)
            self._latest = sf
            self._latest_cond.notify_all()
        for cb in list(self._listeners):
            try:
                cb(sf)
            except Exception:
                log.exception("frame listener failed")

    # ------------------------------------------------------------------ readers (any thread)
    def latest_frame(self) -> StreamFrame | None:
        with self._latest_cond:
            return self._latest

    def wait_frame(self, after_seq: int = 0, timeout: float | None = None) -> StreamFrame | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._latest_cond:
            while self._latest is None or self._latest.seq <= after_seq:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._latest_cond.wait(remaining)
            return self._latest

    def add_frame_listener(self, callback: Callable[[StreamFrame], object]) -> None:
        self._listeners.append(callback)

    def remove_frame_listener(self, callback) -> None:
        if callback in self._listeners:
            self._listeners.remove(callback)

    def stats(self) -> dict:
        latest = self._latest
        return {"accumulated": latest.accumulated if latest else 0,
                "relative_error": latest.relative_error if latest else None}
