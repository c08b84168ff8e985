"""The render plan: each rule fires on a scene that needs it and not on one that doesn't."""
from __future__ import annotations

import numpy as np

from igi.common.camera import look_at
from igi.common.frame import FrameSpec, Tile
from igi.common.geometry import Geometry
from igi.common.lights import LightSampler
from igi.common.loader import load_scene
from igi.common.params import make_params, params_to_dict
from igi.common.render_plan import analyze, frame_plan
from igi.common.scene import (AREA, CONSTANT, DIELECTRIC, DIFFUSE, DIRECTIONAL, Camera, Emitter, Material, Mesh, Scene,
                              Texture)
from tests.support.paths import SHARED
from tests.support.scenes_synthetic import box_faces, quad
from igi.worker.renderer import Renderer

_CACHE: dict = {}


def plan_of(name: str):
    if name not in _CACHE:
        scene = load_scene(SHARED / "scenes" / name / "scene.xml")
        geom = Geometry(scene)
        _CACHE[name] = analyze(scene, geom, LightSampler(scene, geom))
    return _CACHE[name]


def tiny_light_room() -> Scene:
    mats = [Material("white", DIFFUSE, diffuse=Texture.constant(0.7)), Material("lamp", DIFFUSE)]
    meshes = [Mesh(f"wall{i}", v, f, 0) for i, (v, f) in enumerate(box_faces(4.0))]
    v, f = quad([1.99, 3.9, 1.99], [0.02, 0, 0], [0, 0, 0.02])
    if np.cross(v[1] - v[0], v[2] - v[0])[1] > 0:
        f = f[:, ::-1].copy()  # face down
    meshes.append(Mesh("bulb", v, f, 1, emitter=0))
    cam = Camera(look_at([2, 2, 3.9], [2, 2, 0], [0, 1, 0]), fov=60, width=16, height=16)
    return Scene(meshes, mats, [Emitter(AREA, radiance=np.full(3, 1000.0), mesh=6)], cam)


def test_caustics_only_where_emitters_reach_mirror_or_glass():
    assert plan_of("cornell-box-sphere").caustics
    assert not plan_of("cornell-box").caustics  # no specular surface at all
    # Glass and mirrors, but lit only by a constant sky: no light source a caustic can focus.
    gw = plan_of("grey-white-room")
    assert gw.specular_chains and not gw.caustics


def _glass_box_under(emitter: Emitter, closed: bool) -> Scene:
    """A glass cube on a floor, under ``emitter``; ``closed``: inside a diffuse room as well."""
    mats = [Material("white", DIFFUSE, diffuse=Texture.constant(0.7)), Material("glass", DIELECTRIC, int_ior=1.5)]
    meshes = [Mesh(f"glass{i}", v * 0.5 + 1.75, f, 1) for i, (v, f) in enumerate(box_faces(1.0, inward=False))]
    v, f = quad([-5, 0, -5], [0, 0, 10], [10, 0, 0])  # normal +y
    meshes.append(Mesh("floor", v, f, 0))
    if closed:
        meshes += [Mesh(f"wall{i}", v, f, 0) for i, (v, f) in enumerate(box_faces(4.0))]
    cam = Camera(look_at([2, 2, 3.9], [2, 2, 0], [0, 1, 0]), fov=60, width=16, height=16)
    return Scene(meshes, mats, [emitter], cam)


def test_caustics_where_a_sun_meets_mirror_or_glass_first():
    """A directional light or an environment map's sun (its peak) focused by glass plans caustic
    photons; the same sun outside a closed room, or a sky without a peak, does not."""
    sun = Emitter(DIRECTIONAL, irradiance=np.ones(3), direction=np.array([0.3, -1.0, 0.2]))
    sky = np.full((32, 64, 3), 0.3)
    sky[4:6, 10:12] = 5000.0
    for emitter, closed, expected in [(sun, False, True), (sun, True, False),
                                      (Emitter(CONSTANT, radiance=np.ones(3), image=sky), False, True),
                                      (Emitter(CONSTANT, radiance=np.ones(3), image=np.full((32, 64, 3), 0.3)),
                                       False, False)]:
        scene = _glass_box_under(emitter, closed)
        geom = Geometry(scene)
        assert analyze(scene, geom, LightSampler(scene, geom)).caustics == expected, (emitter.kind, closed)


