"""``igi serve`` keeps streaming with a rogue worker (issue 20): real processes on loopback —
``igi serve cornell-box --workers 1`` and a registered rogue (bench/rogue_peer.py: HELLO with
credit 4,096, heartbeats, never answers). Frames are counted on the ZeroMQ feed for a window
before and after the rogue joins (bench.stress_hostile.serve_with_rogue).

Bounds are relative to the measured frame interval, never tighter than the issue's 2 s:
- the stream resumes within the issue's bound: the longest gap after the rogue joined is at
  most max(2 s, 5 x the median frame interval). A silent task is re-queued within 0.1 s of its
  timeout (floor 1.5 s), found by the master's expiry check rather than its 1 s heartbeat tick.
  Before the scheduler fix in this change a silent rogue's held-up tasks were starved by the
  sets of newer frames and no frame came out at all.
"""
from __future__ import annotations

from pathlib import Path

import pytest


pytestmark = [pytest.mark.timeout(600),
              pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="Linux loopback sockets")]


@pytest.fixture(scope="module")
def run():
    from igi.bench.stress_hostile import serve_with_rogue

    r = serve_with_rogue("cornell-box", baseline_s=5.0, window_s=10.0)
    print({k: v for k, v in r.items() if k not in ("serve_log", "state_after")})
    return r


def test_serve_keeps_streaming_with_a_silent_rogue(run):
    assert run["serve_alive"], run["serve_log"]
    assert "Traceback" not in run["serve_log"], run["serve_log"]
    assert run["rogue"].get("tasks", 0) > 0, "the rogue was offered work"
    assert run["frames_before"] >= 3 and run["frames_after"] >= 3, run


def test_serve_gap_within_the_issue_target(run):
    assert run["longest_gap_s"] <= run["bound_s"], (run["longest_gap_s"], run["bound_s"])
