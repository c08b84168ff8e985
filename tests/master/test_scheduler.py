"""The scheduling policy alone: a pure function of pending tasks and worker views."""
from __future__ import annotations

from master.scheduler import PendingTask, WorkerView, assign, credit_for, requeue_front


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
    assert out == [(0, "a"), (1, "a"), (2, "b"), (3, "b")]


def test_affinity_falls_back_when_the_holder_is_full():
    ws = [WorkerView("a", 1, 1, frozenset({(0, 0, 1)})), WorkerView("b", 3)]
    assert assign(tasks((0, 0, 1)), ws) == [(0, "b")]


def test_limit():
    ws = [WorkerView("a", 10)]
    assert len(assign(tasks(*[(0, 0, 0)] * 8), ws, limit=3)) == 3


def test_requeue_front_keeps_order_and_no_duplicates():
    assert requeue_front([5, 6, 7], [3, 6]) == [3, 6, 5, 7]
    assert requeue_front([], [2, 1, 2]) == [2, 1]
    assert requeue_front([1, 2], []) == [1, 2]


def test_requeued_tasks_are_assigned_first():
    queue = requeue_front([("f", 2), ("f", 3)], [("f", 0)])
    pending = [PendingTask(key, (0, 0, key[1])) for key in queue]
    assert assign(pending, [WorkerView("a", 1)]) == [(("f", 0), "a")]


def test_default_credit_is_three_per_thread():
    assert credit_for(1) == 3 and credit_for(4) == 12 and credit_for(0) == 1
