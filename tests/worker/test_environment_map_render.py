"""A scene lit only by an environment map with a sun (tests/data/envmap/outdoor.xml) rendered as
Mitsuba 3's path tracer renders it (outdoor_ref.exr, 4,096 spp): the sun's shadows, the sky's
colour, the map seen directly — where the old fallback, a constant sky of the map's mean, had no
sun and no shadows at all."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from igi.common.image_io import read_image
from igi.common.loader import load_scene
from igi.common.metrics import block_average, relmse
from igi.master.inprocess import render_local

DATA = Path(__file__).resolve().parents[1] / "data" / "envmap"


def test_an_environment_map_with_a_sun_renders_as_mitsubas_path_tracer():
    scene = load_scene(DATA / "outdoor.xml")
    ref = block_average(read_image(DATA / "outdoor_ref.exr"), 2)
    H, W = ref.shape[:2]
    img = render_local(scene, frames=6, width=W, height=H)
    err = relmse(img, ref)
    # the same scene under the old fallback (a constant sky of the map's mean)
    flat = load_scene(DATA / "outdoor.xml")
    flat.emitters[0].image = None
    old = render_local(flat, frames=6, width=W, height=H)
    print("relMSE", err, "fallback", relmse(old, ref))
    assert err < 0.04, err
    assert relmse(old, ref) > 5 * err
    # the sky seen directly is the map (Mitsuba's lookup), and the image's mean light within 3%
    sky = np.zeros(ref.shape[:2], bool)
    sky[:3] = True  # the top rows: sky above the horizon
    np.testing.assert_allclose(img[sky], ref[sky], rtol=0.02)
    np.testing.assert_allclose(img.mean((0, 1)), ref.mean((0, 1)), rtol=0.03)
