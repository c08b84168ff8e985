"""The master's task queue: task keys in queue order, indexed by the VPL/photon set they need.

Dispatch runs after every RESULT and looks at the first ``free`` queued tasks of *each* set
(the policy's set-aware choice looks past the front, but can assign no more than ``free``
tasks of one set). Scanning a flat queue for that made every dispatch O(queued tasks), a
frame's dispatches O(tasks²): at 1920×1080 on 16 workers (~450 tasks queued over 3 frames
in flight) ~0.4 ms a RESULT, half the master's dispatch time. Here each set keeps its own
deque in queue order, and an entry's position is a sequence number (the back counts up, the
front counts down), so the policy's view costs O(sets × free) and removing an assigned task
O(tasks of its set).
"""
from __future__ import annotations

import collections
import itertools
from typing import Callable, Hashable, Iterable, Iterator


class TaskQueue:
    """Task keys, front first, each with the set key it needs; no key twice."""

    def __init__(self) -> None:
        self._pos: dict[Hashable, int] = {}  # task key -> its sequence number (queue order)
        self._set: dict[Hashable, Hashable] = {}  # task key -> set key
        self._by_set: dict[Hashable, collections.deque] = {}  # set key -> task keys, in order
        self._back = 0  # next sequence number at the back
        self._front = -1  # next sequence number at the front

    def __len__(self) -> int:
        return len(self._pos)

    def __bool__(self) -> bool:
        return bool(self._pos)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._pos

    def __iter__(self) -> Iterator[Hashable]:
        """The task keys in queue order (O(n log n): for stats and tests, not dispatch)."""
        return iter(sorted(self._pos, key=self._pos.__getitem__))

    def append(self, key: Hashable, set_key: Hashable) -> None:
        """``key`` at the back of the queue."""
        self.remove(key)
        self._pos[key] = self._back
        self._back += 1
        self._set[key] = set_key
        self._by_set.setdefault(set_key, collections.deque()).append(key)

    def push_front(self, keyed: Iterable[tuple[Hashable, Hashable]]) -> int:
        """The (task key, set key) pairs at the front, in their order (a key already queued moves
        there; a key given twice counts once). Returns how many distinct keys."""
        pairs = list(keyed)
        sets = dict(pairs)  # a key given twice: its first position, its last set key
        order = list(dict.fromkeys(k for k, _ in pairs))
        for key in reversed(order):
            self.remove(key)
            set_key = sets[key]
            self._pos[key] = self._front
            self._front -= 1
            self._set[key] = set_key
            self._by_set.setdefault(set_key, collections.deque()).appendleft(key)
        return len(order)

    def remove(self, key: Hashable) -> bool:
        """Take ``key`` out of the queue; False when it was not queued."""
        if self._pos.pop(key, None) is None:
            return False
        set_key = self._set.pop(key)
        d = self._by_set[set_key]
        if d[0] == key:  # an assigned task is nearly always the first of its set
            d.popleft()
        else:
            d.remove(key)
        if not d:
            del self._by_set[set_key]
        return True

    def remove_where(self, pred: Callable[[Hashable], bool]) -> int:
        """Take out every key with ``pred(key)`` (O(n): frames cancelled or failed). How many."""
        gone = [k for k in self._pos if pred(k)]
        for k in gone:
            self.remove(k)
        return len(gone)

    def heads(self, per_set: int) -> list[Hashable]:
        """The first ``per_set`` keys of each set, all in queue order."""
        if per_set == 1:
            out = [d[0] for d in self._by_set.values()]
        else:
            out = [k for d in self._by_set.values() for k in itertools.islice(d, per_set)]
        out.sort(key=self._pos.__getitem__)  # (heapq.merge over the deques: 10× slower here)
        return out

    def set_of(self, key: Hashable) -> Hashable:
        return self._set[key]
