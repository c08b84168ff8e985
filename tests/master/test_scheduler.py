"""The scheduling policy alone: a pure function of pending tasks and worker views."""
from __future__ import annotations

import collections

import pytest

from igi.master.scheduler import (TIMEOUT_FLOOR, FaultLedger, PendingTask, TaskCost, WorkerView, assign,
                                  credit_for, task_timeout)
from igi.master.task_queue import TaskQueue


def tasks(*keys):
    return [PendingTask(i, key) for i, key in enumerate(keys)]


def test_affinity_to_the_worker_holding_the_set():
    ws = [WorkerView("a", 3, 0, frozenset()), WorkerView("b", 3, 1, frozenset({(0, 7, 4)}))]
    # b is busier but holds set 4: it gets the task
    assert assign(tasks((0, 7, 4)), ws) == [(0, "b")]


def test_least_loaded_without_affinity():
    ws = [WorkerView("a", 3, 2), WorkerView("b", 3, 0), WorkerView("c", 6, 2)]
    assert assign(tasks((0, 0, 0)), ws) == [(0, "b")]
    # load is a fraction of credit: c (2/6) before a (2/3)
    ws = [WorkerView("a", 3, 2), WorkerView("c", 6, 2)]
    assert assign(tasks((0, 0, 0)), ws) == [(0, "c")]


def test_ties_are_deterministic():
    ws = [WorkerView("b", 3), WorkerView("a", 3)]
    assert assign(tasks((0, 0, 0)), ws) == [(0, "a")]
    assert assign(tasks((0, 0, 0)), list(reversed(ws))) == [(0, "a")]


def test_credit_limits_in_flight_tasks():
    ws = [WorkerView("a", 2, 0), WorkerView("b", 3, 2)]
    out = assign(tasks(*[(0, 0, k) for k in range(10)]), ws)
    per = {w: sum(1 for _, x in out if x == w) for w in ("a", "b")}
    assert per == {"a": 2, "b": 1}
    assert [t for t, _ in out] == [0, 1, 2], "a prefix of the queue, in order"
    assert assign(tasks((0, 0, 0)), [WorkerView("a", 3, 3)]) == []
    assert assign(tasks((0, 0, 0)), []) == []


def test_a_worker_given_a_set_counts_as_holding_it():
    ws = [WorkerView("a", 3), WorkerView("b", 3)]
    out = assign(tasks((0, 0, 5), (0, 0, 5), (0, 0, 6), (0, 0, 6)), ws)
    assert sorted(out) == [(0, "a"), (1, "a"), (2, "b"), (3, "b")]


def test_affinity_falls_back_when_the_holder_is_full():
    ws = [WorkerView("a", 1, 1, frozenset({(0, 0, 1)})), WorkerView("b", 3)]
    assert assign(tasks((0, 0, 1)), ws) == [(0, "b")]


def test_a_busy_worker_takes_an_unheld_set_not_a_set_another_holds():
    # a holds set 1 (and is busy with it); b has a task in flight: it builds set 2 rather
    # than a second copy of set 1, although set 1 is queued first
    ws = [WorkerView("a", 3, 3, frozenset({(0, 0, 1)})), WorkerView("b", 3, 1, frozenset({(0, 0, 9)}))]
    assert assign(tasks((0, 0, 1), (0, 0, 2)), ws) == [(1, "b"), ]
    # an idle worker helps with a held set when nothing else waits (never idle)
    ws = [WorkerView("a", 3, 3, frozenset({(0, 0, 1)})), WorkerView("b", 3, 0)]
    assert assign(tasks((0, 0, 1)), ws) == [(0, "b")]
    # b busy and nothing unheld: it waits for its own work rather than build set 1 again
    ws = [WorkerView("a", 3, 3, frozenset({(0, 0, 1)})), WorkerView("b", 3, 1)]
    assert assign(tasks((0, 0, 1)), ws) == []


def test_a_worker_takes_its_own_sets_first_then_the_least_held():
    ws = [WorkerView("a", 4, 0, frozenset({(0, 0, 3)}))]
    out = assign(tasks((0, 0, 1), (0, 0, 3), (0, 0, 2), (0, 0, 3)), ws)
    assert [t for t, _ in out] == [1, 3, 0, 2]


