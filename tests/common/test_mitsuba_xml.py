"""Mitsuba 3 XML loading: the shared scenes, the XML subset, errors and warnings.

Reference numbers marked "Mitsuba 3.9.1" were read back from Mitsuba 3.9.1 (scalar_rgb) while
writing the loader; Mitsuba itself is not needed to run these tests.
"""
import re
import struct
import textwrap
from pathlib import Path

import numpy as np
import pytest

from igi.common.loader import load_scene
from igi.common.luminance import luminance
from igi.common.mitsuba_xml import load_mitsuba
from igi.common.scene import (AREA, CONDUCTOR, CONSTANT, DIELECTRIC, DIFFUSE, DIRECTIONAL, PLASTIC, POINT,
                          ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC, SPOT, THINDIELECTRIC, SceneError)

from tests.support.paths import SCENES

needs_scenes = pytest.mark.skipif(not SCENES.is_dir(), reason="shared scenes not available")

# Mitsuba 3.9.1's face_count summed over all shapes (the README's "Triangles" column; in 3.9.1 a
# rectangle is a 2-triangle mesh and is included), emitters, film size.
SHARED = {
    "cornell-box": (36, 1, (512, 512)),
    "cornell-box-sphere": (2188, 1, (640, 480)),
    "cornell-box-glossy": (1112, 1, (640, 480)),
    "cornell-box-water": (7088, 1, (640, 480)),
    "veach-ajar": (4546, 1, (640, 480)),
    "veach-bidir": (11544, 2, (512, 512)),
    "modern-hall": (31247, 13, (640, 480)),
    "grey-white-room": (139899, 1, (640, 480)),
}

TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0.25\nvt 1 0.25\nvt 0 0.9\nf 1/1 2/2 3/3\n"


def scene_file(tmp_path, body, files=None, version="3.0.0"):
    """Write a scene.xml with `body` inside <scene>; `files` maps relative names to contents."""
    for name, content in (files or {}).items():
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        (p.write_bytes if isinstance(content, bytes) else p.write_text)(content)
    p = tmp_path / "scene.xml"
    p.write_text(f'<?xml version="1.0"?>\n<scene version="{version}">\n{textwrap.dedent(body)}\n</scene>\n')
    return p


def line_of(path, needle):
    for i, ln in enumerate(Path(path).read_text().splitlines(), 1):
        if needle in ln:
            return i
    raise AssertionError(needle)


def degenerate_removed(scene):
    return sum(int(m.group(1)) for w in scene.warnings for m in [re.search(r"removed (\d+) degenerate", w)] if m)


# ------------------------------------------------------------------------------ shared scenes


@needs_scenes
@pytest.mark.parametrize("name", sorted(SHARED))
def test_shared_scene_loads_with_mitsuba_counts(name):
    tris, n_emitters, film = SHARED[name]
    s = load_scene(SCENES / name / "scene.xml")
    # zero-area triangles are removed (with a warning); Mitsuba keeps them in face_count
    assert s.triangle_count + degenerate_removed(s) == tris
    assert len(s.emitters) == n_emitters
    assert (s.camera.width, s.camera.height) == film
    assert s.max_depth == -1
    other = [w for w in s.warnings if "degenerate" not in w]
    assert not other, other
    for m in s.meshes:
        assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int32
        assert 0 <= m.faces.min() and m.faces.max() < len(m.vertices)
        assert np.all(np.isfinite(m.vertices))
        assert 0 <= m.material < len(s.materials)
        if m.normals is not None:
            assert m.normals.shape == m.vertices.shape
            np.testing.assert_allclose(np.linalg.norm(m.normals[m.faces.ravel()], axis=1), 1.0, atol=1e-6)
        if m.uvs is not None:
            assert m.uvs.shape == (len(m.vertices), 2)
    for i, e in enumerate(s.emitters):
        if e.kind == AREA:
            assert s.meshes[e.mesh].emitter == i


@needs_scenes
def test_veach_ajar_details():
    s = load_scene(SCENES / "veach-ajar" / "scene.xml")
    mats = {m.name: m for m in s.materials}
    floor = mats["FloorBSDF"]
    assert floor.kind == ROUGHCONDUCTOR and floor.twosided and floor.distribution == "ggx"
    assert floor.specular.filter == "nearest" and floor.specular.image.shape == (1280, 320, 3)
    np.testing.assert_allclose(floor.eta, [1.65746, 0.880369, 0.521229])
    assert mats["TableBSDF"].diffuse.image is not None  # file name with a space
    landscape = next(m for m in s.meshes if m.name == "Landscape")  # named by the shape id
    assert landscape.normals is None  # face_normals="true"
    light = s.meshes[s.emitters[0].mesh]
    assert light.name == "Light" and len(light.faces) == 2
    np.testing.assert_allclose(s.emitters[0].radiance, 1000)
    np.testing.assert_allclose(s.camera.to_world[0], [-0.137283, -0.0319925, -0.990015, 4.05402])
    assert s.camera.fov == 60 and s.camera.fov_axis == "x"


# ------------------------------------------------------------------------------ subset features


