"""A calibrated discrete-event model of the frame loop with W workers (issue 12).

This machine has 2 cores, so scaling past it is planned by measurement plus a model. The model
simulates what ``Broker.render_sequence`` does, event by event:

- the master keeps ``pipeline`` frames in flight: frame i + pipeline is submitted when frame
  i's image is made (the caller's loop); a frame's tasks (``task_tiles``, k-major) join the
  queue and are dispatched by THE scheduling policy (``master.scheduler.assign``: credit,
  set-aware — a worker takes tasks of the sets it holds or builds, else of the set fewest
  workers hold —, least loaded), over the whole queue, with the master's view of each
  worker's sets (last reported list + sets of its tasks in flight);
- a TASK reaches its worker after the network latency; the worker's render threads (FIFO)
  render it — plus the set build when the worker does not hold set (frame seed, k) — and
  encode it; the RESULT crosses the worker's link and the master's link (bandwidth, FIFO
  each) and the latency;
- the master's *loop thread* (one FIFO server) handles each RESULT: protocol decode,
  validation + lz4 decompression + storing the tile, bookkeeping and the next dispatch;
- when a frame's last tile is in, the *finishing* thread makes the image (wire → float
  conversion, discontinuity filter, compose: a serial share plus a share spread over the
  master's ``master_threads``) and accumulates it, frames in order.

CPU time is shared: every host is a processor-sharing CPU with ``cores`` (a busy job runs at
rate min(1, cores / (busy jobs + background))). Remote workers each get their own host; the
validation runs on this machine put master, workers and the measured background load of other
processes on one 2-core host — so the same model reproduces the real 1–2 worker runs.

All costs are inputs (:class:`Costs`), measured in the same run by :func:`calibrate` — per-task
render time by tile (so scene, settings and the renderer's current speed come in as measured),
set build time, encode time and bytes per pixel, the master's per-result and per-frame costs —
so the tables regenerate with one command (``igi bench scaling --model``) whenever the renderer
or the master changes.

The simulation is deterministic (no randomness; ties broken by event order) and reports
frames/s, bytes per frame, the utilization of every resource and the bottleneck.
"""
from __future__ import annotations

import collections
import heapq
import itertools
import math
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

from igi.common.params import PARAM_BY_NAME
from igi.master import scheduler

GBIT = 1e9


# ---------------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class Costs:
    """Measured costs, in seconds of one core (CPU time) and bytes.

    ``tile_weights``: the render cost per pixel of each region of the image relative to the mean
    (a coarse grid, row-major, measured per task), so bright/complex regions cost what they do.
    """

    render_s_per_px: float  # worker render time per pixel, the task's set already built
    set_build_s: float  # building one VPL/photon set (frame seed, k) on an accumulating worker (amortized)
    encode_s_per_px: float  # codec.encode + message packing on the worker
    bytes_per_px: float  # wire bytes of a RESULT per pixel (compressed buffers)
    result_overhead_bytes: float = 200.0  # RESULT header (msgpack envelope, timings, sets)
    task_bytes: float = 200.0  # a TASK message (plus the FRAME header, amortized)
    master_msg_s: float = 60e-6  # loop thread, per RESULT: zmq receive, protocol decode, bookkeeping, dispatch
    master_recv_s_per_px: float = 30e-9  # loop thread, per pixel: validate + lz4 decompress + store
    finish_s_per_px: float = 150e-9  # making the image, per pixel (1 thread): convert, filter, compose
    finish_serial_share: float = 0.1  # share of finish_s_per_px that does not run in parallel
    accumulate_s_per_px: float = 10e-9  # running mean + output, per pixel (caller thread, serial)
    tile_weights: tuple = ()  # row-major grid of relative per-pixel render cost (mean 1)
    tile_grid: tuple = (0, 0)  # (rows, cols) of tile_weights

    def render_weight(self, fx: float, fy: float) -> float:
        """Relative render cost at image position (fx, fy) in [0, 1)."""
        rows, cols = self.tile_grid
        if not self.tile_weights or rows < 1 or cols < 1:
            return 1.0
        r = min(rows - 1, max(0, int(fy * rows)))
        c = min(cols - 1, max(0, int(fx * cols)))
        return self.tile_weights[r * cols + c]


@dataclass(frozen=True)
class Network:
    name: str
    bandwidth_bps: float  # per link (each worker's, and the master's), bits/s
    latency_s: float = 50e-6  # one way


NETWORKS = (Network("1 Gbit/s", 1 * GBIT, 100e-6), Network("10 Gbit/s", 10 * GBIT, 50e-6),
            Network("100 Gbit/s", 100 * GBIT, 20e-6))
LOOPBACK = Network("loopback", 40 * GBIT, 30e-6)