def test_failed_task_goes_to_another_worker_first():
    t = [PendingTask(0, (0, 0, 1), avoid=frozenset({"a"}))]
    ws = [WorkerView("a", 3, 0, frozenset({(0, 0, 1)})), WorkerView("b", 3, 2)]
    assert assign(t, ws) == [(0, "b")]
    # the other worker is full: the task waits for it, a takes other work meanwhile
    ws = [WorkerView("a", 3, 0), WorkerView("b", 1, 1)]
    assert assign(t + [PendingTask(1, (0, 0, 2))], ws) == [(1, "a")]
    # every worker failed it: anyone may take it again
    assert assign([PendingTask(0, (0, 0, 1), avoid=frozenset({"a"}))], [WorkerView("a", 3)]) == [(0, "a")]


def test_limit():
    ws = [WorkerView("a", 10)]
    assert len(assign(tasks(*[(0, 0, 0)] * 8), ws, limit=3)) == 3


def _queue(keys, set_of=lambda t: (t[0], t[1])) -> TaskQueue:
    q = TaskQueue()
    for t in keys:
        q.append(t, set_of(t))
    return q


def test_requeued_tasks_are_assigned_first():
    queue = _queue([("f", 2), ("f", 3)], lambda key: (0, 0, key[1]))
    queue.push_front([(("f", 0), (0, 0, 0))])
    pending = [PendingTask(key, (0, 0, key[1])) for key in queue.heads(1)]
    assert assign(pending, [WorkerView("a", 1)]) == [(("f", 0), "a")]


def test_default_credit_is_three_per_thread():
    assert credit_for(1) == 3 and credit_for(4) == 12 and credit_for(0) == 1


# ------------------------------------------------------------------ many frames, many workers
def _simulate(workers=16, ks=9, tiles_per_k=12, frames=30, pipeline=3, credit=3, events=None, speed=None):
    """A step simulation of the broker's use of :func:`assign`: every worker renders one task
    per step (``speed`` < 1: slower), a frame's tasks are queued k-major (as task_tiles), a new
    frame is queued when one completes (``pipeline`` frames open), workers join / leave at the
    steps of ``events`` (a leaver's tasks go back to the front of the queue). Returns the set
    builds of every completed frame, the number of steps a worker sat idle while tasks waited,
    and the order in which lost tasks were re-queued."""
    speed = speed or {}
    events = events or {}
    ws = {}

    def join(wid):
        ws[wid] = {"inflight": collections.deque(), "cache": set(), "acc": 0.0}
    for i in range(workers):
        join(f"w{i:02d}")
    queue, remaining, builds, done, idle, requeued = TaskQueue(), {}, collections.Counter(), [], 0, []
    nxt = [0]

    def submit():
        f = nxt[0]
        nxt[0] += 1
        remaining[f] = ks * tiles_per_k
        for k in range(ks):
            for t in range(tiles_per_k):
                queue.append((f, k, t), (f, k))
    for _ in range(pipeline):
        submit()
    step = 0
    while len(done) < frames:
        step += 1
        assert step < 100_000, "stalled"
        for kind, wid in events.get(step, ()):
            if kind == "join":
                join(wid)
            else:
                lost = list(ws.pop(wid)["inflight"])
                requeued.append((lost, list(queue)))
                queue.push_front([(t, (t[0], t[1])) for t in lost])
        views = [WorkerView(wid, credit, len(w["inflight"]),
                            frozenset(w["cache"]) | {(t[0], t[1]) for t in w["inflight"]})
                 for wid, w in ws.items()]
        free = sum(v.free for v in views)  # as the broker: at most `free` tasks of each set
        out = assign([PendingTask(t, (t[0], t[1])) for t in queue.heads(free)], views)
        for t, wid in out:
            ws[wid]["inflight"].append(t)
        for t, _ in out:
            queue.remove(t)
        idle += bool(queue) and sum(1 for w in ws.values() if not w["inflight"])
        for wid, w in ws.items():
            w["acc"] += speed.get(wid, 1.0)
            while w["acc"] >= 1.0 and w["inflight"]:
                w["acc"] -= 1.0
                f, k, _ = t = w["inflight"].popleft()
                if (f, k) not in w["cache"]:
                    w["cache"].add((f, k))
                    builds[f] += 1
                remaining[f] -= 1
                if remaining[f] == 0:
                    done.append(f)
                    submit()
            if not w["inflight"]:
                w["acc"] = 0.0
    return [builds[f] for f in done], idle, requeued


def test_set_builds_per_frame_at_most_the_sets_of_the_frame():
    builds, idle, _ = _simulate()
    assert max(builds) <= 9, builds
    assert idle == 0