def test_obj_shape_semantics_normals_uvs_and_texture_chain(tmp_path):
    from PIL import Image

    # 2x4 image, rows top to bottom red, green, blue, white
    img = np.zeros((4, 2, 3), np.uint8)
    img[0], img[1], img[2], img[3] = [255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]
    Image.fromarray(img).save(tmp_path / "t.png")
    p = scene_file(tmp_path, """
        <bsdf type="diffuse" id="tex"><texture name="reflectance" type="bitmap">
            <string name="filename" value="t.png"/><string name="filter_type" value="nearest"/></texture></bsdf>
        <shape type="obj" id="smooth"><string name="filename" value="tri.obj"/><ref id="tex"/>
            <transform name="to_world"><scale x="2"/></transform></shape>
        <shape type="obj" id="flat"><string name="filename" value="tri.obj"/>
            <boolean name="face_normals" value="true"/><boolean name="flip_normals" value="true"/></shape>
    """, {"tri.obj": TRI})
    s = load_mitsuba(p)
    smooth, flat = s.meshes
    np.testing.assert_allclose(smooth.vertices[1], [2, 0, 0])
    np.testing.assert_allclose(smooth.normals, [[0, 0, 1]] * 3)  # recomputed after to_world
    assert flat.normals is None
    assert flat.faces.tolist() == [[2, 1, 0]]  # flip_normals reverses the winding
    # Mitsuba: v_mitsuba = 1 - vt, bitmap row = v_mitsuba * H. The stored uv keeps vt; the chain
    # must hit the same texel: vt v = 0.9 -> v_mitsuba 0.1 -> row 0 (red); vt v = 0.25 -> row 3 (white).
    tex = s.materials[smooth.material].diffuse
    np.testing.assert_allclose(smooth.uvs, [[0, 0.25], [1, 0.25], [0, 0.9]], atol=1e-7)
    np.testing.assert_allclose(tex.eval(smooth.uvs[[2]]), [[1, 0, 0]])
    np.testing.assert_allclose(tex.eval(smooth.uvs[[0]]), [[1, 1, 1]])
    assert s.materials[flat.material].kind == DIFFUSE  # no BSDF: Mitsuba's default diffuse 0.5


def test_rectangle_uv_normals_and_to_uv_match_mitsuba(tmp_path):
    from PIL import Image

    img = np.zeros((4, 2, 3), np.uint8)
    img[0], img[1], img[2], img[3] = [255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]
    Image.fromarray(img).save(tmp_path / "t.png")
    p = scene_file(tmp_path, """
        <shape type="rectangle">
            <transform name="to_world"><scale x="-1" y="2"/></transform>
            <bsdf type="diffuse"><texture name="reflectance" type="bitmap">
                <string name="filename" value="t.png"/><string name="filter_type" value="nearest"/>
                <boolean name="raw" value="true"/>
                <transform name="to_uv"><scale y="2"/></transform></texture></bsdf>
        </shape>
    """)
    s = load_mitsuba(p)
    m = s.meshes[0]
    # Mitsuba 3.9.1: rectangle mesh vertices (-1,-1),(1,-1),(-1,1),(1,1), faces (1,2,0),(1,3,2),
    # vertex normals = inverse-transpose of +z (stays +z under this mirror)
    assert m.faces.tolist() == [[1, 2, 0], [1, 3, 2]]
    np.testing.assert_allclose(m.normals, [[0, 0, 1]] * 4)
    # Mitsuba's si.uv = ((x+1)/2, (y+1)/2) in local coordinates; stored as (u, 1 - v)
    np.testing.assert_allclose(m.uvs, [[0, 1], [1, 1], [0, 0], [1, 0]])
    # Mitsuba 3.9.1 with to_uv scale(1,2): v_mitsuba 0.1 -> red, 0.3 -> blue, 0.6 -> red, 0.9 -> white
    tex = s.materials[0].diffuse
    v_m = np.array([0.1, 0.3, 0.6, 0.9])
    got = tex.eval(np.stack([np.full(4, 0.25), 1 - v_m], axis=1))
    np.testing.assert_allclose(got, [[1, 0, 0], [0, 0, 1], [1, 0, 0], [1, 1, 1]])


def test_analytic_shapes(tmp_path):
    p = scene_file(tmp_path, """
        <shape type="cube"/>
        <shape type="sphere"><point name="center" x="1" y="2" z="3"/><float name="radius" value="0.5"/></shape>
        <shape type="disk"><transform name="to_world"><translate z="4"/></transform></shape>
    """)
    cube, sphere, disk = load_mitsuba(p).meshes
    assert len(cube.faces) == 12 and len(cube.vertices) == 24
    np.testing.assert_allclose(np.abs(cube.vertices), 1.0)
    d = sphere.vertices - [1, 2, 3]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.5)
    np.testing.assert_allclose(sphere.normals, d / 0.5, atol=1e-12)
    assert len(sphere.faces) >= 128 * 64
    # outward winding: geometric normals agree with the shading normals
    f = sphere.faces
    g = np.cross(sphere.vertices[f[:, 1]] - sphere.vertices[f[:, 0]], sphere.vertices[f[:, 2]] - sphere.vertices[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", g, sphere.normals[f[:, 0]]) > 0)
    # Mitsuba's sphere uv = (phi/2pi, theta/pi), stored as (u, 1 - v): the north pole has v = 1
    top = np.argmax(sphere.vertices[:, 2])
    assert sphere.uvs[top, 1] == pytest.approx(1.0)
    np.testing.assert_allclose(disk.vertices[:, 2], 4)
    np.testing.assert_allclose(disk.normals, [[0, 0, 1]] * len(disk.vertices))
    assert np.linalg.norm(disk.vertices[:, :2] - 0, axis=1).max() == pytest.approx(1.0)


def test_ply_shapes_ascii_and_binary(tmp_path):
    ascii_ply = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float u\nproperty float v\nelement face 1\nproperty list uchar int vertex_indices\n"
                 "end_header\n0 0 0 0 0.1\n1 0 0 1 0.2\n0 1 0 0 0.9\n3 0 1 2\n")
    verts = [(0, 0, 0, 0, 0, 1), (1, 0, 0, 0, 0, 1), (1, 1, 0, 0, 0, 1), (0, 1, 0, 0, 0, 1)]
    binary_ply = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                  b"property float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face 1\n"
                  b"property list uchar int vertex_indices\nend_header\n"
                  + b"".join(struct.pack("<6f", *v) for v in verts) + struct.pack("<B4i", 4, 0, 1, 2, 3))
    p = scene_file(tmp_path, """
        <shape type="ply"><string name="filename" value="a.ply"/></shape>
        <shape type="ply"><string name="filename" value="b.ply"/></shape>
    """, {"a.ply": ascii_ply, "b.ply": binary_ply})
    a, b = load_mitsuba(p).meshes
    # Mitsuba 3.9.1's ply shape keeps the file's v (no flip), so the stored uv is (u, 1 - v)
    np.testing.assert_allclose(a.uvs, [[0, 0.9], [1, 0.8], [0, 0.1]], atol=1e-7)
    np.testing.assert_allclose(a.normals, [[0, 0, 1]] * 3)  # recomputed
    assert b.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_allclose(b.normals, [[0, 0, 1]] * 4)