@dataclass(frozen=True)
class Config:
    workers: int
    width: int = 640
    height: int = 480
    interleave: int = PARAM_BY_NAME["interleave"].default
    task_pixels: int | None = 16384  # the broker's default; None: its opt-in policy (task_pixels_for)
    threads_per_worker: int = 1
    credit_per_thread: int = 3
    pipeline: int = 3  # frames in flight (Broker.pipeline; 3 since issue 19: the set-aware policy
    # needs the next frame's sets queued to keep every worker on sets of its own)
    frames: int = 24  # simulated frames (with 3 frames in flight completions come in bursts:
    warmup: int = 8  # frames before the measured window   a long window is needed for steady state)
    network: Network = NETWORKS[1]
    master_cores: int = 16  # the master's host
    master_threads: int = 8  # threads of the parallel finishing stages
    shared_host_cores: int = 0  # > 0: master and all workers on ONE host with this many cores
    background: float = 0.0  # other runnable threads on the shared host (measured load)
    accumulate: bool = True  # a new seed (new sets) every frame, as when accumulating; False:
    # the camera moves, the seed and the workers' sets stay (docs/design-notes.md): no set builds
    prewarm_frames: int = 0  # sets of frames 0 .. prewarm-1 already held by every worker
    affinity_lookahead: int = 0  # 0: the broker's policy (scheduler.assign, set-aware);
    # L > 0: the older what-if policy (before issue 19): a free worker takes the first of the
    # next L queued tasks whose set it holds or is building, else of the least-held set


# ---------------------------------------------------------------------------------- engine
class _Sim:
    def __init__(self):
        self.now = 0.0
        self._q: list = []
        self._seq = itertools.count()

    def at(self, t: float, fn: Callable, *args) -> None:
        heapq.heappush(self._q, (t, next(self._seq), fn, args))

    def run(self, until: Callable[[], bool]) -> None:
        while self._q and not until():
            t, _, fn, args = heapq.heappop(self._q)
            self.now = max(self.now, t)
            fn(*args)


class _Host:
    """A processor-sharing CPU: busy jobs progress at rate min(1, cores / (jobs + background))."""

    def __init__(self, sim: _Sim, cores: float, background: float = 0.0):
        self.sim, self.cores, self.background = sim, float(cores), float(background)
        self.jobs: dict[int, list] = {}  # id -> [remaining work, callback]
        self._ids = itertools.count()
        self._last = 0.0
        self._version = 0
        self.cpu_busy = 0.0  # core-seconds consumed

    def _rate(self) -> float:
        n = len(self.jobs)
        return min(1.0, self.cores / (n + self.background)) if n else 0.0

    def _advance(self) -> None:
        dt = self.sim.now - self._last
        if dt > 0 and self.jobs:
            r = self._rate()
            for j in self.jobs.values():
                j[0] -= dt * r
            self.cpu_busy += dt * r * len(self.jobs)
        self._last = self.sim.now

    def start(self, work: float, cb: Callable[[], None]) -> None:
        if work <= 0:
            self.sim.at(self.sim.now, cb)
            return
        self._advance()
        self.jobs[next(self._ids)] = [work, cb]
        self._reschedule()

    def _reschedule(self) -> None:
        self._version += 1
        if self.jobs:
            r = self._rate()
            t = min(j[0] for j in self.jobs.values()) / r
            self.sim.at(self.sim.now + max(0.0, t), self._check, self._version)

    def _check(self, version: int) -> None:
        if version != self._version:
            return
        self._advance()
        eps = 1e-12
        done = [jid for jid, j in self.jobs.items() if j[0] <= eps]
        cbs = [self.jobs.pop(jid)[1] for jid in done]
        self._reschedule()
        for cb in cbs:
            cb()


class _Station:
    """A FIFO queue with ``servers`` servers; a job is ``run(done)`` (it starts CPU work on a
    host, or a fixed delay) and the station records its busy intervals."""

    def __init__(self, sim: _Sim, name: str, servers: int = 1):
        self.sim, self.name, self.servers = sim, name, servers
        self.queue: collections.deque = collections.deque()
        self.active = 0
        self.intervals: list[tuple[float, float]] = []

    def submit(self, run: Callable[[Callable[[], None]], None], cb: Callable[[], None]) -> None:
        self.queue.append((run, cb))
        self._next()

    def _next(self) -> None:
        while self.active < self.servers and self.queue:
            run, cb = self.queue.popleft()
            self.active += 1
            start = self.sim.now

            def done(cb=cb, start=start):
                self.active -= 1
                self.intervals.append((start, self.sim.now))
                cb()
                self._next()

            run(done)

    def busy(self, t0: float, t1: float) -> float:
        """Server-seconds busy within [t0, t1]."""
        return sum(max(0.0, min(b, t1) - max(a, t0)) for a, b in self.intervals)


def _delay(sim: _Sim, seconds: float):
    return lambda done: sim.at(sim.now + seconds, done)


def _cpu(host: _Host, work: float):
    return lambda done: host.start(work, done)


