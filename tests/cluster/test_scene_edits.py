"""Many edits (issue 20): edits are folded into a new content-hashed scene blob every
``FOLD_EDITS``, so a worker that joins after 5,000 object moves gets a scene it can load and
renders; a worker connected while edits are folded keeps rendering on its own blob. Real worker
processes on loopback; the moves go through the broker's edit API exactly as the viewer's
``move`` message does (``master.viewer.move_edit`` then ``Broker.apply_edit``)."""
from __future__ import annotations

import logging

import pytest

from igi.bench.stress_scenes import mini_cornell
from tests.support.cluster_helpers import start_worker, stop_procs, wait_until
from igi.common import protocol as P
from igi.master import broker as B
from igi.master.viewer import move_edit

W, H = 64, 48


@pytest.fixture
def procs():
    ps = []
    yield ps
    stop_procs(ps)


def _move(broker, sel, i):
    d = 0.001 if i % 2 == 0 else -0.001  # back and forth: the box stays where it was
    return broker.apply_edit(move_edit(broker, sel, [d, 0.0, 0.0]))


def _frames_keep_coming(broker, count=3, timeout=120):
    seq = broker.latest_frame().seq if broker.latest_frame() else 0
    for _ in range(count):
        f = broker.wait_frame(seq, timeout)
        assert f is not None, "frames stopped"
        assert f.spec.scene_version == broker.scene_version
        seq = f.seq
    return f


def test_worker_joining_after_5000_moves_renders(procs, caplog):
    caplog.set_level(logging.WARNING, logger="igi.master")
    scene = mini_cornell(W, H)
    block = next(i for i, m in enumerate(scene.meshes) if m.name == "block_top")
    sel = {"mesh": block}
    with B.Broker(scene, bind="tcp://127.0.0.1:*", heartbeat=0.5) as broker:
        broker.start_stream({"photons": 0})
        # a worker connected while edits are folded renders on its own blob + edits
        procs.append(start_worker(broker.endpoint, "early", heartbeat=0.5))
        assert broker.wait_for_workers(1, 120)
        _frames_keep_coming(broker, 1)
        for i in range(2 * B.FOLD_EDITS + 3):
            _move(broker, sel, i)
        _frames_keep_coming(broker)
        assert broker.stats()["scene_folds"] >= 2
        stop_procs(procs)  # SIGTERM: BYE
        procs.clear()
        assert wait_until(lambda: not broker.workers(), 30)

        done = 2 * B.FOLD_EDITS + 3
        for i in range(done, 5000):
            _move(broker, sel, i)
        assert broker.scene_version == 5000
        # what a joining worker is sent: the folded blob and fewer edits than the protocol allows
        assert broker._base_version + len(broker._edits) == 5000 and len(broker._edits) < B.FOLD_EDITS
        assert len(broker._edits) < P.MAX_EDITS

        procs.append(start_worker(broker.endpoint, "late", heartbeat=0.5))
        assert broker.wait_for_workers(1, 120)
        f = _frames_keep_coming(broker, 3)
        assert f.spec.scene_version == 5000
        per = {w["name"]: w for w in broker.workers()}
        assert per["late"]["tasks_done"] > 0
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "scene_mismatch" not in text, text[:2000]
    assert "failed" not in text, text[:2000]
