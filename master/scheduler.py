"""The scheduling policy: a pure function of the pending tasks and the workers' loads and caches.

No sockets, no clocks, no randomness: :func:`assign` maps (pending tasks in queue order,
worker views) to a list of (task id, worker id) assignments, so the policy is tested alone
(ipyparallel's schedulers are built the same way) and the broker only applies what it returns.
:class:`FaultLedger` (per-worker fault accounting, issue 20) and :func:`task_timeout` are pure
too: the caller passes what happened, they say what follows.

Policy (docs/architecture.md, docs/scaling.md; set-aware since issue 19):

1. Credit-based flow control: a worker with ``credit`` slots (granted in its HELLO, default
   :data:`common.protocol.CREDIT_PER_THREAD` per render thread, bounded by what it delivers:
   :meth:`FaultLedger.credit`) never gets more than ``credit`` tasks in flight.
2. Set-aware: a free worker takes the first queued task of a VPL/photon set it *holds* (key
   ``(scene_version, seed, k)``: cached, or being built for a task in flight) or that another
   worker gave back (failed, timed out, left: it holds up a frame, so it counts as held by
   everyone), else the first queued task of the set the *fewest* workers able to take it hold
   (ties: the set queued first). So the sets
   of a new frame are spread over the workers once — one owner per k, the owner then gets the
   set's tasks — and a set is built a second time only when no unheld set waits (its owner is
   slow, busy or gone: the least-loaded free worker helps). A worker given a set within one
   call holds it for the rest of the call.
3. One task at a time, to the free worker that holds a queued set first, then to one that
   would build an unheld set, then to a (nearly) idle one that helps with a held set; among
   those the least loaded (``inflight / credit``, ties: more free slots, then worker id). A
   worker takes a set another worker holds only with fewer than ``share_below`` (1) tasks in
   flight, so nobody is idle while a task it may take waits, and busy workers do not build
   second copies of sets.
4. Faults: a task that failed on (or timed out at) a worker is not given to that worker again
   while another eligible worker exists (``PendingTask.avoid``); a task lost by a worker that
   never delivered a result (``PendingTask.trusted_only``: a peer cycling through identities
   cannot keep the front of the queue) goes only to workers that have delivered
   (``WorkerView.trusted``) while any is there; quarantined workers are simply not passed in
   (the broker leaves them out: see :class:`FaultLedger`). A trusted worker does not wait for
   an untrusted holder of a set (rule 3's "another worker holds it" counts trusted holders
   only): otherwise a silent peer that holds a set and all its credit starves that set's
   tasks in every later frame while the trusted workers stay busy, and the stream stops.
5. Re-queued tasks (of an expired, disconnected or departing worker) are put at the FRONT of
   the queue in their original order (the broker's ``master/task_queue.py``,
   ``TaskQueue.push_front``); among tasks of one set the queue order is kept.
"""
from __future__ import annotations

import statistics
from dataclasses import dataclass, field
from typing import Hashable, Iterable, Sequence


@dataclass(frozen=True)
class PendingTask:
    task: Hashable  # the broker's task id
    set_key: Hashable  # the VPL/photon set the task needs, e.g. (scene_version, seed, k)
    avoid: frozenset = frozenset()  # workers on which this task failed or timed out
    trusted_only: bool = False  # lost by a worker that never delivered: trusted workers first


@dataclass(frozen=True)
class WorkerView:
    id: Hashable
    credit: int  # task slots (the effective credit: see FaultLedger.credit)
    inflight: int = 0  # tasks assigned and not yet answered
    cached: frozenset = field(default_factory=frozenset)  # set keys the worker holds or is building
    trusted: bool = True  # has delivered results (FaultLedger.trusted)

    @property
    def free(self) -> int:
        return max(0, self.credit - self.inflight)

    @property
    def load(self) -> float:
        return self.inflight / self.credit if self.credit > 0 else float("inf")


SHARE_BELOW = 1  # a worker takes a set another worker holds only with fewer tasks in flight


