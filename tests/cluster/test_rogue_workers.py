"""Rogue workers (issue 20), real processes and real ZeroMQ sockets on 127.0.0.1: a registered
worker that advertises credit 4,096, heartbeats and never answers, or one that answers every task
with a wrong-sized RESULT, cannot stop a render from finishing with the image a render without
it gives (bit-identical: see test_cluster.py). The rogue is a separate process
(bench/rogue_peer.py); it registers before the good worker so it is offered work first. No
wall-clock thresholds in the asserts: only generous timeouts against hangs.
"""
from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from igi.bench.rogue_peer import rogue_report, start_rogue
from igi.bench.stress_scenes import mini_cornell
from tests.support.cluster_helpers import env, start_worker, stop_procs, wait_until
from tests.support.paths import ROOT, SHARED
from igi.master.broker import Broker
from igi.master.inprocess import render_local

W, H = 64, 48
PARAMS = {"photons": 0}
CORNELL = SHARED / "scenes" / "cornell-box" / "scene.xml"


@pytest.fixture
def procs():
    ps = []
    yield ps
    stop_procs(ps)


@pytest.fixture(scope="module")
def reference():
    return render_local(mini_cornell(W, H), PARAMS, frames=3)


@pytest.mark.parametrize("mode", ["silent", "wrong"])
def test_rogue_worker_cannot_stop_a_render(mode, procs, tmp_path, reference, caplog):
    caplog.set_level(logging.WARNING, logger="igi.master")
    report = tmp_path / "rogue.json"
    with Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.5) as broker:
        procs.append(start_rogue(broker.endpoint, mode, report))
        assert wait_until(lambda: any(w["name"].startswith("rogue") for w in broker.workers()), 60)
        procs.append(start_worker(broker.endpoint, "good", heartbeat=0.5))
        assert broker.wait_for_workers(2, 120)
        image = broker.render_sequence(PARAMS, frames=3, timeout=300)
        stats = broker.stats()
        per = {w["name"]: w for w in stats["per_worker"]}
    got = rogue_report(report)
    assert got.get("tasks", 0) > 0, "the rogue was offered work"
    assert np.array_equal(image, reference), "same image as without the rogue"
    assert per["rogue-" + mode]["tasks_done"] == 0 and per["good"]["tasks_done"] > 0
    if mode == "silent":
        # bounded credit: a worker that never delivered holds at most the initial credit
        assert got["tasks"] <= 2
        assert per["rogue-silent"]["inflight"] <= 2
    else:
        assert stats["quarantined"] == ["rogue-wrong"]
        lines = [r.getMessage() for r in caplog.records if "quarantined" in r.getMessage()]
        assert len(lines) == 1 and "rogue-wrong" in lines[0] and "bad result" in lines[0], lines


def _igi_render(out: Path, extra=()) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "igi.master.cli", "render", str(CORNELL), "-o", str(out), "--width", str(W),
           "--height", str(H), "--frames", "3", "--workers", "1", "--photons", "0", "-q", *extra]
    return subprocess.Popen(cmd, cwd=ROOT, env=env(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.skipif(not CORNELL.exists() or not Path("/proc/net/tcp").exists(),
                    reason="needs the shared scenes and Linux /proc")
@pytest.mark.parametrize("mode", ["silent", "wrong"])
def test_igi_render_survives_a_rogue_worker(mode, procs, tmp_path):
    from igi.common.image_io import read_image

    plain = tmp_path / "plain.exr"
    p = _igi_render(plain)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err

    report = tmp_path / "rogue.json"
    out = tmp_path / "with_rogue.exr"
    r = _igi_render(out)
    procs.append(r)
    procs.append(start_rogue(f"find:{r.pid}", mode, report))
    _, err = r.communicate(timeout=600)
    assert r.returncode == 0, err
    assert "Traceback" not in err and "FrameFailed" not in err
    assert rogue_report(report).get("tasks", 0) > 0, "the rogue was offered work"
    assert np.array_equal(read_image(out), read_image(plain)), "same image as without the rogue"
