"""igi's camera rays follow Mitsuba 3's perspective sensor convention."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.camera import camera_rays, look_at, pixel_jitter, pixel_tile
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


@pytest.mark.parametrize("block", [2, 4, 8])
def test_pixel_jitter_stratifies_every_aligned_block_within_a_frame(block):
    # A block's b² pixels sample one position per 1/b² strip along each axis (a (0, m, 2)-net),
    # whatever the frame's point: an edge's coverage seen by a block is off by at most 1/b².
    rng = np.random.default_rng(3)
    ys, xs = np.mgrid[0:24, 0:24]
    for jitter in [(0.5, 0.5), tuple(rng.random(2)), (0.999, 0.0)]:
        j = pixel_jitter(jitter, xs.ravel(), ys.ravel()).reshape(24, 24, 2)
        assert np.all((j >= 0) & (j < 1))
        n = block * block
        for by in range(0, 24, block):
            for bx in range(0, 24, block):
                pts = j[by:by + block, bx:bx + block].reshape(-1, 2)
                for axis in (0, 1):
                    for c in rng.random(5):
                        assert abs(np.mean(pts[:, axis] < c) - c) <= 1.0 / n + 1e-12
                cells = np.floor(np.mod(pts - np.asarray(jitter), 1.0) * block).astype(int)
                assert len({(a, b) for a, b in cells}) == n  # one point per cell of a b x b grid


def test_pixel_jitter_keeps_each_pixels_sequence_over_frames_stratified():
    from igi.master.accumulation import jitter_for

    for px, py in [(0, 0), (5, 3), (1021, 77)]:
        for axis, frames in ((0, 64), (1, 81)):  # Halton bases 2 and 3: full strata at 2^6, 3^4
            seq = np.array([pixel_jitter(jitter_for(i), np.array([px]), np.array([py]))[0, axis]
                            for i in range(1, frames + 1)])
            s = np.sort(seq)
            gaps = np.diff(np.append(s, s[0] + 1.0))  # on the circle: the rotation wraps
            assert gaps.max() < 2.0 / frames  # a rotated Halton sequence: no gap of two strata
    assert len({tuple(p) for p in pixel_tile().reshape(-1, 2)}) == 64  # pixels differ within a tile


def test_compiled_primary_rays_and_jitter_equal_the_numpy_forms_bit_for_bit():
    """common.camera's compiled rays and per-pixel jitter (common.kernels.camera_rays) give the
    numpy forms' values exactly (tests/support/oracle_camera.py): one jitter point or one per
    pixel, odd film sizes, wide and narrow fields of view, scaled and rotated cameras, empty."""
    from igi.common.camera import camera_rays, pixel_jitter
    from tests.support.oracle_camera import camera_rays_numpy, pixel_jitter_numpy

    g = np.random.default_rng(0)
    for _ in range(12):
        w, h = (int(v) for v in g.integers(1, 2000, 2))
        n = 3000
        px, py = g.integers(0, w, n), g.integers(0, h, n)
        m = np.eye(4)
        m[:3, :3] = np.linalg.qr(g.normal(size=(3, 3)))[0] * g.uniform(0.5, 2)
        m[:3, 3] = g.normal(size=3) * 10
        fov = g.uniform(1, 170)
        j = (g.random(), g.random())
        per_pixel = pixel_jitter(j, px, py)
        np.testing.assert_array_equal(per_pixel, pixel_jitter_numpy(j, px, py))
        assert per_pixel.min() >= 0 and per_pixel.max() < 1
        for jit in ((0.5, 0.5), j, per_pixel):
            for got, want in zip(camera_rays(m.ravel(), fov, w, h, px, py, jit),
                                 camera_rays_numpy(m.ravel(), fov, w, h, px, py, jit)):
                np.testing.assert_array_equal(got, want)
    empty = np.zeros(0, np.int64)
    assert camera_rays(np.eye(4), 40.0, 8, 8, empty, empty)[1].shape == (0, 3)
    assert pixel_jitter((0.1, 0.2), empty, empty).shape == (0, 2)
