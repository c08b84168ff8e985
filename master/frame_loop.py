"""The frame loop: open a frame, hand its tasks to the workers, collect the results, complete it.

Everything here runs on the broker's loop thread (``master/broker.py``), except
:meth:`FrameLoop.alloc_frame`, which any thread may call.

- A frame is cut into tasks (``frame_assembly.task_tiles``; of a fixed size, or with
  ``task_pixels=None`` as large as the render threads connected allow,
  ``frame_assembly.task_pixels_for``); their keys ``(frame, task)`` wait
  in one queue, front first. Each task needs one VPL/photon set, key
  ``(scene_version, seed, k)``; the queue is indexed by it (``master/task_queue.py``), so a
  dispatch costs O(sets), not O(queued tasks).
- Dispatch asks the pure policy of ``master/scheduler.py`` (credit-based flow control,
  set-aware choice over the whole queue, fault avoidance) and sends FRAME (once per worker and
  frame) and TASK. Every assignment has a fresh epoch.
- A RESULT counts only for the task's current epoch and the worker it was given to, in an open
  frame — stale and duplicate results are dropped. Its tile is validated and stored in the
  frame's :class:`FrameAssembler`; when the last tile is in, the frame's Future resolves.
- Tasks of a worker that left, timed out, failed or was quarantined go back to the FRONT of
  the queue, avoiding that worker (``TaskQueue.push_front``); a task that fails
  :data:`MAX_TASK_FAILURES` times fails its frame. Task timeouts follow the measured task
  times (``scheduler.task_timeout``).

What a frame and a task hold is in ``master/frames.py``; worker links (sockets, liveness, the
fault ledger) are ``master/links.py``'s; the stream of frames for the viewer is
``master/stream.py``'s.
"""
from __future__ import annotations

import collections
import concurrent.futures as cf
import logging
import threading
import time
from typing import Callable

from igi.common import protocol as P
from igi.common.frame import FrameSpec

from . import scheduler
from .frame_assembly import FrameAssembler, task_pixels_for, task_tiles, tile_pixel_count
from .frames import Frame, FrameCancelled, FrameFailed, FrameResult, Task
from .links import Links, Worker
from .meters import Meters
from .scene_state import SceneState
from .task_queue import TaskQueue

log = logging.getLogger("igi.master")

MAX_TASK_FAILURES = 3  # a task that fails this often fails its frame


