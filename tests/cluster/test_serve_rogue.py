"""``igi serve`` keeps streaming with a rogue worker (issue 20): real processes on loopback —
``igi serve cornell-box --workers 1`` and a registered rogue (bench/rogue_peer.py: HELLO with
credit 4,096, heartbeats, never answers). Frames are counted on the ZeroMQ feed for a window
before and after the rogue joins (bench.stress_hostile.serve_with_rogue).

The stream resumes: the tasks the rogue holds are re-queued when their timeout passes (the master's
expiry check, not its 1 s heartbeat tick) and frames keep coming after it joined. Before the
scheduler fix a silent rogue's held-up tasks were starved by the sets of newer frames and no frame
came out at all. How long the gap is (the issue's 2 s) is measured by ``igi bench stress --cases
hostile``; wall-clock bounds stay out of tests.
"""
from __future__ import annotations

from pathlib import Path

import pytest


pytestmark = [pytest.mark.timeout(600),
              pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="Linux loopback sockets")]


@pytest.fixture(scope="module")
def run():
    from igi.bench.stress_hostile import serve_with_rogue

    r = serve_with_rogue("cornell-box", baseline_s=3.0, window_s=10.0)
    print({k: v for k, v in r.items() if k not in ("serve_log", "state_after")})
    return r


def test_serve_keeps_streaming_with_a_silent_rogue(run):
    assert run["serve_alive"], run["serve_log"]
    assert "Traceback" not in run["serve_log"], run["serve_log"]
    assert run["rogue"].get("tasks", 0) > 0, "the rogue was offered work"
    assert run["frames_before"] >= 3 and run["frames_after"] >= 3, run


def test_the_tasks_a_silent_rogue_holds_are_requeued_and_frames_come_after_it(run):
    # the stream's longest gap (the 2 s) is a figure of `igi bench stress --cases hostile`, not a test: on a
    # loaded 2-core box it measured 3.6 s with the mechanism working
    assert run["requeued_from_rogue"] >= 1, run["serve_log"]
    assert run["frames_after"] >= 3, run
