"""The live error estimate (even/odd halves) tracks the true relMSE against the reference."""
from __future__ import annotations

from igi.common.image_io import read_image
from igi.common.loader import load_scene
from igi.common.metrics import block_average, relmse
from tests.support.paths import SHARED
from igi.master.cli import ErrorTracker
from igi.master.inprocess import render_local


def test_error_estimate_within_factor_two_of_true_relmse():
    # cornell-box at 64x64: each pixel integrates an 8x8 block of the 512x512 reference, whose
    # own noise (9.7e-5 per full-res pixel) drops to ~1.5e-6 and is negligible here. From 4
    # frames on each half holds >= 2 independent frames; the estimate must then stay within
    # a factor of 2 of the true error at every checkpoint.
    scene = load_scene(SHARED / "scenes" / "cornell-box" / "scene.xml")
    ref = block_average(read_image(SHARED / "references" / "cornell-box.exr"), 8)
    tracker = ErrorTracker()
    ratios = {}

    def on_frame(i, img):
        est = tracker.add(i, img)
        if i + 1 in (4, 8, 16, 24):
            ratios[i + 1] = est / relmse(img, ref)

    render_local(scene, {}, 24, width=64, height=64, on_frame=on_frame)
    assert set(ratios) == {4, 8, 16, 24}
    for n, r in ratios.items():
        assert 0.5 <= r <= 2.0, (n, r)