def test_bsdfs_and_mitsuba_defaults(tmp_path):
    p = scene_file(tmp_path, """
        <bsdf type="diffuse" id="d"/>
        <bsdf type="conductor" id="c"/>
        <bsdf type="conductor" id="au"><string name="material" value="Au"/></bsdf>
        <bsdf type="roughconductor" id="rc"><rgb name="eta" value="2 2 2"/></bsdf>
        <bsdf type="dielectric" id="g"/>
        <bsdf type="dielectric" id="w"><string name="int_ior" value="water"/><string name="ext_ior" value="air"/></bsdf>
        <bsdf type="thindielectric" id="t"><float name="int_ior" value="1.33"/></bsdf>
        <bsdf type="roughdielectric" id="rg"><string name="distribution" value="ggx"/>
            <float name="alpha" value="0.3"/><rgb name="specular_transmittance" value="0.9 0.8 0.7"/></bsdf>
        <bsdf type="plastic" id="p"><spectrum name="diffuse_reflectance" value="0.3"/></bsdf>
        <bsdf type="roughplastic" id="rp"><boolean name="nonlinear" value="true"/></bsdf>
        <bsdf type="twosided" id="two"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.2, 0.3"/></bsdf></bsdf>
    """ + "".join(f'<shape type="cube"><ref id="{i}"/></shape>' for i in
                  ["d", "c", "au", "rc", "g", "w", "t", "rg", "p", "rp", "two", "d"]))
    s = load_mitsuba(p)
    m = {x.name: x for x in s.materials}
    assert len(s.materials) == 11  # a referenced BSDF is one material, however often it is used
    assert s.meshes[0].material == s.meshes[-1].material
    assert m["d"].kind == DIFFUSE and np.allclose(m["d"].diffuse.rgb, 0.5)
    assert m["c"].kind == CONDUCTOR and not m["c"].eta.any() and not m["c"].k.any()  # perfect mirror
    np.testing.assert_allclose(m["au"].eta, [0.143036, 0.375307, 1.442045])
    assert m["rc"].kind == ROUGHCONDUCTOR and m["rc"].alpha == 0.1 and m["rc"].distribution == "beckmann"
    np.testing.assert_allclose(m["rc"].k, 1.0)  # Mitsuba: k defaults to 1 when eta is given
    assert m["g"].kind == DIELECTRIC and (m["g"].int_ior, m["g"].ext_ior) == (1.5046, 1.000277)
    assert (m["w"].int_ior, m["w"].ext_ior) == (1.3330, 1.000277)
    assert m["t"].kind == THINDIELECTRIC and m["t"].int_ior == 1.33
    assert m["rg"].kind == ROUGHDIELECTRIC and (m["rg"].alpha, m["rg"].distribution) == (0.3, "ggx")
    assert m["rg"].int_ior == 1.5046 and np.allclose(m["rg"].specular_transmittance.rgb, [0.9, 0.8, 0.7])
    assert not [w for w in s.warnings if "no <sensor>" not in w]  # every BSDF read as it is, none replaced
    assert m["p"].kind == PLASTIC and np.allclose(m["p"].diffuse.rgb, 0.3) and m["p"].int_ior == 1.49
    assert m["rp"].kind == ROUGHPLASTIC and m["rp"].nonlinear and m["rp"].alpha == 0.1
    assert m["rp"].distribution == "beckmann"
    assert m["two"].twosided and np.allclose(m["two"].diffuse.rgb, [0.1, 0.2, 0.3])


def test_emitters_sensor_and_integrator(tmp_path):
    p = scene_file(tmp_path, """
        <integrator type="path"><integer name="max_depth" value="5"/></integrator>
        <sensor type="perspective">
            <float name="fov" value="45"/><string name="fov_axis" value="y"/><float name="near_clip" value="0.5"/>
            <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
            <film type="hdrfilm"><integer name="width" value="320"/><integer name="height" value="200"/></film>
        </sensor>
        <emitter type="point"><point name="position" value="1 2 3"/><rgb name="intensity" value="4"/></emitter>
        <emitter type="spot">
            <transform name="to_world"><lookat origin="0,5,0" target="0,0,0" up="0,0,1"/></transform>
            <float name="cutoff_angle" value="40"/></emitter>
        <emitter type="directional"><vector name="direction" x="0" y="-2" z="0"/></emitter>
        <emitter type="constant"><rgb name="radiance" value="0.1 0.2 0.3"/></emitter>
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="5, 6, 7"/></emitter></shape>
    """)
    s = load_mitsuba(p)
    assert s.max_depth == 5
    c = s.camera
    assert (c.width, c.height, c.fov, c.fov_axis, c.near_clip) == (320, 200, 45, "y", 0.5)
    point, spot, directional, const, area = s.emitters
    assert point.kind == POINT and np.allclose(point.position, [1, 2, 3]) and np.allclose(point.intensity, 4)
    assert spot.kind == SPOT and np.allclose(spot.position, [0, 5, 0]) and np.allclose(spot.direction, [0, -1, 0])
    assert spot.cutoff_angle == 40 and spot.beam_width == 30  # Mitsuba: 3/4 of the cutoff
    assert directional.kind == DIRECTIONAL and np.allclose(directional.direction, [0, -1, 0])
    assert const.kind == CONSTANT and np.allclose(const.radiance, [0.1, 0.2, 0.3])
    assert area.kind == AREA and area.mesh == 0 and s.meshes[0].emitter == 4


