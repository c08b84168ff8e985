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


@pytest.mark.parametrize("compiled, expect", [(True, "in 0 s"), (False, "in 1 s"), (None, "in 1 s")])
def test_workers_get_the_first_runs_time_unless_the_kernels_are_known_compiled(monkeypatch, compiled, expect):
    """Local workers compile the kernels before their HELLO on a cold cache: the master waits
    FIRST_RUN_HELLO_TIMEOUT for them unless compiled_before() says True (None — cannot be told,
    as for a read-only install — waits the long time too; a dead worker is seen at once)."""
    from igi.worker.kernels import warm

    class NoOne:
        def wait_for_workers(self, count, timeout):
            return False

        def workers(self):
            return []

    class Alive:
        def check(self):
            pass

    monkeypatch.setattr(warm, "compiled_before", lambda: compiled)
    monkeypatch.setattr(local_workers, "HELLO_TIMEOUT", 0.2)
    monkeypatch.setattr(local_workers, "FIRST_RUN_HELLO_TIMEOUT", 1.2)
    with pytest.raises(UsageError, match=f"only 0 of 1 local workers connected {expect}"):
        local_workers.wait_workers(NoOne(), Alive(), 1)
