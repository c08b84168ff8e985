"""worker.set_cache.FrameSets: a miss builds the frame's predicted sets in one batch (with the
same k's of later frames while the batch is small), each set is built once whatever the threads,
and a failed build leaves nothing behind."""
from __future__ import annotations

import threading

import pytest

from igi.worker.set_cache import BATCH_TARGET, FrameSets

CFG = ("vpl", 0, "config")


def _recording():
    calls = []

    def build(frame):
        def b(keys):
            assert keys[0][0] == frame  # the set asked for comes first
            calls.append((frame, [k for f, k in keys if f == frame]))
            return list(keys)
        return b
    return calls, build


def test_a_frame_builds_together_the_sets_the_last_frames_asked_for():
    cache, (calls, build) = FrameSets(64), _recording()
    f1, f2 = (CFG, 7, 1), (CFG, 7, 2)
    for k in (2, 5, 3):
        assert cache.get(f1, k, 9, build(f1)) == (f1, k)
    assert calls == [(f1, [2]), (f1, [5]), (f1, [3])]  # nothing to predict from yet
    calls.clear()
    assert cache.get(f2, 5, 9, build(f2)) == (f2, 5)
    assert calls == [(f2, [5, 2, 3])]  # the one asked for first, then the predicted ones
    for k in (2, 3):
        assert cache.get(f2, k, 9, build(f2)) == (f2, k)
    assert len(calls) == 1 and cache.stats == {"sets_built": 6, "set_hits": 2}


def test_prediction_follows_the_latest_frame_not_a_union_of_frames():
    """A worker of a cluster whose k's drift between frames predicts from its latest frame only:
    a union over frames would grow toward every k."""
    cache, (calls, build) = FrameSets(64), _recording()
    for index, ks in ((1, (0, 1)), (2, (2, 3)), (3, (4,))):
        for k in ks:
            cache.get((CFG, 7, index), k, 9, build((CFG, 7, index)))
    calls.clear()
    cache.get((CFG, 7, 4), 8, 9, build((CFG, 7, 4)))
    assert calls == [((CFG, 7, 4), [8, 4])]


def test_prediction_stays_within_the_frames_sets_and_its_configuration():
    cache, (calls, build) = FrameSets(64), _recording()
    other = (("vpl", 0, "other config"), 7, 1)
    cache.get(other, 1, 9, build(other))
    cache.get((CFG, 7, 1), 8, 9, build((CFG, 7, 1)))
    calls.clear()
    cache.get((CFG, 7, 2), 0, 4, build((CFG, 7, 2)))  # interleave 2 now: k 8 does not exist
    assert calls == [((CFG, 7, 2), [0])]


def test_a_thread_waits_for_the_set_another_thread_is_building():
    cache = FrameSets(64)
    f1, f2 = (CFG, 1, 1), (CFG, 1, 2)
    for k in range(4):
        cache.get(f1, k, 4, lambda ks: [object() for _ in ks])
    started, release, built = threading.Event(), threading.Event(), []

    def slow(keys):
        built.append([k for _, k in keys])
        started.set()
        release.wait(10)
        return [("set", k) for _, k in keys]

    got = {}
    a = threading.Thread(target=lambda: got.__setitem__("a", cache.get(f2, 0, 4, slow)))
    a.start()
    assert started.wait(10)
    b = threading.Thread(target=lambda: got.__setitem__("b", cache.get(f2, 2, 4, slow)))
    b.start()
    b.join(0.2)
    assert b.is_alive()  # waiting on a's batch, not building its own
    release.set()
    a.join(10)
    b.join(10)
    assert built == [[0, 1, 2, 3]] and got == {"a": ("set", 0), "b": ("set", 2)}


def test_a_failed_build_leaves_no_set_and_no_waiter_behind():
    cache = FrameSets(64)
    f = (CFG, 3, 0)

    def broken(ks):
        raise RuntimeError("no light")

    with pytest.raises(RuntimeError, match="no light"):
        cache.get(f, 1, 4, broken)
    assert cache.keys() == []
    assert cache.get(f, 1, 4, lambda ks: ["ok"] * len(ks)) == "ok"


def test_the_cache_keeps_the_most_recent_sets():
    cache = FrameSets(3)
    for i in range(5):
        cache.get((CFG, i, 0), 0, 1, lambda ks: ["s"] * len(ks))
    assert [key[0][1] for key in cache.keys()] == [2, 3, 4]


def _frames(first: int, count: int) -> list[tuple]:
    return [(CFG, 7 + i, i) for i in range(first, first + count)]


