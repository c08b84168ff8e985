"""The master loads the compiled kernels of its frame path before its first frame
(master.kernels.warm): after warm_up_master the wire decode, the discontinuity buffer's
finish pass, the accumulation sums and the filter selection have a compiled signature (checked in a fresh process,
where nothing else has called them); the broker starts the warm-up as it starts, once per
process."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

CHECK = """
import json
from numba.core.registry import CPUDispatcher
import igi.master.kernels.accumulate as a, igi.master.kernels.discontinuity as d
import igi.master.kernels.filter_selection as fs
import igi.common.kernels.wire_decode as w
from igi.master.kernels.warm import warm_up_master

def public(mod):
    return {f"{mod.__name__}.{k}": v for k, v in vars(mod).items() if isinstance(v, CPUDispatcher)
            and v.__module__ == mod.__name__ and v.targetoptions.get("inline") != "always"}

used = {**public(a), **public(d), **public(w), **public(fs)}
before = sorted(k for k, v in used.items() if v.signatures)
warm_up_master()
after = sorted(k for k, v in used.items() if v.signatures)
print(json.dumps({"before": before, "after": after}))
"""


def test_warm_up_master_loads_the_kernels_of_a_frame_in_a_fresh_process():
    out = subprocess.run([sys.executable, "-c", CHECK], check=True, capture_output=True, text=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["before"] == []  # a fresh process: nothing loaded yet (the check is not vacuous)
    # the frame path's kernels: decode, the discontinuity buffer + compose, the accumulation sums
    # (the edge-stopping guide's planes are written by finish_sub's pass: guide_planes is off the path)
    for name in ("igi.common.kernels.wire_decode.decode_tile", "igi.master.kernels.discontinuity.finish_sub",
                 "igi.master.kernels.accumulate.add_frame", "igi.master.kernels.accumulate.mean",
                 "igi.master.kernels.filter_selection.select"):
        assert name in res["after"], name


def test_the_broker_starts_the_warm_up_as_it_starts(monkeypatch):
    import igi.master.broker as broker_mod
    from tests.support.scenes_synthetic import furnace_box

    calls = []
    monkeypatch.setattr(broker_mod, "warm_up_master_in_background", lambda: calls.append(1))
    b = broker_mod.Broker(furnace_box(0.5, 1.0, 8, 8), bind="tcp://127.0.0.1:*").start()
    try:
        assert calls == [1]
    finally:
        b.stop()


EXIT_DURING_WARM_UP = """
import atexit, sys, threading, time
seen, tiles, inside = [], [], threading.Event()
from igi.master.frame_assembly import FrameAssembler
add_wire = FrameAssembler.add_wire

def slow_add_wire(self, *args, **kw):  # the warm-up's first step, held while the process exits
    tiles.append(1)
    inside.set()
    time.sleep(1.0)
    return add_wire(self, *args, **kw)

FrameAssembler.add_wire = slow_add_wire
atexit.register(lambda: print("alive", seen[0].is_alive(), "tiles", len(tiles)))  # runs after warm's own handler
from igi.master.kernels.warm import warm_up_master_in_background
seen.append(warm_up_master_in_background())
inside.wait(120)
sys.exit(0)  # in the middle of the warm-up's first step
"""


def test_a_process_exiting_during_the_warm_up_stops_it_at_its_next_step_and_waits(tmp_path):
    # LLVM's destructors running under a compiling thread aborted a one-frame igi render (CI, stop 62): the exit
    # handler asks the warm-up to stop and waits for it. It stops after the step it is in: one of the 25 tiles.
    out = subprocess.run([sys.executable, "-c", EXIT_DURING_WARM_UP], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "alive False tiles 1" in out.stdout, out.stdout


def test_a_failing_master_warm_up_is_logged_not_raised(monkeypatch, caplog):
    import logging

    from igi.master.kernels import warm

    def boom(stop=None):
        raise RuntimeError("no kernels today")

    monkeypatch.setattr(warm, "warm_up_master", boom)
    monkeypatch.setattr(warm, "_started", None)
    with caplog.at_level(logging.INFO, logger="igi.master.kernels.warm"):
        warm.warm_up_master_in_background().join(10)
    assert "master warm-up failed" in caplog.text and "no kernels today" in caplog.text


def test_warm_up_master_returns_its_duration():
    from igi.master.kernels.warm import warm_up_master

    t = warm_up_master()
    assert np.isfinite(t) and t >= 0


def test_the_warm_up_runs_once_per_process(monkeypatch):
    from igi.master.kernels import warm

    calls = []
    monkeypatch.setattr(warm, "warm_up_master", lambda stop=None: calls.append(1) or 0.0)
    monkeypatch.setattr(warm, "_started", None)
    first = warm.warm_up_master_in_background()
    first.join(10)
    assert warm.warm_up_master_in_background() is first
    assert calls == [1]
