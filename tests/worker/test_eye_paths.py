"""Eye paths (worker.shading.trace_eye): camera rays that leave the scene are misses, whatever
else the tile holds — no end point, depth inf, normal 0, the environment unfiltered — and they
change nothing about the paths of the rays that hit."""
from __future__ import annotations

import numpy as np

from igi.bench.stress_scenes import load_shared
from igi.common.camera import camera_rays
from igi.common.sobol_stream import rng
from igi.worker.renderer import Renderer
from igi.worker.shading import trace_eye


def _rays(scene, w=32, h=24):
    cam = scene.camera
    ys, xs = np.mgrid[0:h, 0:w]
    o, d = camera_rays(cam.to_world, cam.fov_x, w, h, xs.ravel(), ys.ravel())
    d = d.copy()
    d[::3] *= -1.0  # every third ray looks back, away from the box: a miss
    return o, d


def test_misses_leave_no_end_point_and_do_not_change_the_hits():
    r = Renderer(load_shared("cornell-box-sphere"))  # glass ball: chains start among the hits too
    o, d = _rays(r.scene)
    full = trace_eye(r.scene, r.geom, r.lights, o, d, -1, 8, rng(0, 3))
    hit = r.geom.intersect(o, d).valid
    assert 0 < hit.sum() < len(hit)  # both kinds in one batch: not vacuous
    miss = np.nonzero(~hit)[0]
    assert np.all(np.isinf(full.depth[miss])) and np.all(full.normal[miss] == 0.0)
    np.testing.assert_array_equal(full.unfiltered[miss], 0.0)  # no environment in this scene
    assert not np.isin(full.end.pixel, miss).any()
    # The hits alone give the same paths (pixels renumbered).
    rows = np.nonzero(hit)[0]
    alone = trace_eye(r.scene, r.geom, r.lights, o[rows], d[rows], -1, 8, rng(0, 3))
    np.testing.assert_array_equal(rows[alone.end.pixel], full.end.pixel)
    for name in ("position", "ns", "wi", "throughput", "segments", "main", "distance"):
        np.testing.assert_array_equal(getattr(alone.end, name), getattr(full.end, name))
    np.testing.assert_array_equal(alone.depth, full.depth[rows])
    np.testing.assert_array_equal(alone.normal, full.normal[rows])
    np.testing.assert_array_equal(alone.unfiltered, full.unfiltered[rows])


def test_misses_see_the_environment_unfiltered():
    from igi.common import bundled
    from igi.common.loader import load_scene

    scene = load_scene(bundled.resolve("window-room"))
    r = Renderer(scene)
    env = r.lights.environment()
    assert np.any(env > 0)  # a sky: not vacuous
    o, d = _rays(scene)
    full = trace_eye(scene, r.geom, r.lights, o, d, -1, 8, rng(0, 4))
    miss = np.nonzero(~r.geom.intersect(o, d).valid)[0]
    assert len(miss)
    np.testing.assert_allclose(full.unfiltered[miss], np.broadcast_to(env, (len(miss), 3)))
    assert np.all(np.isinf(full.depth[miss])) and np.all(full.normal[miss] == 0.0)