# ---------------------------------------------------------------------------------- model
@dataclass
class SimResult:
    config: Config
    fps: float
    frame_s: float
    bytes_per_frame: float
    tasks_per_frame: int
    utilization: dict  # resource -> busy share in the measured window
    bottleneck: str
    frame_done: list = field(default_factory=list)
    set_builds_per_frame: float = 0.0
    master_mpixel_s: float = 0.0  # the master's own capacity (merge + finish), pipelined
    worker_cpu_s_per_frame: float = 0.0  # CPU work of the workers / of the master per frame
    master_cpu_s_per_frame: float = 0.0

    def as_dict(self) -> dict:
        d = asdict(self)
        d["config"] = {k: (v.name if isinstance(v, Network) else v) for k, v in asdict(self.config).items()
                       if k != "network"}
        d["config"]["network"] = self.config.network.name
        d.pop("frame_done")
        return d


RESOURCES = ("workers", "master loop", "master finish", "master link", "worker links", "shared CPU")


def _tiles(cfg: Config):
    from igi.master.frame_assembly import task_pixels_for, task_tiles, tile_pixel_count

    tp = cfg.task_pixels or task_pixels_for(cfg.width * cfg.height, cfg.workers * cfg.threads_per_worker,
                                            cfg.pipeline)
    tiles = task_tiles(cfg.width, cfg.height, cfg.interleave, tp)
    out = []
    n = cfg.interleave
    for t in tiles:
        px = tile_pixel_count(t, n, cfg.width, cfg.height)
        # the tile's centre in image coordinates (sub-image pixel * n)
        fx = ((t.sx0 + t.sx1) / 2 * n) / cfg.width
        fy = ((t.sy0 + t.sy1) / 2 * n) / cfg.height
        out.append((t, px, fx, fy))
    return out


def master_capacity(costs: Costs, cfg: Config) -> float:
    """Mpixel/s the master sustains when pipelined (loop thread and finishing overlap): the
    slower of the two, with the finishing stage's parallel share over ``master_threads``."""
    px = cfg.width * cfg.height
    tiles = _tiles(cfg)
    loop = len(tiles) * costs.master_msg_s + px * costs.master_recv_s_per_px
    par = px * costs.finish_s_per_px
    t = max(1, min(cfg.master_threads, cfg.master_cores - 1 if cfg.master_cores > 1 else 1))
    fin = par * costs.finish_serial_share + par * (1 - costs.finish_serial_share) / t \
        + px * costs.accumulate_s_per_px
    return px / max(loop, fin) / 1e6 if max(loop, fin) > 0 else math.inf


