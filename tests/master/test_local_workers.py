"""master.local_workers.local_cluster: a loopback master with N local worker processes — a
worker that dies while starting is a clear UsageError, every worker dying mid-render cancels
the frames instead of hanging, and nothing outlives the block."""
from __future__ import annotations

import sys

import pytest

from igi.common import bundled
from igi.common.loader import load_scene
from igi.master import local_workers
from igi.master.broker import FrameCancelled
from igi.master.errors import UsageError
from igi.master.local_workers import local_cluster


def test_a_worker_that_dies_while_starting_is_a_usage_error(monkeypatch):
    monkeypatch.setattr(local_workers, "worker_command", lambda *a, **k: [sys.executable, "-c", "raise SystemExit(3)"])
    with pytest.raises(UsageError, match="exited with status 3"):
        with local_cluster(load_scene(bundled.resolve("cornell-box")), 2):
            pytest.fail("the block ran without workers")


def test_no_workers_is_refused():
    with pytest.raises(UsageError, match="at least one worker"):
        with local_cluster(load_scene(bundled.resolve("cornell-box")), 0):
            pass


def test_every_worker_dying_mid_render_cancels_the_frames_and_stops_everything():
    with local_cluster(load_scene(bundled.resolve("cornell-box")), 1) as cluster:
        procs = list(cluster.workers.procs)
        cluster.broker.render_sequence({"photons": 0}, frames=1, width=16, height=16)  # joined and rendering
        procs[0].kill()
        with pytest.raises(FrameCancelled):
            cluster.broker.render_sequence({"photons": 0}, frames=10_000, width=16, height=16, timeout=60)
        assert cluster.all_exited.is_set()
    assert all(p.poll() is not None for p in procs)
