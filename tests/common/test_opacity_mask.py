"""Mitsuba's ``mask`` (common.kernels.opacity_mask, Embree filter functions on every BVH of
common.geometry.Geometry): a masked surface stops a ray with probability its opacity — in
closest-hit and occlusion queries alike, the same answer for the same ray — a bitmap mask's
holes let every ray through and its solid cells none, and the mask travels with the scene."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.geometry import Geometry, opacity_masks
from igi.common.mitsuba_xml import load_mitsuba
from igi.common.scene import DIFFUSE
from igi.common.scene_codec import decode_scene, encode_scene
from igi.common.ray_packets import _api
from tests.common.test_mitsuba_xml import scene_file

# masks need Embree's C API (embreex's own scenes take no filter function)
pytestmark = pytest.mark.skipif(_api() is None, reason="Embree's C API is not at hand")
_N = 40_000


def _quad_scene(tmp_path, opacity_xml: str):
    """A quad at z = 0 (x, y in [-1, 1], uv = its corners) under ``opacity_xml``, and an opaque
    floor below it at z = -1."""
    return load_mitsuba(scene_file(tmp_path, f"""
        <shape type="rectangle"><bsdf type="mask">{opacity_xml}<bsdf type="diffuse"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-1"/></transform>
            </shape>"""))


def _rays_down(rng, n=_N):
    xy = rng.uniform(-0.999, 0.999, (n, 2))
    o = np.column_stack([xy, np.full(n, 0.5)])
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    return o, d


def test_a_constant_mask_stops_its_share_of_rays_alike_in_every_query_and_bvh(tmp_path):
    scene = _quad_scene(tmp_path, '<float name="opacity" value="0.3"/>')
    geom = Geometry(scene)
    o, d = _rays_down(np.random.default_rng(1))
    hits = geom.intersect(o, d)
    on_quad = hits.valid & (np.abs(hits.t - 0.5) < 1e-4)
    assert abs(on_quad.mean() - 0.3) < 0.015  # 0.3 ± ~6 σ
    assert np.all(hits.valid)  # what passes the quad meets the floor
    blocked = geom.occluded(o, d, np.full(_N, 1.0))  # segments ending above the floor
    np.testing.assert_array_equal(blocked, on_quad)  # one ray, one answer: closest and shadow BVH
    again = geom.intersect(o, d)
    np.testing.assert_array_equal(again.t, hits.t)
    # a ray of another origin draws again: the masks of two rays are independent
    other = geom.intersect(o + [0.0, 0.0, 0.25], d)
    both = on_quad & other.valid & (np.abs(other.t - 0.75) < 1e-4)
    assert abs(both.mean() - 0.09) < 0.01


def test_the_hull_culled_interior_bvh_masks_its_own_triangles_as_the_full_one(tmp_path):
    """The shadow rays between two points inside a closed box take the BVH without its walls
    (Geometry.interior_bvh: a subset of the triangles, indexed anew): a masked quad inside,
    listed after the walls, stops the same rays there as in the full BVH."""
    scene = load_mitsuba(scene_file(tmp_path, """
        <shape type="cube"><transform name="to_world"><scale value="2"/></transform></shape>
        <shape type="rectangle"><bsdf type="mask"><float name="opacity" value="0.3"/><bsdf type="diffuse"/></bsdf>
        </shape>"""))
    geom = Geometry(scene)
    inner, planes = geom.interior_bvh()
    assert len(planes) == 6 and inner is not geom.shadow_bvh()  # the walls culled: a BVH of the quad alone
    o, d = _rays_down(np.random.default_rng(4))
    local = (o - geom.center).astype(np.float32)
    t = np.full(_N, 1.0)
    full = geom.occluded_local(local, d, t)
    interior = geom.occluded_local(local, d, t, interior=np.ones(_N, bool))
    np.testing.assert_array_equal(interior, full)
    assert abs(full.mean() - 0.3) < 0.015


def test_a_bitmap_masks_holes_pass_every_ray_and_its_solid_cells_none(tmp_path):
    # Mitsuba's checkerboard: color0 (opacity 1) where (u mod 1 > ½) == (v mod 1 > ½)
    scene = _quad_scene(tmp_path, """<texture type="checkerboard" name="opacity">
        <float name="color0" value="1"/><float name="color1" value="0"/></texture>""")
    geom = Geometry(scene)
    o, d = _rays_down(np.random.default_rng(2))
    u, v = (o[:, 0] + 1) / 2, (o[:, 1] + 1) / 2  # the rectangle's uv (v up, as Mitsuba's)
    away = (np.abs(u - 0.5) > 0.01) & (np.abs(v - 0.5) > 0.01)
    solid = (u > 0.5) == (v > 0.5)
    blocked = geom.occluded(o, d, np.full(_N, 1.0))
    np.testing.assert_array_equal(blocked[away], solid[away])
    assert solid[away].any() and (~solid[away]).any()
    assert any("checkerboard opacity" in w and "eval_1" in w for w in scene.warnings)  # Mitsuba 3.9.1 swaps it


def test_an_opaque_or_absent_mask_builds_no_filter(tmp_path):
    scene = _quad_scene(tmp_path, '<float name="opacity" value="1"/>')
    geom = Geometry(scene)
    assert opacity_masks(scene.materials, geom.material_of, geom.faces, geom.vertex_uvs) is None
    o, d = _rays_down(np.random.default_rng(3), 1000)
    assert np.all(np.abs(geom.intersect(o, d).t - 0.5) < 1e-4)


def test_mask_loads_as_its_nested_bsdf_with_an_opacity_and_travels_with_the_scene(tmp_path):
    scene = _quad_scene(tmp_path, '<float name="opacity" value="0.25"/>')
    mat = scene.materials[scene.meshes[0].material]
    assert mat.kind == DIFFUSE and np.allclose(mat.opacity.rgb, 0.25)
    assert not [w for w in scene.warnings if "bsdf 'mask'" in w]
    back = decode_scene(encode_scene(scene))
    np.testing.assert_array_equal(back.materials[scene.meshes[0].material].opacity.rgb, mat.opacity.rgb)
    assert back.digest() == scene.digest()
    denser = _quad_scene(tmp_path, '<float name="opacity" value="0.5"/>')
    assert denser.digest() != scene.digest()  # the mask is part of what the scene is
    bare = load_mitsuba(scene_file(tmp_path, '<shape type="rectangle"><bsdf type="mask"/></shape>'))
    assert any("bsdf 'mask' without a nested BSDF" in w for w in bare.warnings)


def test_a_masked_emitter_stays_opaque_and_says_so(tmp_path):
    """Light sampling emits from an area light's whole shape: a mask on it would show α·L."""
    scene = load_mitsuba(scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="mask"><float name="opacity" value="0.3"/><bsdf type="diffuse"/></bsdf>
            <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter></shape>"""))
    assert any("opacity mask on an emitting shape" in w for w in scene.warnings)
    geom = Geometry(scene)
    assert opacity_masks(scene.materials, geom.material_of, geom.faces, geom.vertex_uvs, geom.emitter_of) is None
    o, d = _rays_down(np.random.default_rng(5), 1000)
    assert geom.intersect(o, d).valid.all()


@pytest.mark.parametrize("value", ["0.4", "0.4, 0.2, 0.9"])
def test_a_coloured_opacity_is_its_luminance(tmp_path, value):
    tag = "float" if "," not in value else "rgb"
    scene = _quad_scene(tmp_path, f'<{tag} name="opacity" value="{value}"/>')
    geom = Geometry(scene)
    masks = opacity_masks(scene.materials, geom.material_of, geom.faces, geom.vertex_uvs)
    rgb = np.array([float(x) for x in value.split(",")] * (3 if tag == "float" else 1))
    assert masks[2][0, 0] == pytest.approx(float(np.dot([0.212671, 0.71516, 0.072169], rgb)))