def simulate(costs: Costs, cfg: Config) -> SimResult:
    """Run the frame loop of ``cfg`` with ``costs``; deterministic."""
    if cfg.workers < 1 or cfg.frames <= cfg.warmup or cfg.pipeline < 1 or cfg.warmup < 0:
        raise ValueError("need workers >= 1, frames > warmup and pipeline >= 1")
    sim = _Sim()
    net = cfg.network
    bps = net.bandwidth_bps / 8.0
    shared = None
    if cfg.shared_host_cores > 0:
        shared = _Host(sim, cfg.shared_host_cores, cfg.background)
    master_host = shared or _Host(sim, cfg.master_cores)
    worker_hosts = [shared or _Host(sim, cfg.threads_per_worker) for _ in range(cfg.workers)]

    loop = _Station(sim, "master loop")
    finish = _Station(sim, "master finish")
    master_link = _Station(sim, "master link")
    wstations = [_Station(sim, f"w{i}", cfg.threads_per_worker) for i in range(cfg.workers)]
    wlinks = [_Station(sim, f"link{i}") for i in range(cfg.workers)]

    tiles = _tiles(cfg)
    ntasks = len(tiles)
    px_frame = cfg.width * cfg.height
    credit = cfg.threads_per_worker * cfg.credit_per_thread
    inflight = [0] * cfg.workers
    def set_key(f: int, k: int):
        return (f if cfg.accumulate else 0, k)

    warm = {set_key(f, k) for f in range(cfg.prewarm_frames) for k in range(cfg.interleave ** 2)}
    if not cfg.accumulate:
        warm |= {set_key(0, k) for k in range(cfg.interleave ** 2)}  # a moving camera keeps them
    worker_sets: list[set] = [set(warm) for _ in range(cfg.workers)]  # held by the worker
    master_view: list[frozenset] = [frozenset(warm) for _ in range(cfg.workers)]  # as last reported
    inflight_keys: list[list] = [[] for _ in range(cfg.workers)]
    queue: collections.deque = collections.deque()
    remaining: dict[int, int] = {}
    merged: set[int] = set()
    frame_done: list[float] = []
    cpu_marks: list[float] = []  # the shared host's consumed core-seconds at each frame's end
    set_builds = [0]
    work_total = [0.0]  # CPU seconds of worker work, of master work (all frames)
    master_total = [0.0]
    submitted = [0]
    bytes_total = [0.0]
    next_image = [0]

    # the queue by set, in queue order (a frame's tasks are k-major, so each set's tasks are
    # contiguous and the sets come in queue order): the policy only ever needs the first
    # ``free`` tasks of each set, which keeps a dispatch cheap however long the queue
    by_set: dict = {}
    queued = [0]

    def submit(f: int) -> None:
        remaining[f] = ntasks
        for i in range(ntasks):
            if cfg.affinity_lookahead > 0:
                queue.append((f, i))
            by_set.setdefault(set_key(f, tiles[i][0].k), collections.deque()).append((f, i))
        queued[0] += ntasks
        dispatch()

    def dispatch() -> None:
        if not queued[0]:
            return
        free = sum(max(0, credit - x) for x in inflight)
        if not free:
            return
        if cfg.affinity_lookahead > 0:
            assigned = _lookahead_assign(queue, cfg.workers, credit, inflight, master_view, inflight_keys,
                                         lambda key: set_key(key[0], tiles[key[1]][0].k), cfg.affinity_lookahead)
        else:
            # the master's view of a worker's sets: its last reported list plus the sets of the
            # tasks it has in flight (it builds them), as the broker keeps it
            # (only the sets still queued matter to the policy)
            queued_sets = by_set.keys()
            views = [scheduler.WorkerView(w, credit, inflight[w],
                                          frozenset(queued_sets & (master_view[w] | set(inflight_keys[w]))))
                     for w in range(cfg.workers)]
            pending = [scheduler.PendingTask(t, key) for key, dq in by_set.items()
                       for t in itertools.islice(dq, free)]
            assigned = scheduler.assign(pending, views)
        for (f, i), w in assigned:
            inflight[w] += 1
            key = set_key(f, tiles[i][0].k)
            inflight_keys[w].append(key)
            if cfg.affinity_lookahead > 0:
                queue.remove((f, i))
            by_set[key].remove((f, i))
            if not by_set[key]:
                del by_set[key]
            queued[0] -= 1
            sim.at(sim.now + net.latency_s + costs.task_bytes / bps, arrive, f, i, w)

    def arrive(f: int, i: int, w: int) -> None:
        tile, px, fx, fy = tiles[i]
        key = set_key(f, tile.k)

        def run(done):
            work = px * costs.render_s_per_px * costs.render_weight(fx, fy) + px * costs.encode_s_per_px
            if key not in worker_sets[w]:  # checked when the render starts, as the renderer does
                worker_sets[w].add(key)
                if f < cfg.frames:  # frames past the measured ones only keep the pipeline full
                    set_builds[0] += 1
                work += costs.set_build_s
            if f < cfg.frames:
                work_total[0] += work
            worker_hosts[w].start(work, done)

        wstations[w].submit(run, lambda: send(f, i, w))

    def send(f: int, i: int, w: int) -> None:
        nbytes = tiles[i][1] * costs.bytes_per_px + costs.result_overhead_bytes
        sets = frozenset(worker_sets[w])
        wlinks[w].submit(_delay(sim, nbytes / bps),
                         lambda: master_link.submit(_delay(sim, nbytes / bps),
                                                    lambda: sim.at(sim.now + net.latency_s, received,
                                                                   f, i, w, nbytes, sets)))

    def received(f: int, i: int, w: int, nbytes: float, sets: frozenset) -> None:
        px = tiles[i][1]

        def handled():
            inflight[w] -= 1
            inflight_keys[w].remove(set_key(f, tiles[i][0].k))
            master_view[w] = sets
            if f < cfg.frames:
                bytes_total[0] += nbytes
            remaining[f] -= 1
            if remaining[f] == 0:
                merged.add(f)
                make_images()
            dispatch()

        if f < cfg.frames:
            master_total[0] += costs.master_msg_s + px * costs.master_recv_s_per_px
        loop.submit(_cpu(master_host, costs.master_msg_s + px * costs.master_recv_s_per_px), handled)

    def make_images() -> None:
        f = next_image[0]
        if f in merged and not finish.active and not finish.queue:
            merged.discard(f)
            finish.submit(finish_run, lambda: imaged(f))

    def finish_run(done) -> None:
        par = px_frame * costs.finish_s_per_px
        ser = par * costs.finish_serial_share + px_frame * costs.accumulate_s_per_px
        master_total[0] += par + px_frame * costs.accumulate_s_per_px
        t = max(1, cfg.master_threads)
        share = par * (1 - costs.finish_serial_share) / t
        left = [t]

        def part_done():
            left[0] -= 1
            if left[0] == 0:
                done()

        def serial_done():
            for _ in range(t):
                master_host.start(share, part_done)

        master_host.start(ser, serial_done)

    def imaged(f: int) -> None:
        frame_done.append(sim.now)
        if shared is not None:
            shared._advance()
            cpu_marks.append(shared.cpu_busy)
        next_image[0] = f + 1
        if submitted[0] < cfg.frames + cfg.pipeline - 1:  # the pipeline stays full to the end
            submitted[0] += 1
            submit(submitted[0] - 1)
        make_images()

    for _ in range(min(cfg.pipeline, cfg.frames)):
        submitted[0] += 1
        submit(submitted[0] - 1)
    sim.run(lambda: len(frame_done) >= cfg.frames)
    if len(frame_done) < cfg.frames:  # pragma: no cover - a bug in the model
        raise RuntimeError("simulation stalled")

    t0 = frame_done[cfg.warmup - 1] if cfg.warmup > 0 else 0.0  # warmup 0: from the start, as a timed run
    t1 = frame_done[-1]
    window = max(1e-12, t1 - t0)
    measured = cfg.frames - cfg.warmup
    util = {
        "workers": sum(s.busy(t0, t1) for s in wstations) / (window * cfg.workers * cfg.threads_per_worker),
        "master loop": loop.busy(t0, t1) / window,
        "master finish": finish.busy(t0, t1) / window,
        "master link": master_link.busy(t0, t1) / window,
        "worker links": max(s.busy(t0, t1) for s in wlinks) / window,
    }
    if shared is not None:  # our own jobs' share of the cores (the rest: idle or background)
        c0 = cpu_marks[cfg.warmup - 1] if cfg.warmup > 0 else 0.0
        util["shared CPU"] = (cpu_marks[-1] - c0) / (window * shared.cores)
    res = SimResult(config=cfg, fps=measured / window, frame_s=window / measured,
                    bytes_per_frame=bytes_total[0] / cfg.frames, tasks_per_frame=ntasks,
                    utilization=util,
                    bottleneck=_bottleneck(util, cfg, ntasks, set_builds[0] * costs.set_build_s / max(1e-12, work_total[0])),
                    frame_done=frame_done, set_builds_per_frame=set_builds[0] / cfg.frames,
                    master_mpixel_s=master_capacity(costs, cfg),
                    worker_cpu_s_per_frame=work_total[0] / cfg.frames,
                    master_cpu_s_per_frame=master_total[0] / cfg.frames)
    return res


