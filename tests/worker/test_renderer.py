"""Renderer.render_tile: where an accumulated frame's eye rays pass through their pixels, which
VPL count a frame's sets take, and sets built ahead for later accumulation frames."""
from __future__ import annotations

import numpy as np

from igi.common import bundled
from igi.common.camera import camera_rays, frame_jitter, resolve_camera
from igi.common.interleave import make_tiles
from igi.common.loader import load_scene
from igi.common.scene import DIFFUSE
from igi.common.params import make_params, params_to_dict
from igi.common.frame import frame_seed
from igi.master.accumulation import sequence_spec
from igi.worker import set_cache
from igi.worker.renderer import LOOKAHEAD_FRAMES, Renderer, later_frames
from igi.worker.vpl_importance import View


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
        jitter = frame_jitter(spec.jitter, index > 0, xs, ys, scene.camera, w, h)
        o, d = camera_rays(np.asarray(cam, float).reshape(4, 4), fov_x, w, h, xs, ys, jitter)
        hits = r.geom.intersect(o, d)
        t = hits.t
        diffuse = np.array([m.kind == DIFFUSE for m in scene.materials] + [False])
        hit = hits.valid & diffuse[hits.material]  # there the depth is the first hit's distance
        assert hit.mean() > 0.8
        np.testing.assert_allclose(depth[hit], t[hit], rtol=1e-5)
        if index > 0:  # pixels of one frame sample different sub-pixel positions
            assert len({tuple(j) for j in np.round(jitter, 9)}) >= 64


def _vpl_sets_built(r: Renderer) -> dict:
    """{indirect VPL count a set was built for: [its VPLs]} of the VPL sets the renderer holds
    (the count is the fifth entry of a set's cache config: worker/renderer.py vpl_set)."""
    out: dict = {}
    for key in r._frame_sets.keys():
        (config, _seed, _index), _k = key
        if config[0] == "vpl":
            out.setdefault(config[4], []).append(len(r._frame_sets._sets[key]))
    return out


def _render(scene, index: int, **params) -> Renderer:
    cam, fov_x, _, _ = resolve_camera(scene, None, None, None)
    r = Renderer(scene)
    for i in range(index + 1):
        r.render_tile(sequence_spec(i, i, cam, fov_x, 16, 16, params_to_dict(make_params(**params))),
                      make_tiles(16, 16, 1, 16, 16)[0])
    return r


def test_a_moving_cameras_frame_takes_at_most_the_moving_vpl_count_and_a_still_cameras_frames_the_full_one():
    scene = load_scene(bundled.resolve("cornell-box"))
    base = dict(interleave=1, photons=0, vpl_importance=0, direct_vpls=2, indirect_vpls=12,
                moving_indirect_vpls=6, light_path_length=3)
    # a streamed view's frame after a move (master/stream.py marks it)
    sets = _vpl_sets_built(_render(scene, 0, **base, moving_camera=True, consistent_first_frame=False))
    assert list(sets) == [6] and 2 < sets[6][0] <= 2 + 6  # 2 walks of at most 3 vertices
    # a still camera: the first frame and the ones accumulated after it, with accumulation off too
    assert list(_vpl_sets_built(_render(scene, 1, **base))) == [12]
    assert list(_vpl_sets_built(_render(scene, 0, **base, accumulate=False))) == [12]
    # the moving count caps, never raises: none asked for, none built
    sets = _vpl_sets_built(_render(scene, 0, **dict(base, indirect_vpls=0), moving_camera=True))
    assert list(sets) == [0] and sets[0][0] <= 2
    sets = _vpl_sets_built(_render(scene, 0, **dict(base, indirect_vpls=3, vpl_importance=1), moving_camera=True))
    assert list(sets) == [3]
    # -1: moving frames as still ones
    sets = _vpl_sets_built(_render(scene, 0, **dict(base, moving_indirect_vpls=-1), moving_camera=True))
    assert list(sets) == [12] and 2 < sets[12][0] <= 2 + 12


def test_a_moving_cameras_frame_decides_importance_sampling_from_the_still_frames_pilot():
    scene = load_scene(bundled.resolve("cornell-box"))
    r = _render(scene, 0, interleave=1, photons=0, moving_camera=True)
    pilots = [key for key in r._views if key[0] == "pilot"]
    assert len(pilots) == 1 and pilots[0][3] == make_params().indirect_vpls


def test_later_frames_are_offered_as_many_as_the_accumulation_has_shown_and_only_in_sequence():
    p = make_params(seed=11)
    assert later_frames(frame_seed(11, 0), 0, p) == []  # a first frame: the camera may move next
    assert later_frames(frame_seed(11, 1), 1, p, "cfg") == [("cfg", frame_seed(11, 2), 2)]
    assert later_frames(frame_seed(11, 3), 3, p) == [((), frame_seed(11, i), i) for i in (4, 5, 6)]
    far = later_frames(frame_seed(11, 100), 100, p)
    assert len(far) == LOOKAHEAD_FRAMES and far[0] == ((), frame_seed(11, 101), 101)
    assert later_frames(frame_seed(11, 3) + 1, 3, p) == []  # not the master's sequencing
    wrap = make_params(seed=2**31 - 2)  # seeds wrap inside their declared range
    assert later_frames(frame_seed(2**31 - 2, 1), 1, wrap) == [((), 0, 2)]


