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


def _vpl_sets_built(r: Renderer) -> dict:
    """{indirect VPL count in the set's config: [set sizes]} of the VPL sets the renderer holds."""
    out: dict = {}
    for (config, _seed, _index), _k in r._frame_sets.keys():
        if config[0] == "vpl":
            out.setdefault(config[4], []).append(len(r._frame_sets._sets[((config, _seed, _index), _k)]))
    return out


def test_a_moving_cameras_frame_takes_the_moving_vpl_count_and_a_still_cameras_frames_the_full_one():
    scene = load_scene(bundled.resolve("cornell-box"))
    cam, fov_x, _, _ = resolve_camera(scene, None, None, None)
    w = h = 16
    base = dict(interleave=1, photons=0, vpl_importance=0, direct_vpls=2, indirect_vpls=12,
                moving_indirect_vpls=6, light_path_length=3)
    tile = make_tiles(w, h, 1, w, h)[0]
    # a streamed view's frame after a move: index 0 without the consistent estimators
    r = Renderer(scene)
    r.render_tile(sequence_spec(0, 0, cam, fov_x, w, h, params_to_dict(make_params(**base, consistent_first_frame=False))), tile)
    sets = _vpl_sets_built(r)
    assert list(sets) == [6] and 2 < sets[6][0] <= 2 + 6  # 2 walks of at most 3 vertices
    # the same frame with accumulation off is shown once too
    r = Renderer(scene)
    r.render_tile(sequence_spec(0, 0, cam, fov_x, w, h, params_to_dict(make_params(**base, accumulate=False))), tile)
    assert list(_vpl_sets_built(r)) == [6]
    # a still camera: the first frame and the ones accumulated after it take the full count
    r = Renderer(scene)
    for index in (0, 1):
        r.render_tile(sequence_spec(index, index, cam, fov_x, w, h, params_to_dict(make_params(**base))), tile)
    assert list(_vpl_sets_built(r)) == [12]
    # -1: moving frames as still ones
    r = Renderer(scene)
    r.render_tile(sequence_spec(0, 0, cam, fov_x, w, h, params_to_dict(make_params(
        **dict(base, moving_indirect_vpls=-1), consistent_first_frame=False))), tile)
    sets = _vpl_sets_built(r)
    assert list(sets) == [12] and 2 < sets[12][0] <= 2 + 12