def _lookahead_assign(queue, workers: int, credit: int, inflight: list, view: list, inflight_keys: list,
                      key_of, lookahead: int) -> list:
    """The what-if policy of Config.affinity_lookahead (not the broker's)."""
    out = []
    taken = set()
    load = list(inflight)
    held = [set(view[w]) | set(inflight_keys[w]) for w in range(workers)]
    holders = collections.Counter(k for h in held for k in h)
    for w in sorted(range(workers), key=lambda w: (load[w] / credit, w)):
        while load[w] < credit:
            window = [t for t in itertools.islice(queue, lookahead + len(taken)) if t not in taken][:lookahead]
            if not window:
                return out
            # a set it holds; else the set fewest workers hold (spreads the sets, one per worker)
            pick = next((t for t in window if key_of(t) in held[w]), None)
            if pick is None:
                pick = min(window, key=lambda t: holders[key_of(t)])
                holders[key_of(pick)] += 1
                held[w].add(key_of(pick))
            out.append((pick, w))
            taken.add(pick)
            load[w] += 1
    return out


def _bottleneck(util: dict, cfg: Config, ntasks: int, set_share: float = 0.0) -> str:
    """The resource with the highest utilization; when nothing is near saturation, the frame
    loop is bound by latency and task supply (too few tasks in flight for the workers)."""
    name, u = max(util.items(), key=lambda kv: kv[1])
    if u >= 0.85:
        return name + (f" ({set_share * 100:.0f}% set builds)" if name == "workers" and set_share >= 0.1 else "")
    if ntasks * cfg.pipeline < 1.5 * cfg.workers * cfg.threads_per_worker:
        return "task supply"
    return "frame latency"


# ---------------------------------------------------------------------------------- calibration
STEADY_SETS = 64  # sets a worker lists in every RESULT once accumulating for a while (its
# renderer caches 128 VPL + photon sets; the RESULT lists the VPL ones, each validated)