def assign(pending: Sequence[PendingTask], workers: Iterable[WorkerView],
           limit: int | None = None, share_below: int = SHARE_BELOW) -> list[tuple[Hashable, Hashable]]:
    """Assignments (task id, worker id); see the module docstring.

    ``limit`` caps the number of assignments (None: as many as credit allows).
    """
    workers = list(workers)
    state = {w.id: [w.credit, w.inflight, set(w.cached)] for w in workers}
    all_ids = set(state)
    untrusted = {w.id for w in workers if not w.trusted}
    if len(untrusted) == len(all_ids):
        untrusted = set()  # nobody has delivered yet: trust does not restrict anyone
    # the queue by set: set key -> positions (queue order), and the order sets first appear
    by_set: dict = {}
    for pos, t in enumerate(pending):
        by_set.setdefault(t.set_key, []).append(pos)
    holders: dict = {}  # set key -> workers holding it (one pass over the workers' sets)
    for wid, s in state.items():
        for key in s[2]:
            if key in by_set:
                holders.setdefault(key, set()).add(wid)
    lost_sets = {t.set_key for t in pending if t.avoid}  # sets of tasks another worker gave back
    queued = by_set.keys()

    def holders_of(key) -> set:
        return holders.setdefault(key, set())
    taken: set[int] = set()
    heads = {key: 0 for key in by_set}  # index into by_set[key] of the first untaken position
    out: list[tuple[Hashable, Hashable]] = []
    blocked: set = set()  # workers with a free slot but no task they may take
    cap = len(pending) if limit is None else min(limit, len(pending))

    def first_for(key, wid):
        """First untaken position of ``key`` that ``wid`` may take (None when none)."""
        lst = by_set[key]
        i = heads[key]
        while i < len(lst) and lst[i] in taken:
            i += 1
        heads[key] = i
        for pos in lst[i:]:
            if pos not in taken and _may_take(pending[pos], wid, all_ids) \
                    and not (pending[pos].trusted_only and wid in untrusted):
                return pos
        return None

    def choice(wid):
        """(kind, position) of the task ``wid`` would take: kind 0 a set it holds, 1 a set
        nobody holds, 2 a set others hold (only when the worker is nearly idle); None: none."""
        held = state[wid][2]
        best = None
        for key in (held | lost_sets) & queued:  # (the queued sets it holds or others gave back)
            pos = first_for(key, wid)
            if pos is not None and (key in held or pending[pos].avoid) and (best is None or pos < best):
                best = pos
        if best is not None:
            return (0, 0, best)
        cands = []
        for key in by_set:
            pos = first_for(key, wid)
            if pos is None:
                continue
            h = holders_of(key)
            able = h - pending[pos].avoid  # holders that may take this task
            if wid not in untrusted:
                # a set held only by workers that never delivered (or are in a fault streak) is
                # not waited for: a silent peer holding credit must not starve its sets
                able -= untrusted
            if able and state[wid][1] >= share_below:
                continue  # another worker builds/holds it; help only when (nearly) idle
            cands.append((2 if able else 1, len(able), pos))
        return min(cands) if cands else None

    while len(out) < cap:
        best = None
        for wid, s in state.items():
            if s[1] >= s[0] or wid in blocked:
                continue
            c = choice(wid)
            if c is None:
                blocked.add(wid)
                continue
            rank = (c[0], s[1] / s[0], -(s[0] - s[1]), _id_order(wid))
            if best is None or rank < best[0]:
                best = (rank, wid, c[2])
        if best is None:
            break
        _, wid, pos = best
        t = pending[pos]
        taken.add(pos)
        out.append((t.task, wid))
        state[wid][1] += 1
        if t.set_key not in state[wid][2]:
            state[wid][2].add(t.set_key)
            holders_of(t.set_key).add(wid)
    return out


def _may_take(t: PendingTask, wid, all_ids: set) -> bool:
    """A task avoids the workers it failed on while any other worker is there to take it."""
    if wid not in t.avoid:
        return True
    return all_ids <= t.avoid


def _id_order(wid):
    return (type(wid).__name__, wid)


def credit_for(threads: int, per_thread: int | None = None) -> int:
    """Default credit a worker grants: ~3 tasks in flight per render thread."""
    from igi.common.protocol import CREDIT_PER_THREAD

    return max(1, int(threads) * (CREDIT_PER_THREAD if per_thread is None else per_thread))


# ------------------------------------------------------------------ fault accounting (issue 20)
INITIAL_CREDIT = 2  # slots a new worker gets before it has delivered anything
QUARANTINE_AFTER = 3  # consecutive failures/timeouts that quarantine a worker
TIMEOUT_FACTOR = 8.0  # task timeout = max(factor * the task's expected time, floor), <= cap (task_timeout)
TIMEOUT_FLOOR = 1.5  # seconds: a silent worker may stall a stream ~this long (issue 20: <= 2 s)
TIMEOUT_WINDOW = 64  # recent task times considered


@dataclass
class WorkerRecord:
    delivered: int = 0  # results accepted (all time)
    window: int = 0  # results delivered since the last fault (grows the credit)
    consecutive: int = 0  # failures/timeouts since the last delivered result
    failures: int = 0
    timeouts: int = 0
    quarantined: str | None = None  # why, once quarantined
    streak_kinds: set = field(default_factory=set)  # kinds of the consecutive faults ("failed", "timeout")
    soft: bool = False  # quarantined for timeouts alone: a late answer lifts it