def test_specular_chains_only_with_mirror_or_glass():
    assert plan_of("cornell-box-sphere").specular_chains
    assert not plan_of("cornell-box").specular_chains


def test_glossy_vpl_evaluation_only_with_glossy_surfaces():
    assert plan_of("cornell-box-glossy").glossy_vpl_eval
    assert not plan_of("cornell-box").glossy_vpl_eval


def test_textures_only_with_bitmaps():
    assert plan_of("veach-ajar").textures
    assert not plan_of("cornell-box").textures


def test_single_small_emitter_is_treated_as_a_point():
    scene = tiny_light_room()
    geom = Geometry(scene)
    assert analyze(scene, geom, LightSampler(scene, geom)).point_light
    assert not plan_of("cornell-box").point_light


def test_many_emitters_are_subsampled():
    assert plan_of("modern-hall").light_subsampling
    assert not plan_of("cornell-box").light_subsampling


def test_plan_is_printed_with_reasons():
    lines = plan_of("cornell-box").lines()
    assert len(lines) == 6 and all(len(line.split()) >= 3 for line in lines)


def test_frame_plan_rules():
    assert not frame_plan(False, False, True).rebuild_sets  # camera only: reuse sets
    assert not frame_plan(False, False, True).accumulate
    assert frame_plan(True, False, False).rebuild_sets  # scene edit
    assert frame_plan(False, True, False).rebuild_sets  # parameters
    static = frame_plan(False, False, False)
    assert static.accumulate and static.rebuild_sets  # nothing moved: next seed, accumulate
    assert not frame_plan(False, False, False, accumulate_enabled=False).accumulate
    follow = frame_plan(False, False, True, view_dependent_sets=True)
    assert follow.rebuild_sets and not follow.accumulate and "importance" in follow.reason


def _frames_after_moves(importance: int) -> list[int]:
    """Sets built after rendering the camera's view, the same view again, then a moved one."""
    scene = load_scene(SHARED / "scenes" / "cornell-box-sphere" / "scene.xml")
    r = Renderer(scene)
    p = params_to_dict(make_params(accumulate=False, vpl_importance=importance))
    cam = scene.camera
    moved = cam.to_world.copy()
    moved[:3, 3] += [0.1, 0.05, 0.0]
    built = []
    for to_world in (cam.to_world, cam.to_world, moved):
        spec = FrameSpec(0, 0, tuple(np.asarray(to_world).ravel()), cam.fov_x, 48, 36, p)
        for k in range(9):
            r.render_tile(spec, Tile(k, 0, 0, 16, 12))
        built.append(r.stats["sets_built"])
    return built


def test_camera_only_motion_costs_no_preprocessing():
    first, same, moved = _frames_after_moves(importance=0)
    assert first >= 9 and same == first and moved == first  # the same VPL sets, from the cache


def test_camera_move_rebuilds_importance_sampled_sets_only():
    first, same, moved = _frames_after_moves(importance=1)
    assert same == first  # same view: cached
    assert moved == first + 9  # the VPLs follow the view


def test_plan_off_renders_the_same_image():
    # Forcing every pass on (no plan) must not change the result on a Lambertian scene:
    # the skipped passes contribute nothing there. (Shadow roulette off: without a plan every
    # surface VPL is a general BSDF column, whose roulette guess differs from a Lambertian's.)
    scene = load_scene(SHARED / "scenes" / "cornell-box" / "scene.xml")
    from igi.master.inprocess import render_local

    p = {"shadow_roulette": 0.0}
    a = render_local(scene, p, 1, width=32, height=32, renderer=Renderer(scene))
    b = render_local(scene, p, 1, width=32, height=32, renderer=Renderer(scene, use_plan=False))
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=1e-5)