def _same(a, b) -> None:
    for name, x in vars(a).items():
        y = getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
        elif name not in ("derived", "grid", "env_guide", "surface"):
            assert x == y, name


def test_sets_built_ahead_for_later_frames_equal_the_sets_built_alone(monkeypatch):
    """A worker holding one k builds it for later accumulation frames in one batch: each of
    those VPL and photon sets (importance-sampled VPLs, photons with the shrinking radius of
    their own frame) is bit for bit the set built when its frame comes."""
    scene = load_scene(bundled.resolve("cornell-box"))
    cam, fov_x, w, h = resolve_camera(scene, None, 32, 24)
    view = View.of(cam, fov_x, w, h)
    params = make_params(interleave=3, photons=300, vpl_importance=1, seed=5)
    frames = [(frame_seed(5, i), i) for i in range(1, 8)]

    def sets(r):
        return [(r.vpl_set(s, 4, params, roulette=True, view=view, index=i), r.photon_set(s, 4, params, index=i))
                for s, i in frames]

    ahead = Renderer(scene)
    built_ahead = sets(ahead)
    assert ahead.stats["set_hits"] == 4  # frames 2, 4, 5, 6 were built with frames 1 and 3
    monkeypatch.setattr(set_cache, "BATCH_TARGET", 1)  # one set a batch: no later frames
    alone = Renderer(scene)
    built_alone = sets(alone)
    assert alone.stats["set_hits"] == 0
    for (va, pa), (vb, pb) in zip(built_ahead, built_alone):
        assert len(va) > 4 and len(pa) > 0
        _same(va, vb)
        _same(va.surface, vb.surface)
        _same(pa, pb)
    radii = [p.radius for _, p in built_ahead]
    assert all(a > b for a, b in zip(radii, radii[1:]))  # each frame's own radius


def test_a_tile_reports_the_seconds_it_spent_building_sets_and_none_when_they_were_held():
    """render_tile's ``timings``: "sets" (what the master's task timeouts allow for) is there
    when the call built the tile's VPL or photon sets or prepared its view (pilot, camera
    points: blocks inside one another counted once, so never more than the call took), absent
    when all were cached."""
    import time

    scene = load_scene(bundled.resolve("cornell-box"))
    cam, fov_x, _, _ = resolve_camera(scene, None, None, None)
    r = Renderer(scene)
    pd = params_to_dict(make_params(interleave=2))
    spec = sequence_spec(0, 0, cam, fov_x, 16, 16, pd)
    tiles = make_tiles(16, 16, 2, 8, 8)
    first: dict = {}
    t0 = time.perf_counter()
    r.render_tile(spec, tiles[0], first)
    assert 0.0 < first["sets"] <= time.perf_counter() - t0
    held: dict = {}
    r.render_tile(spec, tiles[0], held)
    assert "sets" not in held
    r.render_tile(spec, tiles[0])  # no timings asked for: nothing to report to


def test_a_rough_split_lobe_is_filtered_on_its_own_and_the_radiance_stays_the_same():
    """params.filter_lobe_alpha: on cornell-box-glossy (smooth plastics of α 0.16 and 0.24, split at
    the first hit), a lobe at least that rough leaves its pixel no unfiltered radiance — it is the
    pixel's lobe, which the discontinuity buffer filters apart from the irradiance — and each
    pixel's radiance (reflectance × irradiance + lobe + unfiltered) is the one the unfiltered lobe
    gives; lobes below the threshold stay unfiltered (no lobe)."""
    from igi.bench.stress_scenes import load_shared

    scene = load_shared("cornell-box-glossy")
    cam, fov_x, _, _ = resolve_camera(scene, None, None, None)
    w, h = 32, 24
    tile = make_tiles(w, h, 1, w, h)[0]
    out = {}
    for alpha in (0.1, 10.0):
        spec = sequence_spec(0, 0, cam, fov_x, w, h, params_to_dict(make_params(interleave=1, filter_lobe_alpha=alpha)))
        out[alpha] = Renderer(scene).render_tile(spec, tile)
    filtered, plain = out[0.1], out[10.0]
    carried = filtered.lobe[:, 0] >= 0
    assert carried.sum() > 20  # the floor's and the blocks' lobes: not vacuous
    assert not plain.has_lobe and not np.any(filtered.unfiltered[carried] > 0)
    np.testing.assert_array_equal(filtered.reflectance, plain.reflectance)
    np.testing.assert_array_equal(filtered.irradiance, plain.irradiance)

    def radiance(b):
        return b.reflectance.astype(np.float64) * b.irradiance + b.unfiltered + np.maximum(b.lobe, 0)

    np.testing.assert_allclose(radiance(filtered), radiance(plain), rtol=2e-3, atol=1e-6)