def test_set_builds_bounded_when_workers_join_and_leave():
    events = {20: [("leave", "w03")], 45: [("join", "x1")], 70: [("leave", "w07"), ("join", "x2")],
              71: [("leave", "w11")]}
    builds, idle, requeued = _simulate(frames=40, events=events)
    changes = sum(len(v) for v in events.values())
    assert max(builds) <= 9 + changes, builds
    assert sum(builds) <= 9 * len(builds) + changes, builds  # each change costs at most one build
    assert idle == 0
    for lost, _ in requeued:
        assert lost  # the leavers had work in flight


def test_requeue_order_after_a_worker_dies_is_unchanged():
    events = {25: [("leave", "w05")]}
    _, _, requeued = _simulate(frames=6, events=events)
    (lost, before), = requeued
    q = _queue(before)
    q.push_front([(t, (t[0], t[1])) for t in lost])
    after = list(q)
    assert after[:len(lost)] == lost and after[len(lost):] == [t for t in before if t not in lost]
    # and assign hands the lost tasks out in that order: a new worker takes them first
    pending = [PendingTask(t, (t[0], t[1])) for t in q.heads(len(lost))]
    out = assign(pending, [WorkerView("new", len(lost))])
    assert [t for t, _ in out] == lost


def test_no_worker_idle_while_work_waits_even_with_slow_workers():
    builds, idle, _ = _simulate(frames=20, speed={"w01": 0.3, "w05": 0.5}, pipeline=2)
    assert idle == 0
    # more workers than the sets in flight: every worker still works (sets are shared)
    builds, idle, _ = _simulate(workers=40, frames=10)
    assert idle == 0


# ------------------------------------------------------------------ fault accounting
def test_effective_credit_grows_with_delivered_results():
    led = FaultLedger(initial_credit=2)
    assert led.credit("r", 4096) == 2  # a new worker: small, whatever it advertises
    assert led.credit("g", 1) == 1
    for _ in range(5):
        led.delivered("g")
    assert led.credit("g", 4096) == 7 and led.credit("g", 3) == 3
    led.failed("g", "x")
    assert led.credit("g", 4096) == 2 + 5 // 2


def test_quarantine_after_consecutive_faults_once():
    led = FaultLedger(quarantine_after=3)
    assert led.failed("r", "bad result") is None
    led.delivered("r")  # a success in between resets the count
    assert led.failed("r", "bad result") is None
    assert led.timed_out("r") is None
    why = led.failed("r", "bad result: 7 pixels, tile has 12")
    assert why and "3 consecutive" in why and "7 pixels" in why
    assert led.quarantined("r") == why
    assert led.failed("r", "again") is None  # reported once
    led.forget("r")
    assert led.quarantined("r") == why  # a quarantined worker is remembered
    led.delivered("g")
    led.forget("g")
    assert "g" not in led.records


def test_task_timeout_follows_measured_task_times():
    def per_task(times, **kw):  # tasks of one pixel: the per-pixel times are the task times
        return task_timeout(TaskCost.measured(times), cap=60.0, pixels=1, **kw)

    assert per_task([]) == 60.0
    assert per_task([0.05] * 10) == TIMEOUT_FLOOR
    assert per_task([1.0, 1.0, 50.0], factor=8) == 8.0
    assert per_task([30.0] * 3) == 60.0


def test_task_timeout_scales_with_the_tasks_pixels_and_allows_for_a_set_build():
    # recent tasks: 1e-5 s a pixel (quarter-size tiles of 768 pixels took ~8 ms each)
    cost = TaskCost.measured([1e-5] * 20, set_builds=[[0.01, 0.6, 0.012]])  # one view's preparation
    assert cost.set_build == 0.6
    small = task_timeout(cost, cap=60.0, pixels=768)
    assert small == TIMEOUT_FLOOR  # 8 × 7.7 ms: the floor
    full = task_timeout(cost, cap=60.0, pixels=12288 * 16)  # a tile 256× the size
    assert full == pytest.approx(8 * 1e-5 * 12288 * 16)
    # the first task of a set on a worker: the longest recent set build is added before the factor
    assert task_timeout(cost, cap=60.0, pixels=768, builds_set=True) == pytest.approx(8 * (768e-5 + 0.6))
    assert task_timeout(cost, cap=4.0, pixels=768, builds_set=True) == 4.0  # never past the cap
    # no set build measured yet: nothing added
    assert task_timeout(TaskCost.measured([1e-5] * 20), cap=60.0, pixels=768, builds_set=True) == TIMEOUT_FLOOR
    # only the last TIMEOUT_WINDOW times count
    assert TaskCost.measured([1.0] * 500 + [1e-5] * 64).per_pixel == 1e-5
    assert TaskCost.measured([1e-5], [[5.0] + [0.01] * 64]).set_build == 0.01


