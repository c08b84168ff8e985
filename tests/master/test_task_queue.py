"""The master's task queue keeps the order a flat list would, and its per-set heads are the
flat scan the policy used to get."""
from __future__ import annotations

import collections
import random

import pytest

from igi.master.task_queue import TaskQueue


def _flat_requeue_front(queue: list, lost: list) -> list:
    """The flat-list definition: the lost keys first, in order, no key twice."""
    lost = list(dict.fromkeys(lost))
    return lost + [k for k in queue if k not in set(lost)]


def _flat_heads(queue: list, set_of: dict, per_set: int) -> list:
    """The scan the broker did before the index: the first ``per_set`` keys of each set."""
    seen: collections.Counter = collections.Counter()
    out = []
    for k in queue:
        if seen[set_of[k]] < per_set:
            seen[set_of[k]] += 1
            out.append(k)
    return out


def test_push_front_keeps_order_and_no_duplicates():
    q = TaskQueue()
    for k in (5, 6, 7):
        q.append(k, k % 2)
    assert q.push_front([(3, 1), (6, 0)]) == 2
    assert list(q) == [3, 6, 5, 7]
    q = TaskQueue()
    assert q.push_front([(2, 0), (1, 0), (2, 0)]) == 2
    assert list(q) == [2, 1] and len(q) == 2
    assert q.push_front([]) == 0 and list(q) == [2, 1]


def test_remove_and_membership():
    q = TaskQueue()
    q.append("a", 0)
    q.append("b", 0)
    assert "a" in q and q.remove("a") and "a" not in q
    assert not q.remove("a")  # not queued: nothing happens
    assert list(q) == ["b"] and q.heads(5) == ["b"]
    assert q.remove("b") and not q and q.heads(3) == []


def test_append_of_a_queued_key_moves_it_to_the_back():
    q = TaskQueue()
    for k in "abc":
        q.append(k, 0)
    q.append("a", 1)
    assert list(q) == ["b", "c", "a"] and q.set_of("a") == 1 and q.heads(1) == ["b", "a"]


@pytest.mark.parametrize("seed", range(8))
def test_random_operations_match_the_flat_queue(seed):
    rng = random.Random(seed)
    q, flat, set_of = TaskQueue(), [], {}
    nxt = 0
    for _ in range(600):
        op = rng.random()
        if op < 0.45:  # a frame's tasks at the back, set-major like task_tiles
            for _ in range(rng.randint(1, 6)):
                k, s = (nxt, rng.randint(0, 40)), rng.randint(0, 7)
                nxt += 1
                q.append(k, s)
                flat.append(k)
                set_of[k] = s
        elif op < 0.6 and flat:  # lost tasks to the front (some queued, some given twice)
            lost = rng.sample(list(set_of), min(len(set_of), rng.randint(1, 5)))
            lost += lost[:1]
            q.push_front([(k, set_of[k]) for k in lost])
            flat = _flat_requeue_front(flat, lost)
        elif op < 0.85 and flat:  # assignments: one of the heads the policy sees
            heads = q.heads(rng.randint(1, 3))
            k = rng.choice(heads)
            assert q.remove(k)
            flat.remove(k)
        elif flat:  # a frame cancelled
            gone = rng.choice(flat)[1]
            assert q.remove_where(lambda k: k[1] == gone) == sum(1 for k in flat if k[1] == gone)
            flat = [k for k in flat if k[1] != gone]
        assert len(q) == len(flat)
        assert list(q) == flat
        for per_set in (1, 2, 5):
            assert q.heads(per_set) == _flat_heads(flat, set_of, per_set)