def calibrate(scene, params=None, width: int = 640, height: int = 480, sample: int = 1,
              task_pixels: int | None = None, log=None, steady_sets: int = STEADY_SETS) -> dict:
    """Measure the model's costs on this machine, now (CPU time of this process, so other load
    inflates them little): render + encode every ``sample``-th task of a frame (the first task
    of every k always, which also gives the set build time), the master's per-result handling
    (protocol decode, add_wire) and its frame finishing (image, 1 thread), the accumulation.

    Returns {"costs": Costs, "detail": {...}} (detail: the raw figures, for the report).
    """
    from igi.common import protocol as P
    from igi.common.codec import encode
    from igi.common.params import make_params, params_to_dict

    from igi.master.accumulation import sequence_spec
    from igi.master.frame_assembly import DEFAULT_TASK_PIXELS, task_tiles, tile_pixel_count
    from igi.common.camera import resolve_camera

    from igi.worker.renderer import Renderer

    if params is None:
        params = make_params()
    elif isinstance(params, dict):
        params = make_params(**params)
    pdict = params_to_dict(params)
    tp = task_pixels or DEFAULT_TASK_PIXELS
    renderer = Renderer(scene)
    cam, fov, w, h = resolve_camera(scene, None, width, height)
    n = params.interleave
    spec = sequence_spec(0, 0, cam, fov, w, h, pdict)
    tiles = task_tiles(w, h, n, tp)
    say = log or (lambda *_: None)
    say(f"calibrating: rendering {len(tiles[::max(1, sample)])}+ of {len(tiles)} tasks at {w}x{h} …")

    cpu = time.process_time
    first_of_k = {}
    rendered = []  # (tile, px, render_s, first, bufs)
    for idx, t in enumerate(tiles):
        first = t.k not in first_of_k
        if not first and idx % max(1, sample):
            continue
        c0 = cpu()
        bufs = renderer.render_tile(spec, t)
        dt = cpu() - c0
        if first:
            first_of_k[t.k] = (t, dt)
        rendered.append((t, tile_pixel_count(t, n, w, h), dt, first, bufs))
    # the first task of each k paid for the set: render it again with the set cached
    builds = []
    for k, (t, dt) in first_of_k.items():
        c0 = cpu()
        renderer.render_tile(spec, t)
        builds.append(max(0.0, dt - (cpu() - c0)))
    warm = [(t, px, dt) for t, px, dt, first, _ in rendered if not first]
    if not warm:  # one task per k: use the re-render times
        warm = [(t, tile_pixel_count(t, n, w, h), dt - b) for (t, dt), b in zip(first_of_k.values(), builds)]
    render_px = sum(dt for _, _, dt in warm) / max(1, sum(px for _, px, _ in warm))

    # relative cost map (per-pixel render time of each task, at its position)
    rows, cols = 6, 8
    grid = [[] for _ in range(rows * cols)]
    for t, px, dt in warm:
        fx = ((t.sx0 + t.sx1) / 2 * n) / w
        fy = ((t.sy0 + t.sy1) / 2 * n) / h
        grid[min(rows - 1, int(fy * rows)) * cols + min(cols - 1, int(fx * cols))].append(dt / px)
    cells = [sum(g) / len(g) if g else None for g in grid]
    known = [c for c in cells if c is not None]
    mean = sum(known) / len(known) if known else 1.0
    weights = tuple((c if c is not None else mean) / mean for c in cells)

    # encode (worker) and the RESULT messages
    enc_s = 0.0
    enc_px = 0
    wire = []
    for t, px, _, _, bufs in rendered:
        c0 = cpu()
        data = encode(bufs)
        msg = P.encode(P.RESULT, {"frame": 0, "task": len(wire), "epoch": 1, "count": px, "data": data,
                                  "sets": [[s // (n * n), s % (n * n)] for s in range(steady_sets)], "rays": 1,
                                  "timings": {"wait_scene": 0.0, "render": 0.01, "encode": 0.001}}, check=False)
        enc_s += cpu() - c0
        enc_px += px
        wire.append((t, px, data, msg))
    bytes_px = sum(len(d) for _, _, d, _ in wire) / enc_px
    overhead = sum(len(m) - len(d) for _, _, d, m in wire) / len(wire)

    master = measure_master(w, h, n, [(t, d) for t, _, d, _ in wire], pdict, tp,
                            msgs=[m for _, _, _, m in wire], reps=3)
    # the same RESULTs listing only the current frame's n² sets (a moving camera keeps them);
    # workers list their sets only when the list changes (issue 19): most RESULTs carry none
    few = [P.encode(P.RESULT, dict(P.decode(m).body, sets=[[0, k] for k in range(n * n)]), check=False)
           for _, _, _, m in wire]
    master_few = measure_master(w, h, n, [(t, d) for t, _, d, _ in wire], pdict, tp, msgs=few, reps=3)
    master["msg_s_current_sets"] = master_few["msg_s"]
    none = [P.encode(P.RESULT, {k: v for k, v in P.decode(m).body.items() if k != "sets"}, check=False)
            for _, _, _, m in wire]
    master_none = measure_master(w, h, n, [(t, d) for t, _, d, _ in wire], pdict, tp, msgs=none, reps=3)
    master["msg_s_all_sets"] = master["msg_s"]
    master["msg_s"] = master["msg_s_no_sets"] = master_none["msg_s"]
    alone_s = sum(builds) / max(1, len(builds))
    amortized_s = _accumulating_set_cost(scene, params, cam, fov, w, h)
    costs = Costs(render_s_per_px=render_px, set_build_s=amortized_s,
                  encode_s_per_px=enc_s / enc_px, bytes_per_px=bytes_px, result_overhead_bytes=overhead,
                  master_msg_s=master["msg_s"], master_recv_s_per_px=master["recv_s_per_px"],
                  finish_s_per_px=master["finish_s_per_px"], accumulate_s_per_px=master["accumulate_s_per_px"],
                  tile_weights=weights, tile_grid=(rows, cols))
    detail = {"width": w, "height": h, "tasks": len(tiles), "tasks_rendered": len(rendered),
              "render_ms_per_task": render_px * (w * h / len(tiles)) * 1e3,
              "set_build_ms": costs.set_build_s * 1e3, "set_build_alone_ms": alone_s * 1e3,
              "set_build_note": SET_COST_NOTE, "encode_ms_per_task": costs.encode_s_per_px * w * h / len(tiles) * 1e3,
              "bytes_per_px": bytes_px, "master": master}
    return {"costs": costs, "detail": detail}


ACCUMULATED_FRAMES = 30  # frames 1..30 of an accumulation: the cache's batches of 2, 4, 8 and 16 frames
SET_COST_NOTE = (f"a VPL + photon set of one k per frame over frames 1-{ACCUMULATED_FRAMES} of an accumulation, as a "
                 "worker holding one k builds them (worker/set_cache.py: with later frames' sets in its batches)")


def _accumulating_set_cost(scene, params, cam, fov: float, w: int, h: int) -> float:
    """CPU seconds per (frame, k) of the VPL and photon sets of one k over the first
    ACCUMULATED_FRAMES frames after an accumulation reset, asked for as render_tile does: what
    a worker of a large cluster, holding one k, pays per frame (set builds while accumulating;
    a moving camera keeps its sets). A renderer of its own that has asked for that k alone (its
    cache predicts from the k's asked for last), the view's one-time pilot not timed."""
    from igi.common.params import make_params, params_to_dict
    from igi.master.accumulation import sequence_spec
    from igi.worker.renderer import Renderer, consistent_frame
    from igi.worker.vpl_importance import View

    renderer = Renderer(scene)
    pdict = params_to_dict(params)
    view = View.of(cam, fov, w, h)
    k = 0
    for i in range(ACCUMULATED_FRAMES + 1):
        if i == 1:
            c0 = time.process_time()
        spec = sequence_spec(i, i, cam, fov, w, h, pdict)
        p = make_params(**spec.params)
        renderer.vpl_set(spec.seed, k, p, roulette=consistent_frame(p, i), view=view, index=i)
        renderer.photon_set(spec.seed, k, p, index=i, view=view)
    return (time.process_time() - c0) / ACCUMULATED_FRAMES


def synthetic_wire(buffers: dict, width: int, height: int, n: int, task_pixels: int, encode=None) -> list:
    """Wire bytes of a frame of another size made from rendered full-frame buffers (nearest
    resampling): for timing the master at resolutions not rendered here. ``encode``: the
    codec's (default: this revision's common.codec.encode)."""
    import numpy as np

    from igi.common.interleave import extract

    if encode is None:
        from igi.common.codec import encode

    from igi.master.frame_assembly import task_tiles

    H0, W0 = buffers["depth"].shape
    ys = (np.arange(height) * H0 // height)
    xs = (np.arange(width) * W0 // width)
    big = {k: v[ys][:, xs] for k, v in buffers.items()}
    return [(t, encode(extract(t, n, big))) for t in task_tiles(width, height, n, task_pixels)]


def measure_master(width: int, height: int, n: int, wire: list, pdict: dict, task_pixels: int,
                   msgs: list | None = None, reps: int = 3) -> dict:
    """The master's costs for one frame, CPU time: per RESULT (protocol decode when ``msgs`` are
    given, FrameAssembler.add_wire, the next TASK's encode and scheduling) and per frame
    (image() with 1 thread, guided by and teaching a learnt edge-stopping guide as a still
    view's frames are; accumulation). Also the wall-clock merge + finish of one frame with
    the configured threads (``merge_filter_mpixel_s``, the benchmark's historical figure)."""
    import numpy as np

    from igi.common import protocol as P

    from igi.master import parallel
    from igi.master.accumulation import Accumulator
    from igi.master.frame_assembly import FrameAssembler

    from igi.master.edge_stopping import MIN_FRAMES, EdgeStoppingGuide

    cpu = time.process_time
    px_frame = width * height
    # the steady state of a still view: frames guided by (and teaching) the edge-stopping guide
    guide = EdgeStoppingGuide().track("bench")
    warm = FrameAssembler(width, height, n)
    for t, d in wire:
        warm.add_wire(t, d)
    for i in range(MIN_FRAMES):
        warm.image(pdict, i, guide)
    index = MIN_FRAMES
    wire_px = sum(_tile_px(t, n, width, height) for t, _ in wire)
    best = {"recv": math.inf, "decode_msg": math.inf, "finish": math.inf, "acc": math.inf,
            "wall_merge": math.inf, "wall_finish": math.inf}
    views = [scheduler.WorkerView(i, 3, 1, frozenset({(0, i % 9)})) for i in range(16)]
    prev = parallel.set_threads(1)
    try:
        for _ in range(max(1, reps)):
            c0 = cpu()
            for m in (msgs or []):
                P.decode(m)
            for _ in range(len(wire)):
                P.encode(P.TASK, {"frame": 1, "task": 2, "epoch": 3, "k": 0, "tile": [0, 0, 64, 64]}, check=False)
                scheduler.assign([scheduler.PendingTask((0, 0), (0, 0))], views)
            best["decode_msg"] = min(best["decode_msg"], cpu() - c0)
            asm = FrameAssembler(width, height, n)
            c0 = cpu()
            for t, d in wire:
                asm.add_wire(t, d)
            best["recv"] = min(best["recv"], cpu() - c0)
            c0 = cpu()
            img = asm.image(pdict, index, guide)
            index += 1
            best["finish"] = min(best["finish"], cpu() - c0)
            acc = Accumulator()
            c0 = cpu()
            acc.add(img, "k")
            acc.mean(guide)  # with the filter selection's blend (master.filter_selection)
            best["acc"] = min(best["acc"], cpu() - c0)
        parallel.set_threads(prev)
        for _ in range(max(1, reps)):
            asm = FrameAssembler(width, height, n)
            t0 = time.perf_counter()
            for t, d in wire:
                asm.add_wire(t, d)
            t1 = time.perf_counter()
            asm.image(pdict, index, guide)
            index += 1
            t2 = time.perf_counter()
            best["wall_merge"] = min(best["wall_merge"], t1 - t0)
            best["wall_finish"] = min(best["wall_finish"], t2 - t1)
    finally:
        parallel.set_threads(prev)
    zmq_s = _zmq_message_cost(int(np.mean([len(d) for _, d in wire])))
    msg_s = best["decode_msg"] / max(1, len(wire)) + zmq_s
    return {
        "tasks": len(wire), "pixels": px_frame, "bytes": sum(len(d) for _, d in wire),
        "msg_s": msg_s, "zmq_recv_s": zmq_s,
        "recv_s_per_px": best["recv"] / wire_px,
        "finish_s_per_px": best["finish"] / px_frame,
        "accumulate_s_per_px": best["acc"] / px_frame,
        # merge = every tile's add_wire (validate, decompress, store); protocol and dispatch
        # per message are msg_s (reported apart: they do not depend on the pixel path)
        "merge_cpu_ms": best["recv"] * 1e3, "finish_cpu_ms": best["finish"] * 1e3,
        "accumulate_cpu_ms": best["acc"] * 1e3,
        "merge_filter_mpixel_s_1thread": px_frame / (best["recv"] + best["finish"]) / 1e6,
        "threads": parallel.threads(),
        "wall_merge_ms": best["wall_merge"] * 1e3, "wall_finish_ms": best["wall_finish"] * 1e3,
        "merge_filter_mpixel_s": px_frame / (best["wall_merge"] + best["wall_finish"]) / 1e6,
    }


def _tile_px(t, n, w, h) -> int:
    from igi.master.frame_assembly import tile_pixel_count

    return tile_pixel_count(t, n, w, h)


def _zmq_message_cost(nbytes: int, count: int = 300) -> float:
    """CPU seconds the receiving side spends per message of ``nbytes`` over TCP loopback
    (ROUTER receive of a DEALER's messages, as the master's loop does)."""
    import threading

    import zmq

    ctx = zmq.Context.instance()
    router = ctx.socket(zmq.ROUTER)
    port = router.bind_to_random_port("tcp://127.0.0.1")
    dealer = ctx.socket(zmq.DEALER)
    dealer.connect(f"tcp://127.0.0.1:{port}")
    payload = b"x" * nbytes
    try:
        def pump():
            for _ in range(count):
                dealer.send(payload)

        dealer.send(b"hi")
        router.recv_multipart()
        th = threading.Thread(target=pump)
        th.start()
        c0 = time.thread_time()
        for _ in range(count):
            router.recv_multipart(copy=True)
        dt = time.thread_time() - c0
        th.join()
    finally:
        dealer.close(0)
        router.close(0)
    return dt / count


# ---------------------------------------------------------------------------------- tables
WORKER_COUNTS = (1, 2, 4, 8, 16, 32, 64, 128, 256)


def predict(costs: Costs, width: int, height: int, workers=WORKER_COUNTS, networks=NETWORKS,
            **cfg) -> list[SimResult]:
    out = []
    for net in networks:
        for wk in workers:
            out.append(simulate(costs, Config(workers=wk, width=width, height=height, network=net, **cfg)))
    return out
