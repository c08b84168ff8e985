"""The profiler hooks `igi bench rays` uses: Renderer.stage_times and Geometry.time_embree
record where a tile's time goes, change nothing in the result, and are off by default."""
from __future__ import annotations

import numpy as np

from igi.common.camera import resolve_camera
from igi.common.frame import FrameSpec
from igi.common.interleave import make_tiles
from igi.common.params import make_params, params_to_dict
from igi.worker.kernels.warm import _tiny_scene
from igi.worker.renderer import Renderer


def _spec(scene):
    cam, fov_x, w, h = resolve_camera(scene, None, None, None)
    pd = params_to_dict(make_params(photons=500, interleave=2))
    return FrameSpec(frame=0, seed=3, camera_to_world=tuple(np.asarray(cam, float).ravel()), fov_x=float(fov_x),
                     width=w, height=h, params=pd, scene_version=0, jitter=(0.5, 0.5))


def test_stage_times_and_embree_timer_record_without_changing_the_tile():
    scene = _tiny_scene()
    spec = _spec(scene)
    tile = make_tiles(spec.width, spec.height, 2, 4, 4)[0]
    off = Renderer(scene)
    assert off.stage_times is None and "intersect_seconds" not in off.geom.counters
    a = off.render_tile(spec, tile)
    on = Renderer(scene)
    on.stage_times = {}
    on.geom.time_embree(True)
    b = on.render_tile(spec, tile)
    for name in ("reflectance", "irradiance", "unfiltered", "depth", "normal"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    assert {"eye paths", "VPL set", "VPL gather", "BSDF direct", "photon set"} <= set(on.stage_times)
    assert all(v >= 0 for v in on.stage_times.values())
    c = on.geom.counters
    assert c["intersect_seconds"] > 0 and c["occluded_seconds"] > 0
    on.geom.time_embree(False)
    before = dict(c)
    on.stage_times = None
    on.render_tile(spec, tile)
    assert c["intersect_seconds"] == before["intersect_seconds"]  # off again: nothing measured
