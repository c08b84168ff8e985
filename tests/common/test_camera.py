"""igi's camera rays follow Mitsuba 3's perspective sensor convention."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.camera import camera_rays, look_at
from igi.common.scene import Camera


def test_lookat_matches_mitsuba_columns():
    # Mitsuba: dir = normalize(target - origin), left = normalize(cross(up, dir)),
    # new_up = cross(dir, left); columns [left, new_up, dir, origin].
    m = look_at([0, 1, 6.8], [0, 1, 0], [0, 1, 0])
    np.testing.assert_allclose(m[:3, 0], [-1, 0, 0], atol=1e-12)  # camera +x (image left) = world -x
    np.testing.assert_allclose(m[:3, 1], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(m[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], [0, 1, 6.8])


@pytest.mark.parametrize("px,py", [(0, 0), (511, 0), (0, 511), (255, 255), (100, 400)])
def test_cornell_box_pixel_directions_match_mitsuba(px, py):
    # Cornell-box sensor: fov 19.5 deg along x, 512x512. In Mitsuba, film position
    # (sx, sy) = ((px+0.5)/W, (py+0.5)/H) maps to camera direction
    # ((1-2sx) tan(fov/2), (1-2sy) tan(fov/2)/aspect, 1); camera x = world -x here.
    t = np.tan(np.radians(19.5) / 2)
    sx, sy = (px + 0.5) / 512, (py + 0.5) / 512
    expected = np.array([-(1 - 2 * sx) * t, (1 - 2 * sy) * t, -1.0])
    expected /= np.linalg.norm(expected)
    o, d = camera_rays(look_at([0, 1, 6.8], [0, 1, 0], [0, 1, 0]), 19.5, 512, 512,
                       np.array([px]), np.array([py]))
    np.testing.assert_allclose(d[0], expected, atol=1e-12)
    np.testing.assert_allclose(o[0], [0, 1, 6.8])


def test_top_left_pixel_sees_upper_left_of_the_scene():
    o, d = camera_rays(look_at([0, 0, 0], [0, 0, 1], [0, 1, 0]), 90, 4, 3, np.array([0]), np.array([0]))
    # Looking down +z with +y up, image left is world +x (left = cross(up, dir)).
    assert d[0, 0] > 0 and d[0, 1] > 0


def test_fov_axis_y_converts_to_horizontal_fov():
    # fov_axis y with a 4:3 film: tan(fx/2) = tan(fy/2) * 4/3.
    cam = Camera(np.eye(4), fov=30, fov_axis="y", width=640, height=480)
    assert np.tan(np.radians(cam.fov_x) / 2) == pytest.approx(np.tan(np.radians(15)) * 4 / 3)
    cam = Camera(np.eye(4), fov=30, fov_axis="smaller", width=640, height=480)
    assert np.tan(np.radians(cam.fov_x) / 2) == pytest.approx(np.tan(np.radians(15)) * 4 / 3)


def test_jitter_spans_the_pixel_footprint():
    m = look_at([0, 0, 0], [0, 0, 1], [0, 1, 0])
    _, d0 = camera_rays(m, 60, 8, 8, np.array([3]), np.array([3]), (0.0, 0.0))
    _, d1 = camera_rays(m, 60, 8, 8, np.array([4]), np.array([4]), (0.0, 0.0))
    _, dj = camera_rays(m, 60, 8, 8, np.array([3]), np.array([3]), (1.0, 1.0))
    np.testing.assert_allclose(dj, d1, atol=1e-12)  # the far corner of pixel 3 is pixel 4's near corner
    assert not np.allclose(d0, d1)