def test_a_shape_without_a_bsdf_is_diffuse_half_grey_and_black_where_it_emits(tmp_path):
    # Mitsuba 3.9.1: Shape gives a shape without a BSDF a diffuse of reflectance 0.5, or 0 where it
    # carries an emitter (a bare lamp reflects nothing; reflecting 0.5 there made igi's indirect light
    # 8-13% too bright in open scenes lit by a bare rectangle)
    p = scene_file(tmp_path, """
        <shape type="rectangle"/>
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
        <shape type="cube"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="5"/></emitter>
            <bsdf type="diffuse"/></shape>
        <shape type="cube"/>
    """)
    s = load_mitsuba(p)
    plain, lamp, cube_lamp, lamp_with_bsdf, cube = (s.materials[m.material] for m in s.meshes)
    assert plain is cube and lamp is cube_lamp  # one default material of each kind
    assert plain.kind == DIFFUSE and np.allclose(plain.diffuse.rgb, 0.5) and not plain.is_black
    assert lamp.kind == DIFFUSE and np.allclose(lamp.diffuse.rgb, 0.0) and lamp.is_black
    assert np.allclose(lamp_with_bsdf.diffuse.rgb, 0.5) and not lamp_with_bsdf.is_black  # a BSDF given is kept
    assert len(s.materials) == 3


SPECTRAL = """
    <emitter type="point"><point name="position" value="1 2 3"/><spectrum name="intensity" value="4"/></emitter>
    <emitter type="directional"><vector name="direction" value="0 -1 0"/><spectrum name="irradiance" value="2"/>
    </emitter>
    <emitter type="constant"><spectrum name="radiance" value="400:0.5, 700:0.5"/></emitter>
    <shape type="rectangle"><emitter type="area"><spectrum name="radiance" value="10"/></emitter>
        <bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>
    <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="10"/></emitter>
        <bsdf type="diffuse"><spectrum name="reflectance" value="360:0.5, 830:0.5"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="diffuse"><spectrum name="reflectance" filename="box.spd"/></bsdf></shape>
"""
# Mitsuba 3.9.1 (scalar_rgb): spectrum_list_to_srgb of a flat 0.5 over 400-700 nm as light, and of the 500-600 nm
# box as a reflectance (under D65, clamped into [0, 1])
FLAT_LIGHT_400_700 = (0.599846, 0.474761, 0.451722)
BOX_REFLECTANCE = (0.213897, 1.0, 0.0)


def test_spectra_read_as_mitsuba_3_reads_them_light_in_emitters_reflectances_under_d65(tmp_path):
    # a kitchen lit by <spectrum> emitters rendered 20% less red than Mitsuba, its classic Cornell box (measured
    # reflectance spectra) grey instead of red and green
    box = "# a 500-600 nm box\n400 0\n499 0\n500 1\n600 1\n601 0\n700 0\n"
    s = load_mitsuba(scene_file(tmp_path, SPECTRAL, files={"box.spd": box}))
    point, sun, sky, area, area_rgb = s.emitters
    e = np.array([1.204794, 0.948291, 0.908916])  # the equal-energy illuminant: XYZ (1, 1, 1) -> linear sRGB
    assert np.allclose(point.intensity, 4 * e, rtol=1e-5) and np.allclose(sun.irradiance, 2 * e, rtol=1e-5)
    assert np.allclose(area.radiance, 10 * e, rtol=1e-5)
    assert abs(luminance(area.radiance) - 10) < 1e-4  # unit luminance per v: E's Y is 1
    assert np.allclose(sky.radiance, FLAT_LIGHT_400_700, atol=2e-6)
    assert np.allclose(area_rgb.radiance, 10)  # <rgb> as given
    grey, flat, boxed = (s.materials[m.material].diffuse.rgb for m in s.meshes)
    assert np.allclose(grey, 0.5) and np.allclose(flat, 0.5, atol=1e-3)  # reflectances under D65: grey
    assert np.allclose(boxed, BOX_REFLECTANCE, atol=2e-6)
    assert any("outside the sRGB gamut" in w for w in s.warnings)  # clamped, as Mitsuba warns


def test_bad_spectra_name_the_element(tmp_path):
    for value, what in (("500:1, 400:1", "increasing order"), ("500:1", "two or more"), ("500:1, 600:x", "pairs")):
        p = scene_file(tmp_path, f'<shape type="rectangle"><bsdf type="diffuse">'
                                 f'<spectrum name="reflectance" value="{value}"/></bsdf></shape>')
        with pytest.raises(SceneError, match=what):
            load_mitsuba(p)
    p = scene_file(tmp_path, '<shape type="rectangle"><bsdf type="diffuse">'
                             '<spectrum name="reflectance" filename="bad.spd"/></bsdf></shape>',
                   files={"bad.spd": "400 0.5\n500 x\n"})
    with pytest.raises(SceneError, match=r"spectrum file 'bad.spd' line 2: '500 x' is not 'wavelength value'"):
        load_mitsuba(p)


