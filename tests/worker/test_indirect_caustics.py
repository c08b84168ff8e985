"""Light that surfaces reflect through mirror/glass chains (L D S+ D E, worker.indirect_caustics)
is counted: in cornell-box-sphere a glass ball passes a share of the room's indirect light that
VPL shadow rays (blocked by the glass) and emitter photons cannot carry."""
from __future__ import annotations

import numpy as np
import pytest

import igi.worker.renderer as renderer
from igi.bench.quality import load_reference, reduced_reference
from igi.bench.stress_scenes import load_shared
from igi.master.inprocess import render_local


def _dark_region_ratio(monkeypatch, lensed: bool) -> float:
    """Mean of igi over the reference where the reference is below 1 (away from the emitter's
    anti-aliased edges), 16 accumulated frames at 1/4 size."""
    if not lensed:
        monkeypatch.setattr(renderer, "lensed_reflection", lambda *a, **k: np.zeros((len(a[3]), 3)))
    _, ref = load_reference("cornell-box-sphere")
    ref = reduced_reference(ref, 4)
    img = render_local(load_shared("cornell-box-sphere"), {}, 16, width=ref.shape[1], height=ref.shape[0])
    m = ref.mean(axis=2) < 1.0
    return float(img[m].mean() / ref[m].mean())


def test_light_through_the_glass_ball_is_no_longer_missing(monkeypatch):
    with_lens = _dark_region_ratio(monkeypatch, True)
    assert with_lens == pytest.approx(1.0, abs=0.02)


def test_without_the_lensed_light_the_room_reads_dark(monkeypatch):
    # the same measure without the chain gather: the path class the test above needs is real
    assert _dark_region_ratio(monkeypatch, False) < 0.97