def test_one_worker_reporting_huge_set_builds_cannot_lengthen_every_timeout():
    """Issue 20: a peer may report anything; the allowance is the lower median over the workers
    of each one's longest recent build, so one liar among honest workers moves nothing."""
    honest = [[0.01, 0.9, 0.012], [0.011, 0.7]]
    assert TaskCost.measured([1e-5], honest + [[1e6]]).set_build == 0.9
    assert TaskCost.measured([1e-5], [[0.9], [1e6]]).set_build == 0.9  # one honest, one liar
    assert TaskCost.measured([1e-5], [[], [0.3]]).set_build == 0.3  # a worker with no builds yet
    assert TaskCost.measured([1e-5], [[], []]).set_build == 0.0


def test_a_late_answer_lifts_a_quarantine_caused_by_timeouts_alone():
    led = FaultLedger(quarantine_after=3)
    for _ in range(2):
        assert led.timed_out("slow") is None
    assert led.timed_out("slow")
    assert led.quarantined("slow")
    assert led.answered("slow") is True and led.quarantined("slow") is None
    # a worker quarantined for bad results stays quarantined whatever it answers later
    led.failed("bad", "x")
    led.timed_out("bad")
    assert led.failed("bad", "y")
    assert led.answered("bad") is False and led.quarantined("bad")


def test_tasks_lost_by_an_untrusted_worker_go_to_trusted_workers():
    lost = PendingTask(0, (0, 0, 1), trusted_only=True)
    other = PendingTask(1, (0, 0, 2))
    ws = [WorkerView("new", 2, 0, trusted=False), WorkerView("good", 2, 2, trusted=True)]
    assert assign([lost, other], ws) == [(1, "new")]  # the lost task waits for "good"
    ws = [WorkerView("new", 2, 0, trusted=False), WorkerView("good", 2, 1, trusted=True)]
    assert sorted(assign([lost, other], ws)) == [(0, "good"), (1, "new")]
    # nobody has delivered yet (a fresh cluster): trust restricts nobody
    assert assign([lost], [WorkerView("new", 2, 0, trusted=False)]) == [(0, "new")]
    led = FaultLedger()
    assert not led.trusted("w")
    led.delivered("w")
    assert led.trusted("w")


def test_a_set_held_by_an_untrusted_worker_does_not_starve():
    """A silent peer that holds set 1 and all its credit (issue 20): a busy trusted worker takes
    set 1's tasks instead of waiting for that holder to free a slot (which never happens)."""
    t = PendingTask(0, (0, 0, 1))
    held = frozenset({(0, 0, 1)})
    rogue = WorkerView("rogue", 2, 2, held, trusted=False)
    good = WorkerView("good", 3, 2, frozenset({(0, 0, 2)}), trusted=True)
    assert assign([t], [rogue, good]) == [(0, "good")]
    # a trusted holder is still waited for by a busy worker (no second copy of its set)
    assert assign([t], [WorkerView("owner", 2, 2, held, trusted=True), good]) == []
    # an untrusted worker keeps deferring to any holder
    assert assign([t], [rogue, WorkerView("new", 2, 1, trusted=False), good]) == [(0, "good")]


def test_a_worker_in_a_fault_streak_is_not_trusted():
    led = FaultLedger()
    led.delivered("w")
    assert led.trusted("w")
    led.timed_out("w")
    assert not led.trusted("w")
    led.answered("w")
    assert led.trusted("w")
    led.failed("w", "bad result")
    assert not led.trusted("w")
    led.delivered("w")
    assert led.trusted("w")


def test_a_given_back_task_goes_before_own_and_fresh_sets():
    """The stall issue 20's serve-rogue case found: a task a silent rogue gave back (timed out)
    holds up its frame; a busy good worker that holds sets of newer frames, with fresh unheld
    sets queued too, must take the given-back task first or no frame is ever published."""
    rogue_set, own, fresh = (0, 13, 5), (0, 25, 3), (0, 26, 0)
    lost = PendingTask("13/5", rogue_set, avoid=frozenset({"rogue"}), trusted_only=True)
    queue = [lost, PendingTask("25/3", own), PendingTask("26/0", fresh)]
    rogue = WorkerView("rogue", 2, 2, frozenset({rogue_set}), trusted=False)
    good = WorkerView("good", 3, 2, frozenset({own}), trusted=True)
    assert assign(queue, [rogue, good], limit=1) == [("13/5", "good")]
    # with no given-back task the good worker keeps to its own set first (set affinity)
    assert assign(queue[1:], [rogue, good], limit=1) == [("25/3", "good")]