def test_spectra_match_mitsuba_3s_own_conversion(tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    from igi.common.cie import spectrum_to_linear_srgb

    rng = np.random.default_rng(3)
    for _ in range(20):
        wl = np.sort(rng.uniform(360, 830, rng.integers(2, 12)))
        vals = rng.uniform(0, 2, len(wl))
        for emitted in (False, True):
            ours, _ = spectrum_to_linear_srgb(wl, vals, emitted)
            theirs = mi.spectrum_list_to_srgb(list(wl), list(vals), not emitted, not emitted)
            assert np.allclose(ours, np.array(theirs), atol=1e-5), (wl, vals, emitted)
    body = """
        <integrator type="path"><integer name="max_depth" value="2"/></integrator>
        <sensor type="perspective"><float name="fov" value="10"/>
            <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
            <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film></sensor>
        <shape type="rectangle"><emitter type="area"><spectrum name="radiance" value="3"/></emitter></shape>"""
    p = scene_file(tmp_path, body)
    seen = np.array(mi.render(mi.load_file(str(p)), spp=4))[2, 2, :3]  # the emitter itself, seen head-on
    assert np.allclose(load_mitsuba(p).emitters[0].radiance, seen, rtol=1e-4)


def test_focal_length_and_default_camera(tmp_path):
    p = scene_file(tmp_path, '<sensor type="perspective"><string name="focal_length" value="35mm"/></sensor>')
    c = load_mitsuba(p).camera
    assert c.fov_x == pytest.approx(52.62254, abs=1e-3)  # Mitsuba 3.9.1's x_fov for 35mm at 768x576
    p = scene_file(tmp_path, '<shape type="cube"/>')
    s = load_mitsuba(p)
    assert any("no <sensor>" in w for w in s.warnings)
    assert (s.camera.width, s.camera.height, s.camera.fov) == (768, 576, 45)
    assert s.camera.to_world[2, 3] < -1  # in front of the cube, looking along +z


def _film_filter(tmp_path, film_body, film=True):
    f = f'<film type="hdrfilm">{film_body}</film>' if film else ""
    s = load_mitsuba(scene_file(tmp_path, f'<sensor type="perspective">{f}</sensor><shape type="cube"/>'))
    return (s.camera.rfilter, s.camera.rfilter_params), s.warnings


def test_a_films_reconstruction_filter_is_read_with_mitsubas_defaults(tmp_path):
    # Mitsuba 3: hdrfilm's rfilter defaults to gaussian (stddev 0.5), with or without a <film>
    assert _film_filter(tmp_path, "")[0] == ("gaussian", (0.5, 0.0))
    assert _film_filter(tmp_path, "", film=False)[0] == ("gaussian", (0.5, 0.0))
    assert load_mitsuba(scene_file(tmp_path, '<shape type="cube"/>')).camera.rfilter == "gaussian"  # no sensor
    assert _film_filter(tmp_path, '<rfilter type="box"/>')[0] == ("box", (0.5, 0.0))
    assert _film_filter(tmp_path, '<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>')[0] == (
        "tent", (1.5, 0.0))
    assert _film_filter(tmp_path, '<rfilter type="gaussian"><float name="stddev" value="0.3"/></rfilter>')[0] == (
        "gaussian", (0.3, 0.0))
    assert _film_filter(tmp_path, '<rfilter name="rfilter" type="tent"/>')[0] == ("tent", (1.0, 0.0))  # named
    (kind, params), warnings = _film_filter(tmp_path, '<rfilter type="mitchell"><float name="B" value="0.2"/></rfilter>')
    assert kind == "mitchell" and params == pytest.approx((0.2, 1 / 3))
    assert any("negative lobes" in w for w in warnings)
    (kind, params), warnings = _film_filter(tmp_path, '<rfilter type="lanczos"><integer name="lobes" value="2"/></rfilter>')
    assert (kind, params) == ("lanczos", (2.0, 0.0)) and any("negative lobes" in w for w in warnings)
    (kind, params), warnings = _film_filter(tmp_path, '<rfilter type="mitchell"><float name="B" value="1"/>'
                                                      '<float name="C" value="0"/></rfilter>')
    assert kind == "mitchell" and not any("negative lobes" in w for w in warnings)  # (B-spline: none)
    filt, warnings = _film_filter(tmp_path, '<rfilter type="sinc"/>')
    assert filt == ("gaussian", (0.5, 0.0)) and any("unknown reconstruction filter 'sinc'" in w for w in warnings)
    with pytest.raises(SceneError, match=r"scene.xml:\d+.*stddev -0.5 must be"):
        _film_filter(tmp_path, '<rfilter type="gaussian"><float name="stddev" value="-0.5"/></rfilter>')
    filt, warnings = _film_filter(tmp_path, '<rfilter type="tent"><float name="width" value="2"/></rfilter>')
    assert filt == ("tent", (1.0, 0.0)) and any("unsupported parameter 'width'" in w for w in warnings)


CYLINDERS = """
    <shape type="cylinder"><point name="p0" value="0.5, 0.2, -0.3"/><point name="p1" value="0.5, 1.7, 0.5"/>
        <float name="radius" value="0.4"/></shape>
    <shape type="cylinder"><point name="p0" value="-1, 0, 0"/><point name="p1" value="-1, 0, -2"/>
        <float name="radius" value="0.3"/>
        <transform name="to_world"><rotate x="1" angle="30"/><translate y="0.5"/></transform></shape>
"""


def test_cylinders_are_mitsubas_open_cylinders(tmp_path):
    from igi.common.geometry import Geometry

    s = load_mitsuba(scene_file(tmp_path, CYLINDERS))
    a, b = s.meshes
    # Mitsuba 3.9.1: the first cylinder's bbox and surface area (2 pi r |p1 - p0|)
    np.testing.assert_allclose(a.vertices.min(0), [0.1, 0.0117647, -0.652941], atol=2e-4)
    np.testing.assert_allclose(a.vertices.max(0), [0.9, 1.88824, 0.852941], atol=2e-4)
    tri = a.vertices[a.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(4.272566, rel=1e-3)  # (tessellated: 128 segments)
    # rays Mitsuba 3.9.1 traced: (origin, direction) -> t, uv, shading normal
    rays = [((3, 0.95, 0.1), (-1, 0, 0), 2.1, (0.0, 0.5), (1, 0, 0)),
            ((0.5, 1.0, 3), (0, 0, -1), 2.42, (0.75, 0.658824), (0, -0.470588, 0.882353)),
            ((-1, 3, -0.5), (0, -1, 0), 1.864915, (0.75, 0.375278), (0, 0.866025, 0.5))]
    hits = Geometry(s).intersect(np.array([r[0] for r in rays], float), np.array([r[1] for r in rays], float))
    assert hits.valid.all()
    np.testing.assert_allclose(hits.t, [r[2] for r in rays], atol=1e-4)
    uv = np.column_stack([hits.uv[:, 0], 1 - hits.uv[:, 1]])  # (meshes store 1 - Mitsuba's v)
    np.testing.assert_allclose(uv, [r[3] for r in rays], atol=1e-4)
    np.testing.assert_allclose(hits.ns, [r[4] for r in rays], atol=1e-4)
    assert np.all(np.einsum("ij,ij->i", hits.ng, hits.ns) > 0.999)  # the faces wind outward
    for bad, what in [('<point name="p1" value="0.5, 0.2, -0.3"/>', "has no length"),
                      ('<float name="radius" value="0"/>', "radius 0.0 must be")]:
        body = f'<shape type="cylinder"><point name="p0" value="0.5, 0.2, -0.3"/>{bad}</shape>'
        with pytest.raises(SceneError, match=what):
            load_mitsuba(scene_file(tmp_path, body))


INSTANCES = """
    <bsdf type="diffuse" id="grey"/>
    <shape type="shapegroup" id="pair">
        <shape type="rectangle"><transform name="to_world"><scale x="0.5"/><translate z="-1"/></transform>
            <ref id="grey"/></shape>
        <shape type="sphere"><point name="center" value="0, 0.5, 0"/><float name="radius" value="0.25"/>
            <ref id="grey"/></shape>
    </shape>
    <shape type="instance" id="left"><ref id="pair"/>
        <transform name="to_world"><rotate y="1" angle="30"/><translate x="-1.5"/></transform></shape>
    <shape type="instance"><ref id="pair"/>
        <transform name="to_world"><scale value="2"/><translate x="1.5" y="-0.5"/></transform></shape>
"""


def test_instances_place_their_shapegroups_shapes_as_mitsuba_does(tmp_path):
    from igi.common.geometry import Geometry

    s = load_mitsuba(scene_file(tmp_path, INSTANCES))
    p = tmp_path / "scene.xml"
    line = line_of(p, "scale value")  # (an unnamed instance is named by its line)
    assert [m.name.split("#")[1] for m in s.meshes] == ["left", "left"] + [f"instance@scene.xml:{line - 1}"] * 2
    assert len(s.materials) == 1 and not [w for w in s.warnings if "sensor" not in w]
    # Mitsuba 3.9.1: the scene's bbox and three rays' hit distances
    lo = np.min([m.vertices.min(0) for m in s.meshes], 0)
    hi = np.max([m.vertices.max(0) for m in s.meshes], 0)
    np.testing.assert_allclose(lo, [-2.43301, -2.5, -2], atol=1e-4)
    np.testing.assert_allclose(hi, [2.5, 1.5, 0.5], atol=1e-4)
    hits = Geometry(s).intersect(np.array([[-1.5, 0.5, 5], [1.5, 0.5, 5], [1.5, 3, 0]], float),
                                 np.array([[0, 0, -1], [0, 0, -1], [0, -1, 0]], float))
    np.testing.assert_allclose(hits.t, [4.75, 4.5, 2.0], atol=2e-4)


def test_instances_past_the_memory_budget_are_refused_before_they_fill_it(tmp_path):
    from igi.common.limits import set_memory_budget

    body = ('<shape type="shapegroup" id="g"><shape type="sphere"/></shape>'
            + '<shape type="instance"><ref id="g"/></shape>' * 50)
    set_memory_budget("2M")
    try:
        with pytest.raises(SceneError, match=r"meshes take .* more than the memory budget of 2 MiB"):
            load_mitsuba(scene_file(tmp_path, body))
    finally:
        set_memory_budget(None)
    assert len(load_mitsuba(scene_file(tmp_path, body)).meshes) == 50


@pytest.mark.parametrize("body,what", [
    ('<shape type="shapegroup" id="g"><shape type="instance"><ref id="g"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "nested instancing"),
    ('<shape type="shapegroup" id="g"><shape type="rectangle"><emitter type="area"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "emitting shape inside a shapegroup"),
    ('<shape type="instance"/>', "needs one shapegroup"),
    ('<shape type="cube" id="c"/><shape type="instance"><ref id="c"/></shape>', "needs one shapegroup"),
])
def test_bad_instancing_is_named(tmp_path, body, what):
    with pytest.raises(SceneError, match=what):
        load_mitsuba(scene_file(tmp_path, body))


def test_a_shapegroup_without_an_id_warns_and_a_mesh_file_is_read_once_for_all_its_instances(tmp_path, monkeypatch):
    from igi.common import mitsuba_shapes

    reads = []
    real = mitsuba_shapes.load_obj_mesh
    monkeypatch.setattr(mitsuba_shapes, "load_obj_mesh", lambda *a, **k: reads.append(a[0]) or real(*a, **k))
    p = scene_file(tmp_path, """
        <shape type="shapegroup"><shape type="cube"/></shape>
        <shape type="shapegroup" id="g"><shape type="obj"><string name="filename" value="t.obj"/></shape></shape>
        """ + "".join(f'<shape type="instance"><ref id="g"/><transform name="to_world"><translate x="{i}"/>'
                      '</transform></shape>' for i in range(3)), files={"t.obj": TRI})
    s = load_mitsuba(p)
    assert any("shapegroup without an id is never instanced" in w for w in s.warnings)
    assert len(s.meshes) == 3 and len(reads) == 1
    np.testing.assert_allclose([m.vertices[0, 0] for m in s.meshes], [0, 1, 2])


def test_defaults_substitution_refs_aliases_and_includes(tmp_path):
    p = scene_file(tmp_path, """
        <default name="spp" value="16"/>
        <default name="refl" value="0.25"/>
        <default name="w" value="64"/>
        <include filename="inc.xml"/>
        <alias id="base" as="other"/>
        <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="$w"/></film></sensor>
        <shape type="cube"><ref id="other"/></shape>
    """, {"inc.xml": '<scene version="3.0.0"><bsdf type="diffuse" id="base">'
                     '<float name="reflectance" value="$refl"/></bsdf></scene>'})
    s = load_mitsuba(p)
    assert s.camera.width == 64
    np.testing.assert_allclose(s.materials[0].diffuse.rgb, 0.25)
    s = load_mitsuba(p, defaults={"refl": "0.75", "w": "128"})
    assert s.camera.width == 128
    np.testing.assert_allclose(s.materials[0].diffuse.rgb, 0.75)


def test_mitsuba_0_6_camel_case_names_are_upgraded(tmp_path):
    p = scene_file(tmp_path, """
        <shape type="obj"><string name="filename" value="tri.obj"/><boolean name="faceNormals" value="true"/>
            <transform name="toWorld"><translate x="1"/></transform>
            <bsdf type="dielectric"><float name="intIOR" value="1.7"/></bsdf></shape>
    """, {"tri.obj": TRI}, version="0.6.0")
    s = load_mitsuba(p)
    assert s.meshes[0].normals is None and s.meshes[0].vertices[0, 0] == 1
    assert s.materials[0].int_ior == 1.7


# ------------------------------------------------------------------------------ warnings


def test_unsupported_elements_warn_with_name_line_and_fallback(tmp_path):
    p = scene_file(tmp_path, """
        <shape type="cube">
            <bsdf type="measured"><string name="filename" value="x.bsdf"/></bsdf>
        </shape>
        <shape type="bsplinecurve"/>
        <emitter type="sunsky"/>
        <medium type="homogeneous" id="fog"/>
        <shape type="cube"><bsdf type="roughplastic"><float name="alpha_q" value="0.3"/></bsdf></shape>
    """)
    s = load_mitsuba(p)
    w = "\n".join(s.warnings)
    assert f"unsupported bsdf 'measured' at {p}:{line_of(p, 'measured')}, using diffuse 0.5" in w
    assert f"unsupported shape 'bsplinecurve' at {p}:{line_of(p, 'bsplinecurve')}, skipped" in w
    assert f"unsupported emitter 'sunsky' at {p}:{line_of(p, 'sunsky')}" in w
    assert "homogeneous" in w and f"{p}:{line_of(p, 'medium')}" in w
    assert "unsupported parameter 'alpha_q'" in w
    assert len(s.meshes) == 2 and s.materials[0].kind == DIFFUSE


def test_degenerate_triangles_are_removed_with_a_count(tmp_path):
    p = scene_file(tmp_path, '<shape type="obj" id="m"><string name="filename" value="d.obj"/></shape>',
                   {"d.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 3\n"})
    s = load_mitsuba(p)
    assert s.triangle_count == 1
    assert any("m: removed 2 degenerate" in w for w in s.warnings)


# ------------------------------------------------------------------------------ errors


def assert_error(p, line, text):
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = str(e.value)
    assert f"scene.xml:{line}:" in msg, msg
    assert text in msg, msg
    return msg


def test_truncated_tag_names_file_and_line(tmp_path):
    p = tmp_path / "scene.xml"
    p.write_text('<scene version="3.0.0">\n  <shape type="cube">\n  </shap>\n</scene>\n')
    assert_error(p, 3, "mismatched tag")
    p.write_text('<scene version="3.0.0">\n  <shape type="cube"\n')
    with pytest.raises(SceneError, match=r"scene\.xml:\d+: "):
        load_scene(p)


def test_bad_number_names_element_value_and_line(tmp_path):
    p = scene_file(tmp_path, '<sensor type="perspective">\n<float name="fov" value="abc"/>\n</sensor>')
    assert_error(p, line_of(p, "abc"), "<float name='fov'> value 'abc' is not a number")
    p = scene_file(tmp_path, '<shape type="cube">\n<rgb name="x" value="1, two, 3"/></shape>')
    assert_error(p, line_of(p, "two"), "not a list of numbers")
    p = scene_file(tmp_path, '<shape type="cube"><transform name="to_world">\n<matrix value="1 2"/></transform></shape>')
    assert_error(p, line_of(p, "matrix"), "16 values")


def test_unknown_ref_names_id_and_line(tmp_path):
    p = scene_file(tmp_path, '<shape type="cube">\n<ref id="nothing"/>\n</shape>')
    assert_error(p, line_of(p, "nothing"), "<ref id='nothing'>: no object with this id")


def test_missing_mesh_file_names_file_and_reference(tmp_path):
    p = scene_file(tmp_path, '<shape type="obj">\n<string name="filename" value="meshes/foo.obj"/>\n</shape>')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    assert str(e.value) == f"meshes/foo.obj: file not found (referenced at {p}:{line_of(p, '<shape')})"


def test_malformed_mesh_in_scene_names_mesh_file_and_line(tmp_path):
    p = scene_file(tmp_path, '<shape type="obj"><string name="filename" value="meshes/bar.obj"/></shape>',
                   {"meshes/bar.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n"})
    with pytest.raises(SceneError, match=r"^meshes/bar\.obj:4: face index 99 out of range"):
        load_scene(p)


def test_billion_laughs_is_refused(tmp_path):
    p = tmp_path / "scene.xml"
    ents = "\n".join(f'  <!ENTITY lol{i} "{("&lol%d;" % (i - 1)) * 10}">' for i in range(1, 10))
    p.write_text(f'<?xml version="1.0"?>\n<!DOCTYPE scene [\n  <!ENTITY lol0 "lol">\n{ents}\n]>\n'
                 '<scene version="3.0.0"><string name="x" value="&lol9;"/></scene>\n')
    msg = assert_error(p, 3, "entity")
    assert "lol0" in msg


def test_external_entity_is_refused(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("top secret")
    p = tmp_path / "scene.xml"
    p.write_text(f'<?xml version="1.0"?>\n<!DOCTYPE scene [\n<!ENTITY xxe SYSTEM "file://{secret}">\n]>\n'
                 '<scene version="3.0.0"><shape type="cube" id="&xxe;"/></scene>\n')
    msg = assert_error(p, 3, "entity")
    assert "top secret" not in msg


@pytest.mark.parametrize("body, text", [
    ('<shape type="cube"><boolean name="flip_normals" value="maybe"/></shape>', "is not 'true' or 'false'"),
    ('<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="6.5"/></film></sensor>',
     "is not an integer"),
    ('<bsdf type="dielectric" id="x"><string name="int_ior" value="unobtainium"/></bsdf><shape type="cube"><ref id="x"/></shape>',
     "unknown index of refraction"),
    ('<shape type="cube"><bsdf type="conductor"><string name="material" value="Xx"/></bsdf></shape>',
     "unknown conductor material"),
    ('<shape type="cube" id="a"/><shape type="cube" id="a"/>', "duplicate id 'a'"),
    ('<sensor type="perspective"><integer name="width" value="$nope"/></sensor>', "undefined parameter '$nope'"),
    ('<shape type="cube"><float value="1"/></shape>', "needs a 'name' attribute"),
])
def test_bad_values_raise_scene_error_with_line(tmp_path, body, text):
    p = scene_file(tmp_path, body)
    with pytest.raises(SceneError, match=r"scene\.xml:\d+: ") as e:
        load_scene(p)
    assert text in str(e.value)


def test_wrong_root_and_missing_file(tmp_path):
    p = tmp_path / "scene.xml"
    p.write_text("<notascene/>\n")
    assert_error(p, 1, "root element must be <scene>")
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "missing.xml")


def test_checkerboard_is_color0_where_u_and_v_fall_in_the_same_half_as_mitsuba_paints_it(tmp_path):
    # Mitsuba 3's checkerboard: color0 where (u mod 1 > 1/2) == (v mod 1 > 1/2), after to_uv
    p = scene_file(tmp_path, """
        <shape type="rectangle"><bsdf type="diffuse">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.9, 0.1, 0.1"/><rgb name="color1" value="0.1, 0.2, 0.8"/>
                <transform name="to_uv"><scale x="3" y="2"/><translate x="0.1" y="0.2"/></transform>
            </texture></bsdf></shape>""")
    s = load_mitsuba(p)
    tex = s.materials[0].diffuse
    assert not any("texture" in w or "to_uv" in w for w in s.warnings) and not tex.is_constant
    rng = np.random.default_rng(3)
    uv_m = rng.random((2000, 2)) * 4 - 2  # Mitsuba's (u, v), beyond [0, 1] too: it repeats
    a, b = 3 * uv_m[:, 0] + 0.1, 2 * uv_m[:, 1] + 0.2
    first = ((a - np.floor(a)) > 0.5) == ((b - np.floor(b)) > 0.5)
    got = tex.eval(np.stack([uv_m[:, 0], 1.0 - uv_m[:, 1]], -1))  # meshes hold (u, 1 - v)
    np.testing.assert_allclose(got, np.where(first[:, None], [0.9, 0.1, 0.1], [0.1, 0.2, 0.8]), atol=1e-6)


@pytest.mark.parametrize("weight, kind", [(0.8, CONDUCTOR), (0.2, DIFFUSE)])
def test_blendbsdf_stands_for_its_heavier_nested_bsdf(tmp_path, weight, kind):
    p = scene_file(tmp_path, f"""
        <shape type="cube"><bsdf type="blendbsdf"><float name="weight" value="{weight}"/>
            <bsdf type="diffuse"/><bsdf type="conductor"/></bsdf></shape>""")
    s = load_mitsuba(p)
    assert s.materials[0].kind == kind
    which = "second" if weight > 0.5 else "first"
    assert f"using its {which} nested BSDF (weight {weight:g})" in "\n".join(s.warnings)


def test_a_blendbsdfs_textured_weight_is_taken_at_its_mean_and_the_warning_says_so(tmp_path):
    p = scene_file(tmp_path, """
        <shape type="cube"><bsdf type="blendbsdf"><texture type="checkerboard" name="weight">
            <float name="color0" value="0.9"/><float name="color1" value="0.5"/></texture>
            <bsdf type="diffuse"/><bsdf type="conductor"/></bsdf></shape>""")
    s = load_mitsuba(p)
    assert s.materials[0].kind == CONDUCTOR
    assert "using its second nested BSDF (weight 0.7, its texture's mean)" in "\n".join(s.warnings)
