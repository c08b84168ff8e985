"""common.gc_policy: long-lived objects leave the collector's view, garbage does not."""
from __future__ import annotations

import gc
import weakref

import pytest

from igi.common import gc_policy


class _Node:
    def __init__(self):
        self.other = None


def _cycle() -> weakref.ref:
    a, b = _Node(), _Node()
    a.other, b.other = b, a  # only the cyclic collector frees these
    return weakref.ref(a), a


@pytest.fixture(autouse=True)
def _restore_gc():
    threshold = gc.get_threshold()
    yield
    gc.unfreeze()
    gc.set_threshold(*threshold)


def test_garbage_cycles_are_collected_before_the_freeze():
    ref, a = _cycle()
    del a
    gc_policy.settle_long_lived()
    assert ref() is None  # collected, not frozen alive


def test_live_objects_are_frozen_and_a_later_settle_collects_them_once_dropped():
    ref, a = _cycle()
    frozen = gc_policy.settle_long_lived()
    assert frozen >= 2
    del a
    gc.collect()
    assert ref() is not None  # frozen: out of the full collection's view
    gc_policy.settle_long_lived()
    assert ref() is None


def test_young_collections_run_less_often_but_never_more():
    gc.set_threshold(700, 10, 10)
    gc_policy.settle_long_lived()
    assert gc.get_threshold() == (gc_policy.YOUNG_THRESHOLD, 10, 10)
    gc.set_threshold(5 * gc_policy.YOUNG_THRESHOLD, 10, 10)
    gc_policy.settle_long_lived()
    assert gc.get_threshold()[0] == 5 * gc_policy.YOUNG_THRESHOLD
