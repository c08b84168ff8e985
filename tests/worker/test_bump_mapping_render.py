"""Normal and bump maps (tests/data/bump/bump.xml: a floor rippled by a normal map over a diffuse,
a back wall dimpled by a height map over a rough plastic, lit from low at the side) rendered as
Mitsuba 3's path tracer renders them (bump_ref.exr): the relief's light and shade where the old
fallback, the nested BSDF alone, drew both flat."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from igi.common.image_io import read_image
from igi.common.loader import load_scene
from igi.common.metrics import block_average, relmse
from igi.master.inprocess import render_local

DATA = Path(__file__).resolve().parents[1] / "data" / "bump"


def _ripple_contrast(img: np.ndarray) -> float:
    """The floor's light and shade across the ripples: the spread of the column means of a
    band of the floor, over their mean."""
    band = img[int(img.shape[0] * 0.8):, :, :].mean(axis=(0, 2))
    return float(band.std() / band.mean())


def test_normal_and_bump_mapped_surfaces_render_as_mitsubas():
    scene = load_scene(DATA / "bump.xml")
    assert not scene.warnings, scene.warnings
    assert [m.normal_map is not None for m in scene.materials].count(True) == 1
    assert [m.bump_map is not None for m in scene.materials].count(True) == 1
    ref = block_average(read_image(DATA / "bump_ref.exr"), 2)
    H, W = ref.shape[:2]
    img = render_local(scene, frames=16, width=W, height=H)
    err = relmse(img, ref)
    flat = load_scene(DATA / "bump.xml")
    flat.materials = [dataclasses.replace(m, normal_map=None, bump_map=None) for m in flat.materials]
    old = render_local(flat, frames=2, width=W, height=H)  # (its error is bias: 2 frames tell it)
    print("relMSE", err, "flat", relmse(old, ref), "ripple contrast", _ripple_contrast(img),
          _ripple_contrast(ref), _ripple_contrast(old), "floor", img[int(H * 0.7):].mean() / ref[int(H * 0.7):].mean())
    assert err < 0.006, err
    assert relmse(old, ref) > 10 * err
    # the ripples' light and shade as Mitsuba's (flat: 23% less)
    np.testing.assert_allclose(_ripple_contrast(img), _ripple_contrast(ref), rtol=0.05)
    # the rippled floor as bright as Mitsuba's: the light walks' flux corrected for the shading
    # normals (common.kernels.shading_normals; without, its indirect light was ~20% too bright)
    floor = slice(int(H * 0.7), H)
    np.testing.assert_allclose(img[floor].mean((0, 1)), ref[floor].mean((0, 1)), rtol=0.03)
    np.testing.assert_allclose(img.mean((0, 1)), ref.mean((0, 1)), rtol=0.03)