class FrameLoop:
    """Open frames, the task queue and the dispatch/result cycle (see the module docstring)."""

    def __init__(self, links: Links, scene: SceneState, *, task_pixels: int | None, task_timeout: float,
                 frames_in_flight: Callable[[], int] = lambda: 1):
        self.links = links
        self.scene = scene
        self.counters = links.counters  # shared with the links: one set of figures for stats()
        # None: sized per frame for the render threads connected (frame_assembly.task_pixels_for)
        self.task_pixels = None if task_pixels is None else int(task_pixels)
        self.frames_in_flight = frames_in_flight
        self.task_timeout = float(task_timeout)  # the cap of scheduler.task_timeout
        self._last_pixels = 1  # the last task sent's pixels (current_task_timeout)
        self.queue = TaskQueue()  # (frame, task) keys, front first, by set
        self.frames: collections.OrderedDict[int, Frame] = collections.OrderedDict()
        self.meters = Meters()
        self.on_stream_frame_closed: Callable[[], None] = lambda: None  # the stream refills
        self._epoch = 0
        self._next_frame = 0
        self._alloc_lock = threading.Lock()

    # ------------------------------------------------------------------ frames
    def alloc_frame(self) -> int:
        """A new frame number (any thread)."""
        with self._alloc_lock:
            f = self._next_frame
            self._next_frame += 1
            return f

    def open_frame(self, spec: FrameSpec, fut: cf.Future, stream_gen: int | None) -> None:
        """Queue the tasks of ``spec``; ``fut`` resolves to its FrameResult (or an exception)."""
        if not fut.set_running_or_notify_cancel():
            return
        try:
            self._check_openable(spec)
        except Exception as e:
            fut.set_exception(e)
            return
        n = int(spec.params["interleave"])
        tiles = task_tiles(spec.width, spec.height, n, self.frame_task_pixels(spec.width * spec.height))
        tasks = {}
        for i, t in enumerate(tiles):
            tasks[i] = Task(spec.frame, i, t, (spec.scene_version, spec.seed, t.k))
            self.queue.append((spec.frame, i), tasks[i].set_key)
        self.frames[spec.frame] = Frame(spec, FrameAssembler(spec.width, spec.height, n), fut,
                                        tasks, len(tiles), time.monotonic(), stream_gen=stream_gen)
        self.dispatch()

    def frame_task_pixels(self, pixels: int) -> int:
        """Pixels per task of a new frame: the fixed size, or the policy's for the threads now."""
        if self.task_pixels is not None:
            return self.task_pixels
        threads = sum(w.threads for w in self.links.workers.values()
                      if not self.links.faults.quarantined(w.ident))
        return task_pixels_for(pixels, threads, self.frames_in_flight())

    def _check_openable(self, spec: FrameSpec) -> None:
        if self.scene.hash is None:
            raise ValueError("no scene loaded")
        current = self.scene.version
        if spec.scene_version != current:
            raise FrameCancelled(f"frame {spec.frame} is for scene version {spec.scene_version}, "
                                 f"current is {current}")
        if spec.frame in self.frames:
            raise ValueError(f"frame {spec.frame} is already open")
        P.validate(P.FRAME, P.frame_body(spec, self.scene.hash))

    def cancel_frames(self, pred: Callable[[Frame], bool], exc: Exception) -> None:
        gone = [num for num, f in self.frames.items() if pred(f)]
        if not gone:
            return
        for num in gone:
            f = self.frames.pop(num)
            if not f.future.done():
                f.future.set_exception(exc)
        gone_set = set(gone)
        self.queue.remove_where(lambda k: k[0] in gone_set)

    def open_stream_frames(self, gen: int) -> int:
        return sum(1 for f in self.frames.values() if f.stream_gen == gen)

    def older_stream_frame_open(self, frame: int, gen: int) -> bool:
        return any(num < frame and f.stream_gen == gen for num, f in self.frames.items())

    def _lookup(self, frame: int, task: int) -> tuple[Frame | None, Task | None]:
        f = self.frames.get(frame)
        return f, (f.tasks.get(task) if f is not None else None)

    def _complete_frame(self, f: Frame) -> None:
        self.frames.pop(f.spec.frame, None)
        now = time.monotonic()
        self.counters["frames"] += 1
        self.meters.frame_done(now, f.bytes)
        if not f.future.done():
            f.future.set_result(FrameResult(f.spec, f.assembler, f.bytes, f.total, f.started, now))
        if f.stream_gen is not None:
            self.on_stream_frame_closed()

    def _fail_frame(self, f: Frame, t: Task, why: str) -> None:
        self.frames.pop(f.spec.frame, None)
        self.queue.remove_where(lambda k: k[0] == f.spec.frame)
        log.error("frame %d failed: task %d failed %d times (%s)", f.spec.frame, t.task, t.failures, why)
        if not f.future.done():
            f.future.set_exception(FrameFailed(f"frame {f.spec.frame}: task {t.task} failed "
                                               f"{t.failures} times ({why})"))
        if f.stream_gen is not None:
            self.on_stream_frame_closed()

    # ------------------------------------------------------------------ dispatch
    def dispatch(self) -> None:
        """One round of the policy over the whole queue; sends the TASKs it assigns."""
        if not self.queue or not self.links.workers:
            return
        t0 = time.perf_counter()
        faults = self.links.faults
        free = sum(max(0, faults.credit(w.ident, w.credit) - len(w.inflight))
                   for w in self.links.workers.values())
        if free == 0:
            return
        pending = self._pending_tasks(free)
        views = self._worker_views({t.set_key for t in pending})
        assigned = scheduler.assign(pending, views)
        if assigned:
            self._apply_assignments(assigned)
        self.meters.dispatch_times.append(time.perf_counter() - t0)

    def _worker_views(self, queued_sets: set) -> list:
        """What the policy sees of every worker that may get tasks: its effective credit
        (bounded by what it delivered), tasks in flight, and which of the ``queued_sets`` it
        holds or builds (the others do not matter to the policy)."""
        faults = self.links.faults
        views = []
        for w in self.links.workers.values():
            if w.scene_state is None or faults.quarantined(w.ident):
                continue
            building = {self._set_of(key) for key in w.inflight}
            sets = frozenset(k for k in queued_sets if k in w.cached or k in building)
            views.append(scheduler.WorkerView(w.ident, faults.credit(w.ident, w.credit),
                                              len(w.inflight), sets, faults.trusted(w.ident)))
        return views

    def _set_of(self, key) -> tuple | None:
        _, t = self._lookup(*key)
        return t.set_key if t is not None else None

    def _pending_tasks(self, free: int) -> list:
        """The queue as the policy sees it: the whole queue (set-aware choice looks past the
        front), but at most the first ``free`` tasks of each set — no more can be assigned.
        Tasks of frames gone meanwhile are dropped from the queue."""
        while True:
            pending, stale = [], []
            for key in self.queue.heads(free):
                _, t = self._lookup(*key)
                if t is None:
                    stale.append(key)
                else:
                    pending.append(t.as_pending(key))
            if not stale:
                return pending
            for key in stale:  # and look again: a set's later tasks move up
                self.queue.remove(key)

    def _apply_assignments(self, assigned: list) -> None:
        for key, wid in assigned:
            w = self.links.workers.get(wid)
            if w is None:
                continue
            f = self.frames[key[0]]
            if not self._ensure_frame_sent(w, f):
                continue
            if self._send_task(w, f, f.tasks[key[1]]):
                self.queue.remove(key)

    def _send_task(self, w: Worker, f: Frame, t: Task) -> bool:
        self._epoch += 1
        t.epoch, t.worker, t.sent = self._epoch, w.ident, time.monotonic()
        t.pixels = tile_pixel_count(t.tile, f.assembler.n, f.spec.width, f.spec.height)
        t.builds_set = t.set_key not in w.cached
        self._last_pixels = t.pixels
        tl = t.tile
        msg = P.encode(P.TASK, {"frame": t.frame, "task": t.task, "epoch": t.epoch, "k": tl.k,
                                "tile": [tl.sx0, tl.sy0, tl.sx1, tl.sy1]}, check=False)
        if not self.links.send(w, msg):
            t.worker = None
            return False
        w.inflight[(t.frame, t.task)] = t.epoch
        if w.first_task_s is None:
            w.first_task_s = t.sent - w.joined
        return True

    def _ensure_frame_sent(self, w: Worker, f: Frame) -> bool:
        if f.spec.frame in w.frames_sent:
            return True
        # the hash of the blob this worker's scene came from (same content at this version)
        st = w.scene_state
        h = st[0] if st is not None and st[1] == f.spec.scene_version else self.scene.hash
        if not self.links.send(w, P.encode(P.FRAME, P.frame_body(f.spec, h), check=False)):
            return False
        w.frames_sent[f.spec.frame] = True
        while len(w.frames_sent) > 64:
            w.frames_sent.popitem(last=False)
        return True

    # ------------------------------------------------------------------ results
    def on_result(self, w: Worker, body: dict) -> None:
        t0 = time.perf_counter()
        self._handle_result(w, body)
        self.meters.result_times.append(time.perf_counter() - t0)

    def _handle_result(self, w: Worker, body: dict) -> None:
        key = (body["frame"], body["task"])
        now = time.monotonic()
        answered = w.inflight.get(key) == body["epoch"]
        if answered:
            del w.inflight[key]  # the slot is free again whatever happens to the result
        f, t = self._lookup(*key)
        if t is None or t.epoch != body["epoch"] or t.worker != w.ident:
            self._stale_result(w, key, body["epoch"], answered)
            return
        self._note_report(w, body, now)
        t_merge = time.perf_counter()
        if not self._merge_tile(w, f, t, body):
            return
        self.links.faults.delivered(w.ident)
        self._note_cached_sets(w, f, t, body)
        self.meters.merge_times.append(time.perf_counter() - t_merge)
        self.meters.task_bytes.append(len(body["data"]))
        self._task_done(w, f, t, len(body["data"]), now)

    def _note_report(self, w: Worker, body: dict, now: float) -> None:
        """What the RESULT says about the worker: rays traced, render and encode times, the
        seconds it spent building sets."""
        timings = body.get("timings", {})
        w.rays = self.meters.worker_report(body["rays"] if "rays" in body else None, w.rays, timings, now)
        if "render" in timings:
            w.busy_s += timings["render"]
        if timings.get("sets", 0.0) > 0.0:
            w.set_builds.append(timings["sets"])

    def _stale_result(self, w: Worker, key: tuple, epoch: int, answered: bool) -> None:
        if answered and self.links.faults.answered(w.ident):  # late, not silent
            log.warning("worker %s answers again (late): quarantine lifted", w.name)
        self.counters["results_stale"] += 1
        log.debug("stale/duplicate result %s epoch %d from %s", key, epoch, w.name)

    def _merge_tile(self, w: Worker, f: Frame, t: Task, body: dict) -> bool:
        """Validate and store the tile of a RESULT; a bad one fails the task (False)."""
        try:
            count = t.pixels  # (counted when the task was sent)
            if body["count"] != count:
                raise ValueError(f"{body['count']} pixels, tile has {count}")
            # validated and decompressed here; float conversion, scatter and filter happen
            # once per frame, in parallel stripes, when the frame's image is made
            f.assembler.add_wire(t.tile, body["data"])
        except Exception as e:
            self.links.warn("bad_result", "bad result for task %s from %s: %s; re-queued",
                            (t.frame, t.task), w.name, e)
            self._task_failed(f, t, f"bad result: {e}", w)
            return False
        return True

    @staticmethod
    def _note_cached_sets(w: Worker, f: Frame, t: Task, body: dict) -> None:
        """The sets the worker holds: its list when the RESULT carries one, else one more."""
        if "sets" in body:
            v = f.spec.scene_version
            w.cached = {(v, s, k) for s, k in body["sets"]}
        else:
            w.cached.add(t.set_key)

    def _task_done(self, w: Worker, f: Frame, t: Task, nbytes: int, now: float) -> None:
        del f.tasks[t.task]
        w.done += 1
        self.counters["tasks_done"] += 1
        self.meters.latencies.append(now - t.sent)
        self.meters.latency_per_pixel.append((now - t.sent) / max(t.pixels, 1))
        f.bytes += nbytes
        if f.assembler.complete:
            self._complete_frame(f)

    def on_task_error(self, w: Worker, body: dict) -> None:
        """An ERROR naming a task: the task failed on ``w`` (when it is still ``w``'s)."""
        key = (body["frame"], body["task"])
        if w.inflight.get(key) == body["epoch"]:
            del w.inflight[key]
        f, t = self._lookup(*key)
        if t is not None and t.epoch == body["epoch"] and t.worker == w.ident:
            self.links.warn("task_failed", "task %s failed on %s: %s: %s", key, w.name, body["code"],
                            body["message"])
            self._task_failed(f, t, f"{body['code']}: {body['message']}", w)

    def _task_failed(self, f: Frame, t: Task, why: str, w: Worker | None = None) -> None:
        t.failures += 1
        t.worker = None
        if w is not None:
            t.lost_by(w.ident, self.links.faults.trusted(w.ident))  # another worker first
            self.worker_fault(w, self.links.faults.failed(w.ident, why))
        if t.failures >= MAX_TASK_FAILURES:
            self._fail_frame(f, t, why)
            return
        self.queue.push_front([((t.frame, t.task), t.set_key)])
        self.counters["tasks_requeued"] += 1

    # ------------------------------------------------------------------ lost tasks
    def expire_tasks(self, now: float) -> bool:
        """A task unanswered for its timeout (a wedged worker, results it cannot get through)
        goes back to the front of the queue. Its slot stays taken on that worker until
        something comes back, so a worker that never answers runs out of credit. True when
        some task was re-queued."""
        lost = []
        cost = self._task_cost()
        for f in self.frames.values():
            for t in f.tasks.values():
                if t.worker is None:
                    continue
                timeout = scheduler.task_timeout(cost, self.task_timeout, t.pixels, t.builds_set)
                if now - t.sent > timeout:
                    self._expire_task(t, now, timeout)
                    lost.append((t.frame, t.task))
        self.requeue_front(lost)
        return bool(lost)

    def _expire_task(self, t: Task, now: float, timeout: float) -> None:
        faults = self.links.faults
        w = self.links.workers.get(t.worker)
        self.links.warn("task_timeout", "task (%d, %d) unanswered for %.1f s on %s (timeout %.1f s); "
                        "re-queued", t.frame, t.task, now - t.sent, w.name if w else "?", timeout)
        t.lost_by(t.worker, faults.trusted(t.worker))
        t.worker = None
        t.epoch = 0
        if w is not None:
            self.worker_fault(w, faults.timed_out(w.ident, f"task unanswered for {now - t.sent:.1f} s"))

    def _task_cost(self) -> scheduler.TaskCost:
        return scheduler.TaskCost.measured(self.meters.latency_per_pixel,
                                           [w.set_builds for w in self.links.workers.values()])

    def current_task_timeout(self) -> float:
        """Seconds a task the size of the last one sent, its set held, may stay unanswered
        (scheduler.task_timeout: from the measured task times, at most the configured
        ``task_timeout``)."""
        return scheduler.task_timeout(self._task_cost(), self.task_timeout, self._last_pixels)

    def requeue_front(self, lost: list) -> None:
        """Put the task keys ``lost`` back at the front of the queue, in their order."""
        if lost:
            self.queue.push_front([(key, s) for key in lost if (s := self._set_of(key)) is not None])
            self.counters["tasks_requeued"] += len(lost)

    def worker_fault(self, w: Worker, quarantined: str | None) -> None:
        """After a task fault on ``w``: when that quarantined it, say so once and give its
        tasks in flight to the others (it keeps its connection but gets no more tasks)."""
        if quarantined is None:
            return
        self.counters["quarantined"] += 1
        log.warning("worker %s (%s, pid %d) quarantined: %s", w.name, w.host, w.pid, quarantined)
        self.requeue_front(self._take_back(w))

    def _take_back(self, w: Worker) -> list:
        """The tasks in flight on ``w`` (current epoch), unassigned and avoiding ``w``. Its slots
        stay taken, so a late answer is still recognized as its own (see FaultLedger.answered)."""
        lost = []
        trusted = self.links.faults.trusted(w.ident)
        for key, epoch in w.inflight.items():
            _, t = self._lookup(*key)
            if t is not None and t.epoch == epoch and t.worker == w.ident:
                t.worker = None
                t.lost_by(w.ident, trusted)
                lost.append(key)
        return lost

    def reclaim(self, w: Worker) -> int:
        """``w`` is gone: its tasks in flight go to the front of the queue, to other workers
        first (to trusted ones if ``w`` never delivered). Returns how many."""
        lost = self._take_back(w)
        w.inflight.clear()
        self.requeue_front(lost)
        return len(lost)

    def re_registered(self, w: Worker) -> None:
        """A registered worker said HELLO again (a worker that restarts uses a new identity):
        the tasks it held go to other workers first and count as a fault, so a peer cannot
        keep the front of the queue by re-registering. (The links drop it afterwards.)"""
        lost = self.reclaim(w)
        if lost:
            self.worker_fault(w, self.links.faults.timed_out(
                w.ident, f"said HELLO again with {lost} task(s) in flight"))

    # ------------------------------------------------------------------ stats
    def stats(self, now: float) -> dict:
        return {"open_frames": len(self.frames), "queued_tasks": len(self.queue),
                "task_timeout_s": self.current_task_timeout(), **self.meters.stats(now)}
