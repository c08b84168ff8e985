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
        monkeypatch.setattr(renderer, "lensed_arrivals", lambda *a, **k: (np.zeros((len(a[3]), 3)), None))
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


def _ceiling_ratio(monkeypatch, photons_at_chain_ends: bool, seeds: tuple[int, ...] = (0,)) -> float:
    """igi / reference over the ceiling around the emitter (its bounding box in the reference
    grown by half its size, the emitter itself and its edges left out), 16 frames at 1/4 size
    per seed of ``seeds``, averaged (one run's ratio spreads by ~±0.025).
    That ceiling faces away from the light: besides the room's bounces it is lit by the glass
    ball imaging the bright caustic under it (L S S D S S D E, a quarter of its light)."""
    import igi.worker.final_gather as final_gather
    from scipy.ndimage import binary_dilation

    if not photons_at_chain_ends:
        # the batch holds the end points first, then the points y behind them: y's photons only
        ends = {}
        real_gather, real_photons = renderer.final_gather, final_gather.gather_photons

        def batch(*a, **k):
            ends["n"] = len(a[3])
            return real_gather(*a, **k)

        def photons_at_end_points(points, *a, **k):
            out = real_photons(points, *a, **k)
            out[ends["n"]:] = 0.0
            return out

        monkeypatch.setattr(renderer, "final_gather", batch)
        monkeypatch.setattr(final_gather, "gather_photons", photons_at_end_points)
    _, ref = load_reference("cornell-box-sphere")
    ref = reduced_reference(ref, 4)
    lum = ref.mean(axis=2)
    top = np.zeros_like(lum, bool)
    top[: lum.shape[0] // 4] = True
    ys, xs = np.nonzero((lum > 2.0) & top)
    gy, gx = (ys.max() - ys.min()) // 2 + 2, (xs.max() - xs.min()) // 2 + 2
    box = np.zeros_like(top)
    box[max(ys.min() - gy, 0):ys.max() + gy + 1, max(xs.min() - gx, 0):xs.max() + gx + 1] = True
    region = box & ~binary_dilation(lum > 1.0, iterations=2) & (lum > 0.02)
    assert region.sum() > 100
    imgs = [render_local(load_shared("cornell-box-sphere"), {"seed": seed}, 16, width=ref.shape[1],
                         height=ref.shape[0]) for seed in seeds]
    return float(np.mean([img[region].mean() for img in imgs]) / ref[region].mean())


def test_a_caustic_seen_through_the_glass_ball_lights_the_ceiling(monkeypatch):
    assert _ceiling_ratio(monkeypatch, True, seeds=(0, 1)) == pytest.approx(1.0, abs=0.07)


def test_without_photons_at_the_chain_ends_the_ceiling_reads_dark(monkeypatch):
    # the same measure without the caustic photons where the chains end: the path class is real
    assert _ceiling_ratio(monkeypatch, False) < 0.9