class FaultLedger:
    """Per-worker fault accounting: pure bookkeeping, the broker reports events.

    - :meth:`credit`: the effective credit is ``min(advertised, INITIAL_CREDIT + window)``,
      where ``window`` counts the results delivered since the last fault (halved by a fault),
      so a worker that advertises 4,096 slots and never answers holds at most
      :data:`INITIAL_CREDIT` tasks; a good worker reaches its advertised credit after a few
      results.
    - :meth:`failed` / :meth:`timed_out`: after :data:`QUARANTINE_AFTER` consecutive faults (no
      delivered result between them) the worker is quarantined: it keeps its connection but
      gets no task. The call that quarantines returns the reason (log it once); later ones
      return None.
    - :meth:`answered`: a worker that answers a task after its timeout (a stale but genuine
      answer) was slow, not silent: its streak ends, and a quarantine caused by timeouts alone
      is lifted (a stall of the machine must not cost a render its only good worker).
    """

    def __init__(self, initial_credit: int = INITIAL_CREDIT, quarantine_after: int = QUARANTINE_AFTER):
        self.initial_credit = max(1, int(initial_credit))
        self.quarantine_after = max(1, int(quarantine_after))
        self.records: dict = {}

    MAX_RECORDS = 10_000  # a peer reconnecting under new identities cannot grow this without bound

    def record(self, wid) -> WorkerRecord:
        r = self.records.get(wid)
        if r is None:
            if len(self.records) >= self.MAX_RECORDS:
                del self.records[next(iter(self.records))]  # the oldest
            r = self.records[wid] = WorkerRecord()
        return r

    def credit(self, wid, advertised: int) -> int:
        r = self.records.get(wid)
        window = r.window if r is not None else 0
        return max(0, min(int(advertised), self.initial_credit + window))

    def trusted(self, wid) -> bool:
        """Has ``wid`` delivered a result, with no failure or timeout since its last one?"""
        r = self.records.get(wid)
        return r is not None and r.delivered > 0 and r.consecutive == 0

    def quarantined(self, wid) -> str | None:
        r = self.records.get(wid)
        return r.quarantined if r is not None else None

    def delivered(self, wid) -> None:
        r = self.record(wid)
        r.delivered += 1
        r.window += 1
        self._end_streak(r)

    def answered(self, wid) -> bool:
        """A late (stale) answer to a task given to ``wid``; True when that lifted a quarantine."""
        r = self.records.get(wid)
        if r is None:
            return False
        lifted = r.quarantined is not None and r.soft
        if lifted:
            r.quarantined, r.soft = None, False
        self._end_streak(r)
        return lifted

    @staticmethod
    def _end_streak(r: WorkerRecord) -> None:
        r.consecutive = 0
        r.streak_kinds = set()

    def failed(self, wid, why: str) -> str | None:
        r = self.record(wid)
        r.failures += 1
        return self._fault(r, why, "failed")

    def timed_out(self, wid, why: str = "task timed out") -> str | None:
        r = self.record(wid)
        r.timeouts += 1
        return self._fault(r, why, "timeout")

    def _fault(self, r: WorkerRecord, why: str, kind: str) -> str | None:
        r.consecutive += 1
        r.streak_kinds.add(kind)
        r.window //= 2
        if r.quarantined is None and r.consecutive >= self.quarantine_after:
            r.quarantined = (f"{r.consecutive} consecutive task faults "
                             f"({r.failures} failed, {r.timeouts} timed out; last: {why})")
            r.soft = r.streak_kinds == {"timeout"}
            return r.quarantined
        return None

    def forget(self, wid) -> None:
        """Drop the record of a worker that left cleanly (a quarantined one is remembered)."""
        r = self.records.get(wid)
        if r is not None and r.quarantined is None:
            del self.records[wid]


@dataclass(frozen=True)
class TaskCost:
    """What the recent tasks took, as :func:`task_timeout` scales it to one task: the median
    seconds per pixel from TASK sent to RESULT (None: no task measured yet) and a set build's
    allowance — each worker's longest recent set build, the lower median of those over the
    workers. The longest, not the median of the builds: most are one small set (~10 ms), but a
    worker's first task of a new view also prepares it (pilot, camera points, portals: seconds),
    and that is the task a median would time out. Over the workers, a lower median: one worker
    reporting huge builds (issue 20: a peer may lie) cannot lengthen everyone's timeouts."""
    per_pixel: float | None
    set_build: float = 0.0

    @classmethod
    def measured(cls, per_pixel: Sequence[float], set_builds: Iterable[Sequence[float]] = ()) -> "TaskCost":
        """From the recent per-pixel task times and each worker's set-build times (the last
        TIMEOUT_WINDOW of each)."""
        px = list(per_pixel)[-TIMEOUT_WINDOW:]
        longest = [max(list(b)[-TIMEOUT_WINDOW:]) for b in set_builds if b]
        return cls(statistics.median(px) if px else None, statistics.median_low(longest) if longest else 0.0)


def task_timeout(cost: TaskCost, cap: float, pixels: int, builds_set: bool = False,
                 factor: float = TIMEOUT_FACTOR, floor: float = TIMEOUT_FLOOR) -> float:
    """Seconds a task of ``pixels`` pixels may stay unanswered: ``factor`` × what it is expected
    to take — the recent median per pixel times its pixels, plus the longest recent set build
    when its worker did not hold its set (``builds_set``) — at least ``floor``, at most ``cap``; ``cap``
    alone before any task time is known. Per pixel and per set build, so neither a frame of
    another size (a quarter-size first frame, then the full one) nor the first task of a set
    on a worker (a set build can take longer than ten tasks) makes a working worker's task
    look lost."""
    if cost.per_pixel is None:
        return float(cap)
    expected = cost.per_pixel * max(int(pixels), 1) + (cost.set_build if builds_set else 0.0)
    return min(float(cap), max(float(floor), factor * expected))
