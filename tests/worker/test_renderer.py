"""Renderer.render_tile: where an accumulated frame's eye rays pass through their pixels."""
from __future__ import annotations

import numpy as np

from igi.common import bundled
from igi.common.camera import camera_rays, pixel_jitter, resolve_camera
from igi.common.interleave import make_tiles
from igi.common.loader import load_scene
from igi.common.scene import DIFFUSE
from igi.common.params import make_params, params_to_dict
from igi.master.accumulation import sequence_spec
from igi.worker.renderer import Renderer


def test_first_frame_samples_pixel_centres_accumulated_frames_each_pixels_rotated_jitter():
    scene = load_scene(bundled.resolve("cornell-box"))
    cam, fov_x, _, _ = resolve_camera(scene, None, None, None)
    w = h = 24
    pd = params_to_dict(make_params(interleave=1, photons=0))
    r = Renderer(scene)
    tile = make_tiles(w, h, 1, w, h)[0]
    xs, ys = tile.pixels(1, w, h)
    for index in (0, 1, 2):
        spec = sequence_spec(index, index, cam, fov_x, w, h, pd)
        depth = r.render_tile(spec, tile).depth
        jitter = spec.jitter if index == 0 else pixel_jitter(spec.jitter, xs, ys)
        o, d = camera_rays(np.asarray(cam, float).reshape(4, 4), fov_x, w, h, xs, ys, jitter)
        hits = r.geom.intersect(o, d)
        t = hits.t
        diffuse = np.array([m.kind == DIFFUSE for m in scene.materials] + [False])
        hit = hits.valid & diffuse[hits.material]  # there the depth is the first hit's distance
        assert hit.mean() > 0.8
        np.testing.assert_allclose(depth[hit], t[hit], rtol=1e-5)
        if index > 0:  # pixels of one frame sample different sub-pixel positions
            assert len({tuple(j) for j in np.round(jitter, 9)}) == 64
