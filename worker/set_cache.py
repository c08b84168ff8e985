"""The worker's cache of per-set preprocessing: P_k and C_k of each frame (Wald et al. 2002 §4.2),
built many at a time.

A set is a pure function of (configuration, frame seed, accumulation index, k). Tasks of the
same k on the same worker reuse it. While the camera is still, every accumulated frame needs
new sets; built one per task, a set costs several ms of per-call overhead on a few hundred rays
(cornell-box-sphere: 5.1 ms alone, 2.9 ms a set in a batch of 16). So a miss builds, in one
batch, the set asked for together with the sets of the same frame that this worker asked for
in its latest frame (the master prefers to send a k to the worker that holds its set, so a
worker's k's change little from frame to frame): one worker rendering every k builds a frame's
sets in one call, a worker of a cluster about its own.

A worker of a large cluster holds one or two k's, so its batch would stay small: it also builds
the same k's of the next accumulation frames (``later``: their sets are known in advance, the
frames of an accumulation being consecutive blocks of one stream), whole frames until the batch
holds BATCH_TARGET sets or more (at most half the cache). The caller offers at most as many later
frames as the accumulation has already shown, so a worker holding one k builds frames 1-2, 3-6,
7-14, then 16 at a time, and a camera that moves wastes at most the set work already spent since
it stopped. The price: the task that misses waits for the whole batch (16 sets: ~50 ms on
cornell-box-sphere, once per 16 frames). A thread that needs a set another thread is building
waits for it.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Sequence

HISTORY_FRAMES = 8  # recent frames (of all configurations) whose requested k's are remembered
BATCH_TARGET = 16  # sets a batch reaches with later frames (per-set cost flattens past ~16)


class FrameSets:
    """Sets keyed ((configuration, seed, index), k); ``configuration`` is a tuple whose first
    item names the kind of set (``"vpl"``, ``"photons"``)."""

    def __init__(self, max_sets: int):
        self._max = max_sets
        self._sets: OrderedDict[tuple, object] = OrderedDict()
        self._building: set[tuple] = set()
        self._history: OrderedDict[tuple, set[int]] = OrderedDict()  # frame -> k's asked for
        self._cond = threading.Condition()
        self.stats = {"sets_built": 0, "set_hits": 0}
        self.version = 0  # changes whenever the held keys do (what a worker lists to its master)

    def keys(self) -> list[tuple]:
        with self._cond:
            return list(self._sets)

    def get(self, frame: tuple, k: int, sets: int, build: Callable[[list[tuple]], list],
            later: Sequence[tuple] = ()) -> object:
        """The set ``k`` of ``frame`` (configuration, seed, index): cached, or built by
        ``build(keys)`` (a list of sets, one per (frame, k) of ``keys``) with the frame's other
        predicted sets (k's in [0, sets)) and the same k's of the first frames of ``later`` (in
        order: the next frames of the accumulation), whole frames up to BATCH_TARGET sets."""
        key = (frame, k)
        with self._cond:
            self._note(frame, k)
            while True:
                hit = self._sets.get(key)
                if hit is not None:
                    self._sets.move_to_end(key)
                    if frame[0][0] == "vpl":
                        self.stats["set_hits"] += 1
                    return hit
                if key not in self._building:
                    break
                self._cond.wait()
            ks = [k] + [j for j in sorted(self._predicted(frame)) if j != k and 0 <= j < sets]
            frames = min(-(-BATCH_TARGET // len(ks)), self._max // (2 * len(ks)))  # this one and later ones
            ahead = list(later)[:max(0, frames - 1)]
            keys = [key] + [(f, j) for f in [frame] + ahead for j in ks
                            if (f, j) != key and (f, j) not in self._sets and (f, j) not in self._building]
            self._building.update(keys)
        built = None
        try:
            built = build(keys)
        finally:
            with self._cond:
                self._building.difference_update(keys)
                if built is not None:
                    for kk, s in zip(keys, built):
                        self._sets[kk] = s
                    if frame[0][0] == "vpl":
                        self.stats["sets_built"] += len(keys)
                    while len(self._sets) > self._max:
                        self._sets.popitem(last=False)
                    self.version += 1
                self._cond.notify_all()
        return built[0]

    def _note(self, frame: tuple, k: int) -> None:
        ks = self._history.get(frame)
        if ks is None:
            ks = self._history[frame] = set()
            while len(self._history) > HISTORY_FRAMES:
                self._history.popitem(last=False)
        ks.add(k)

    def _predicted(self, frame: tuple) -> set[int]:
        """The k's this worker asked for in its latest other frame of the same configuration (a
        union over several frames would grow toward every k on a worker of a cluster, whose
        scheduler moves a few k's between workers from frame to frame)."""
        for f in reversed(self._history):
            if f != frame and f[0] == frame[0]:
                return self._history[f]
        return set()

