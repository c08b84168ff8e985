"""Mitsuba's ``normalmap`` and ``bumpmap`` (common.bump_mapping, common.kernels.bump_mapping): a hit's
shading normal is the map's — a normal map's 2·rgb − 1 in the frame of the interpolated normal and
dp/du, a bump map's normal of dp/du and dp/dv lifted by the height's gradient — while the
geometric normal stays the triangle's; triangles' dp/du, dp/dv as Mitsuba's meshes compute them;
the maps load from Mitsuba XML and travel with the scene."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.bump_mapping import bump_tables, no_bumps, triangle_tangents
from igi.common.geometry import Geometry
from igi.common.kernels import bump_mapping as kb
from igi.common.kernels.texture import texel
from igi.common.luminance import LUMINANCE_WEIGHTS
from igi.common.mitsuba_xml import load_mitsuba
from igi.common.scene import DIFFUSE, Material, Texture
from igi.common.scene_codec import decode_scene, encode_scene
from tests.common.test_mitsuba_xml import scene_file


def test_triangle_tangents_are_the_positions_derivatives_along_uv():
    rng = np.random.default_rng(1)
    dpdu, dpdv = rng.normal(size=3), rng.normal(size=3)
    origin = rng.normal(size=3)
    uv = rng.random((3, 2))
    verts = origin + uv[:, :1] * dpdu + uv[:, 1:] * dpdv  # p(u, v) linear in uv
    t = triangle_tangents(verts, np.array([[0, 1, 2]]), uv)
    np.testing.assert_allclose(t[0, :3], dpdu, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(t[0, 3:], dpdv, rtol=1e-9, atol=1e-9)
    # no uv (all zero): no derivative, the kernel takes any tangent
    assert not triangle_tangents(verts, np.array([[0, 1, 2]]), np.zeros((3, 2))).any()


def _tables(kind_tex: dict, n_tri=1):
    mat = Material("m", DIFFUSE, **kind_tex)
    return bump_tables([mat], np.zeros(n_tri, np.int32), np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]]),
                       np.array([[0, 1, 2]] * n_tri), np.array([[0.0, 0], [1, 0], [0, 1]]))


def _perturb(tables, uv=(0.3, 0.3), n=(0.0, 0.0, 1.0), d=None):
    d = tuple(-x for x in n) if d is None else d  # (a ray straight down onto the surface)
    return np.array(kb.perturb(0, 0, uv[0], uv[1], *n, *n, *d, *tables))


def test_a_flat_normal_map_keeps_the_normal_and_a_tilted_one_tilts_it_towards_dp_du():
    assert len(bump_tables([Material("m", DIFFUSE)], np.zeros(1, np.int32), np.zeros((3, 3)),
                           np.array([[0, 1, 2]]), np.zeros((3, 2)))[0]) == 0
    flat = _tables({"normal_map": Texture.constant([0.5, 0.5, 1.0])})
    np.testing.assert_allclose(_perturb(flat), [0, 0, 1], atol=1e-12)
    th = 0.4  # (sin θ, 0, cos θ) in (s, t, n): s is dp/du = +x here, t = n × s = +y
    tilt = _tables({"normal_map": Texture.constant([0.5 + 0.5 * np.sin(th), 0.5, 0.5 + 0.5 * np.cos(th)])})
    np.testing.assert_allclose(_perturb(tilt), [np.sin(th), 0, np.cos(th)], atol=1e-12)
    side = _tables({"normal_map": Texture.constant([0.5, 0.5 + 0.5 * np.sin(th), 0.5 + 0.5 * np.cos(th)])})
    np.testing.assert_allclose(_perturb(side), [0, np.sin(th), np.cos(th)], atol=1e-12)
    # the frame follows the shading normal: n = +y, s = dp/du (+x) kept, t = n × s = -z
    np.testing.assert_allclose(_perturb(side, n=(0.0, 1.0, 0.0)), [0, np.cos(th), -np.sin(th)], atol=1e-12)
    # a map of (0.5, 0.5, 0.5) gives no direction (2·rgb − 1 = 0): the normal is kept
    np.testing.assert_allclose(_perturb(_tables({"normal_map": Texture.constant([0.5, 0.5, 0.5])})), [0, 0, 1])


def test_a_perturbed_normal_facing_away_from_wi_is_mirrored_unless_told_not_to():
    th = 1.2
    tables = _tables({"normal_map": Texture.constant([0.5 + 0.5 * np.sin(th), 0.5, 0.5 + 0.5 * np.cos(th)])})
    tilted = np.array([np.sin(th), 0, np.cos(th)])
    a = np.radians(80)
    towards = (-np.sin(a), 0.0, -np.cos(a))  # wi = -d leans the way the normal does: kept
    np.testing.assert_allclose(_perturb(tables, d=towards), tilted, atol=1e-12)
    away = (np.sin(a), 0.0, -np.cos(a))  # wi·n > 0 but wi·n_perturbed < 0: mirrored about n
    np.testing.assert_allclose(_perturb(tables, d=away), [-np.sin(th), 0, np.cos(th)], atol=1e-12)
    kept = _tables({"normal_map": Texture.constant([0.5 + 0.5 * np.sin(th), 0.5, 0.5 + 0.5 * np.cos(th)]),
                    "flip_invalid_normals": False})
    np.testing.assert_allclose(_perturb(kept, d=away), tilted, atol=1e-12)


def test_the_height_gradient_is_the_bilinear_lookups_derivative():
    rng = np.random.default_rng(3)
    img = rng.random((7, 5, 3)).astype(np.float32)
    flat = img.reshape(-1)
    lum = np.array(LUMINANCE_WEIGHTS)
    for su, sv, ou, ov in ((1.0, 1.0, 0.0, 0.0), (2.0, 3.0, 0.1, -0.2), (-1.5, 0.5, 0.0, 0.3)):
        h = 1e-3  # (the lookup interpolates in float32: central differences within one texel cell)

        def cell(u, v):
            x, y = (u * su + ou) % 1.0 * 5 - 0.5, (1.0 - (v * sv + ov) % 1.0) * 7 - 0.5
            return np.floor(x), np.floor(y)

        checked = 0
        for _ in range(40):
            u, v = rng.random(2)
            if len({cell(u + a, v + b) for a, b in ((h, 0), (-h, 0), (0, h), (0, -h))}) > 1:
                continue
            gu, gv = kb.height_gradient(flat, 0, 7, 5, u, v, su, sv, ou, ov, False)
            f = [np.dot(lum, texel(flat, 0, 7, 5, u + a, v + b, su, sv, ou, ov, False)) for a, b in
                 ((h, 0), (-h, 0), (0, h), (0, -h))]
            np.testing.assert_allclose([gu, gv], [(f[0] - f[1]) / (2 * h), (f[2] - f[3]) / (2 * h)],
                                       rtol=1e-3, atol=1e-3)
            checked += 1
        assert checked > 25
    assert kb.height_gradient(flat, 0, 7, 5, 0.3, 0.3, 1.0, 1.0, 0.0, 0.0, True) == (0.0, 0.0)


def test_a_height_ramp_along_u_tilts_the_normal_by_its_slope():
    # height = a·u on a triangle whose dp/du = (2, 0, 0), dp/dv = (0, 2, 0): slope a·scale / 2
    w = 64
    ramp = np.repeat(((np.arange(w) + 0.5) / w)[None, :, None], 4, 0).repeat(3, 2).astype(np.float32)
    tables = _tables({"bump_map": Texture(image=ramp), "bump_scale": 0.5})
    got = _perturb(tables, uv=(0.5, 0.4))
    g = 0.5 * 1.0  # d height / du = 1 (u spans the image once), × scale
    want = np.array([-g * 2.0, 0.0, 4.0])  # (dp/du + n g) × dp/dv
    np.testing.assert_allclose(got, want / np.linalg.norm(want), atol=2e-3)
    # the same height as a constant has no gradient: no table at all
    assert len(_tables({"bump_map": Texture.constant(0.7)})[0]) == 0


def test_hits_carry_the_mapped_shading_normal_and_the_triangles_geometric_one(tmp_path):
    th = 0.5
    rgb = f"{0.5 + 0.5 * np.sin(th)}, 0.5, {0.5 + 0.5 * np.cos(th)}"
    scene = load_mitsuba(scene_file(tmp_path, f"""
        <shape type="rectangle"><bsdf type="normalmap"><rgb name="normalmap" value="{rgb}"/>
            <bsdf type="diffuse"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><translate x="3"/></transform></shape>"""))
    assert scene.materials[0].normal_map is not None
    geom = Geometry(scene)
    o = np.array([[0.2, 0.1, 1.0], [3.1, -0.2, 1.0]])
    hits = geom.intersect(o, np.array([[0.0, 0.0, -1.0]] * 2))
    assert hits.valid.all()
    np.testing.assert_allclose(hits.ng, [[0, 0, 1], [0, 0, 1]], atol=1e-6)
    # the rectangle's dp/du is +x (Mitsuba's): the normal leans towards +x
    np.testing.assert_allclose(hits.ns[0], [np.sin(th), 0, np.cos(th)], atol=1e-6)
    np.testing.assert_allclose(hits.ns[1], [0, 0, 1], atol=1e-6)


def test_normal_and_bump_maps_load_from_mitsuba_xml_and_travel_with_the_scene(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((4, 4, 3), 128, np.uint8)).save(tmp_path / "n.png")
    scene = load_mitsuba(scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="twosided"><bsdf type="normalmap">
            <texture type="bitmap" name="normalmap"><string name="filename" value="n.png"/>
              <boolean name="raw" value="true"/></texture>
            <bsdf type="roughplastic"/></bsdf></bsdf></shape>
        <shape type="rectangle"><bsdf type="bumpmap"><texture type="bitmap">
              <string name="filename" value="n.png"/><boolean name="raw" value="true"/></texture>
            <float name="scale" value="0.25"/><boolean name="flip_invalid_normals" value="false"/>
            <boolean name="use_shadowing_function" value="false"/><bsdf type="diffuse"/></bsdf></shape>"""))
    assert not [w for w in scene.warnings if "sensor" not in w], scene.warnings
    a, b = scene.materials[:2]
    assert a.twosided and a.normal_map is not None and a.bump_map is None
    np.testing.assert_allclose(a.normal_map.image, 128 / 255, atol=1e-6)  # raw: not sRGB-decoded
    assert b.bump_map is not None and b.bump_scale == 0.25 and b.normal_map is None
    assert a.flip_invalid_normals and not b.flip_invalid_normals
    back = decode_scene(encode_scene(scene))
    assert back.digest() == scene.digest()
    assert back.materials[1].bump_scale == 0.25 and back.materials[0].normal_map is not None
    flat = load_mitsuba(scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="twosided"><bsdf type="roughplastic"/></bsdf></shape>
        <shape type="rectangle"><bsdf type="diffuse"/></shape>"""))
    assert flat.digest() != scene.digest()


@pytest.mark.parametrize("body,needle", [
    ('<bsdf type="normalmap"><bsdf type="diffuse"/></bsdf>', "needs a texture named 'normalmap'"),
    ('<bsdf type="normalmap"><rgb name="normalmap" value="0.5, 0.5, 1"/><bsdf type="diffuse"/>'
     '<bsdf type="conductor"/></bsdf>', "exactly one nested BSDF"),
    ('<bsdf type="bumpmap"><bsdf type="diffuse"/></bsdf>', "exactly one nested texture"),
    ('<bsdf type="bumpmap"><float name="scale" value="nan"/><texture type="checkerboard"/>'
     '<bsdf type="diffuse"/></bsdf>', "not finite"),
])
def test_malformed_maps_are_named(tmp_path, body, needle):
    from igi.common.scene import SceneError

    with pytest.raises(SceneError, match=needle):
        load_mitsuba(scene_file(tmp_path, f'<shape type="rectangle">{body}</shape>'))


def test_a_named_nested_bsdf_is_read_without_a_warning(tmp_path):
    scene = load_mitsuba(scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="normalmap"><rgb name="normalmap" value="0.5, 0.5, 1"/>
            <bsdf type="conductor" name="inner"/></bsdf></shape>"""))
    assert scene.materials[0].normal_map is not None and scene.materials[0].kind != 0
    assert not [w for w in scene.warnings if "sensor" not in w], scene.warnings