def _keys_recorder():
    """(the key lists of every build, a build that records its keys and returns them as sets)."""
    keys_built = []

    def build(keys):
        keys_built.append(list(keys))
        return list(keys)
    return keys_built, build


def test_a_worker_holding_one_k_builds_it_for_later_frames_in_the_same_batch():
    """A worker of a large cluster holds one k: its batch takes the k of the later frames it is
    offered, up to BATCH_TARGET sets, and those frames then find their sets cached."""
    cache, (keys_built, build) = FrameSets(256), _keys_recorder()
    f1, f2 = _frames(1, 2)
    cache.get(f1, 4, 9, build)
    keys_built.clear()
    later = _frames(3, 40)
    assert cache.get(f2, 4, 9, build, later) == (f2, 4)
    assert keys_built == [[(f, 4) for f in [f2] + later[:BATCH_TARGET - 1]]]
    for f in later[:BATCH_TARGET - 1]:
        assert cache.get(f, 4, 9, build, _frames(f[2] + 1, 40)) == (f, 4)
    assert len(keys_built) == 1  # every later frame found its set
    assert cache.stats == {"sets_built": 1 + BATCH_TARGET, "set_hits": BATCH_TARGET - 1}


def test_a_worker_holding_many_ks_builds_only_its_frame():
    cache, (keys_built, build) = FrameSets(256), _keys_recorder()
    f1, f2 = _frames(1, 2)
    for k in range(BATCH_TARGET):
        cache.get(f1, k, 25, build)
    keys_built.clear()
    cache.get(f2, 0, 25, build, _frames(3, 8))
    assert keys_built == [[(f2, k) for k in range(BATCH_TARGET)]]


def test_later_frames_fill_the_batch_by_whole_frames_and_skip_sets_held_or_in_building():
    cache, (keys_built, build) = FrameSets(256), _keys_recorder()
    f1, f2, f3, f4 = _frames(1, 4)
    cache.get(f3, 1, 9, build)  # already held: not built again
    for k in (0, 1, 2):  # the latest frame: k's 0, 1, 2 predicted
        cache.get(f1, k, 9, build)
    keys_built.clear()
    cache.get(f2, 2, 9, build, [f3, f4, *_frames(5, 10)])
    per_frame = 3
    frames = -(-BATCH_TARGET // per_frame)  # this frame and whole later frames up to the target
    expect = [(f2, 2), (f2, 0), (f2, 1)] + [(f, k) for f in _frames(3, frames - 1) for k in (2, 0, 1)
                                              if (f, k) != (f3, 1)]
    assert keys_built == [expect]


def test_later_frames_take_at_most_half_the_cache():
    cache, (keys_built, build) = FrameSets(8), _keys_recorder()
    f1, f2 = _frames(1, 2)
    cache.get(f1, 0, 9, build)
    keys_built.clear()
    cache.get(f2, 0, 9, build, _frames(3, 40))
    assert len(keys_built[0]) == 4  # not BATCH_TARGET: half of an 8-set cache


def test_later_frames_skip_a_set_another_thread_is_building():
    cache = FrameSets(256)
    f1, f2, f3 = _frames(1, 3)
    cache.get(f1, 0, 9, lambda keys: list(keys))
    started, release = threading.Event(), threading.Event()

    def slow(keys):
        started.set()
        release.wait(10)
        return list(keys)

    a = threading.Thread(target=lambda: cache.get(f3, 0, 9, slow))  # f3's set, in building
    a.start()
    assert started.wait(10)

    built, build = _keys_recorder()
    cache.get(f2, 0, 9, build, [f3, *_frames(4, 30)])
    release.set()
    a.join(10)
    assert (f3, 0) not in built[0] and (f2, 0) in built[0] and (_frames(4, 1)[0], 0) in built[0]


def test_the_version_moves_exactly_when_the_held_sets_change():
    cache, (_, build) = FrameSets(4), _recording()
    f = (CFG, 7, 1)
    v0 = cache.version
    cache.get(f, 0, 9, build(f))
    v1 = cache.version
    assert v1 != v0 and cache.keys() == [(f, 0)]
    cache.get(f, 0, 9, build(f))  # a hit changes nothing
    assert cache.version == v1
    for k in range(1, 6):  # builds past the limit evict: each changes the keys
        before = (cache.version, cache.keys())
        cache.get(f, k, 9, build(f))
        assert cache.version != before[0] and cache.keys() != before[1]
