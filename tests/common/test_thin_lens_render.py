"""Mitsuba's thin lens end to end: igi's accumulated frames against Mitsuba's render of lit bars
in and out of focus (tests/data/thinlens), and the lens's rays on their own."""
import dataclasses

import numpy as np
import pytest

from igi.common.camera import camera_rays, lens_jitter
from igi.common.image_io import read_image
from igi.common.loader import load_scene
from igi.common.metrics import relmse
from igi.common.transform import look_at
from igi.master.inprocess import render_local
from tests.support.paths import ROOT

DATA = ROOT / "tests" / "data" / "thinlens"


def test_accumulated_frames_converge_to_mitsubas_depth_of_field():
    """32 frames within relMSE 0.012 of Mitsuba's image (64 frames: 0.0027, 128: 0.0012); the
    same view through a pinhole stays at 0.04 however many frames it takes (8 here)."""
    scene = load_scene(DATA / "lens.xml")
    assert (scene.camera.aperture_radius, scene.camera.focus_distance) == (0.2, 5.0) and not scene.warnings
    ref = read_image(DATA / "lens_ref.exr").astype(np.float64)
    H, W = ref.shape[:2]
    img = render_local(scene, frames=32, width=W, height=H)
    pinhole = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, aperture_radius=0.0))
    sharp = render_local(pinhole, frames=8, width=W, height=H)
    err, err_pinhole = relmse(img, ref), relmse(sharp, ref)
    print("relMSE lens", err, "pinhole", err_pinhole)
    assert err < 0.012
    assert err_pinhole > 3 * err
    np.testing.assert_allclose(img.sum((0, 1)), ref.sum((0, 1)), rtol=0.01)  # blur moves light, makes none


def test_lens_rays_leave_the_aperture_and_meet_where_the_pinhole_ray_meets_the_plane_in_focus():
    m = look_at([0.3, 0.2, 5], [0, 0, 0], [0, 1, 0])
    px, py = np.arange(64) % 8 + 20, np.arange(64) // 8 + 10
    u = lens_jitter(3, px, py)
    o0, d0 = camera_rays(m, 40, 96, 64, px, py, (0.3, 0.6))
    o, d = camera_rays(m, 40, 96, 64, px, py, (0.3, 0.6), (0.2, 5.0, u))
    fwd = m[:3, 2]
    local = o - m[:3, 3]
    assert np.allclose(local @ fwd, 0) and np.all(np.linalg.norm(local, axis=1) <= 0.2 + 1e-12)  # on the aperture
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1)
    t0, t = 5.0 / (d0 @ fwd), (5.0 - local @ fwd) / (d @ fwd)  # to the plane 5 ahead of the lens
    np.testing.assert_allclose(o + t[:, None] * d, o0 + t0[:, None] * d0, atol=1e-9)
    assert np.ptp(local @ m[:3, 0]) > 0.2  # the 64 pixels spread over the aperture
    np.testing.assert_array_equal(camera_rays(m, 40, 96, 64, px, py, (0.3, 0.6), (0.0, 5.0, u))[1], d0)


def test_lens_numbers_are_stratified_over_frames_and_over_a_block_of_pixels():
    px, py = np.zeros(64, np.int64) + 5, np.zeros(64, np.int64) + 9
    over_frames = np.array([lens_jitter(i, px[:1], py[:1])[0] for i in range(64)])
    bx, by = np.meshgrid(np.arange(8), np.arange(8))
    over_block = lens_jitter(7, bx.ravel(), by.ravel())
    for pts in (over_frames, over_block):
        assert np.all((pts >= 0) & (pts < 1))
    # a pixel's frames: Halton's bases 5 and 7, each first 5^2 / 7^2 points one in each 1/25 / 1/49
    assert len(set(np.floor(over_frames[:25, 0] * 25).astype(int))) == 25
    assert len(set(np.floor(over_frames[:49, 1] * 49).astype(int))) == 49
    for axis in (0, 1):  # a block of 8 x 8 pixels: one point in each 1/64 of either axis (a rotated net)
        assert len(set(np.floor(over_block[:, axis] * 64).astype(int))) == 64


def test_the_focus_distance_defaults_to_the_far_clip_as_in_mitsuba(tmp_path):
    p = tmp_path / "scene.xml"
    for extra, focus in [("", 10000.0), ('<float name="far_clip" value="42"/>', 42.0)]:
        p.write_text('<scene version="3.0.0"><sensor type="thinlens"><float name="aperture_radius" value="0.1"/>'
                     f'{extra}</sensor><shape type="cube"/></scene>')
        assert load_scene(p).camera.focus_distance == focus


@pytest.mark.parametrize("body,what", [
    ('<sensor type="thinlens"/>', "needs an 'aperture_radius'"),
    ('<sensor type="thinlens"><float name="aperture_radius" value="-1"/></sensor>', "aperture_radius -1.0 must be"),
    ('<sensor type="thinlens"><float name="aperture_radius" value="0.1"/>'
     '<float name="focus_distance" value="0"/></sensor>', "focus_distance 0.0 must be"),
])
def test_bad_lenses_are_named(tmp_path, body, what):
    from igi.common.scene import SceneError

    p = tmp_path / "scene.xml"
    p.write_text(f'<scene version="3.0.0">{body}<shape type="cube"/></scene>')
    with pytest.raises(SceneError, match=what):
        load_scene(p)