def test_a_map_around_a_map_keeps_the_outer_one_with_a_warning(tmp_path):
    scene = load_mitsuba(scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="normalmap"><rgb name="normalmap" value="0.5, 0.5, 1"/>
            <bsdf type="bumpmap"><texture type="checkerboard"/><bsdf type="diffuse"/></bsdf></bsdf></shape>"""))
    assert scene.materials[0].normal_map is not None and scene.materials[0].bump_map is None
    assert any("around another normal or bump map" in w for w in scene.warnings)


def test_a_scene_without_maps_passes_tables_of_the_types_a_scene_with_them_does():
    """(one compiled signature of hit reconstruction for both)"""
    t = no_bumps()
    real = _tables({"bump_map": Texture(image=np.ones((2, 2, 3), np.float32)), "bump_scale": 0.5})
    assert len(real[0]) == 1
    assert [a.dtype for a in t] == [a.dtype for a in real] == [np.int32, np.float64, np.float64, np.float32]
    assert [a.ndim for a in t] == [a.ndim for a in real] == [1, 2, 2, 1]
    assert t[2].shape[1] == real[2].shape[1] == kb.MAP_COLUMNS


def test_a_height_ramp_along_v_tilts_the_normal_along_dp_dv():
    # the image's rows run against v (row 0 is v = 1): a height rising with v falls down the rows
    h = 64
    ramp = np.repeat((1.0 - (np.arange(h) + 0.5) / h)[:, None, None], 4, 1).repeat(3, 2).astype(np.float32)
    got = _perturb(_tables({"bump_map": Texture(image=ramp), "bump_scale": 0.5}), uv=(0.3, 0.5))
    want = np.array([0.0, -0.5 * 2.0, 4.0])  # dp/du × (dp/dv + n g): (2,0,0) × (0,2,0.5)
    np.testing.assert_allclose(got, want / np.linalg.norm(want), atol=2e-3)
