"""OBJ/MTL loading with Mitsuba 3's semantics (reference behaviour checked against Mitsuba 3.9.1)."""
import glob
from pathlib import Path

import numpy as np
import pytest

from igi.common.loader import load_scene
from igi.common.obj_mtl import _parse_fast, _parse_slow, load_obj_mesh, load_obj_scene, recompute_vertex_normals
from igi.common.scene import AREA, CONDUCTOR, DIELECTRIC, DIFFUSE, ROUGHPLASTIC, SceneError

from tests.support.paths import SCENES

needs_scenes = pytest.mark.skipif(not SCENES.is_dir(), reason="shared scenes not available")

CUBE = """v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


# ------------------------------------------------------------------------------ whole scenes


@needs_scenes
@pytest.mark.parametrize("folder", ["cornell-box", "cornell-box-sphere", "cornell-box-glossy", "cornell-box-water"])
def test_mcguire_obj_mtl_loads_as_scene_with_emitter_matching_the_xml_version(folder):
    obj = next((SCENES / folder).glob("CornellBox-*.obj"))
    s = load_scene(obj)
    x = load_scene(SCENES / folder / "scene.xml")
    assert len(s.emitters) == 1 and s.emitters[0].kind == AREA
    light = s.meshes[s.emitters[0].mesh]
    assert light.emitter == 0 and light.name == "light"
    np.testing.assert_allclose(s.emitters[0].radiance, [17, 12, 4])
    assert s.triangle_count == x.triangle_count
    assert (s.camera.width, s.camera.height) == (640, 480)
    # one mesh per usemtl group, with the same triangles (and normals) as the XML's split meshes
    xm = {m.name: m for m in x.meshes}
    for m in s.meshes:
        ref = xm[m.name]
        np.testing.assert_allclose(m.vertices[m.faces], ref.vertices[ref.faces], atol=1e-6)
        np.testing.assert_allclose(m.normals[m.faces], ref.normals[ref.faces], atol=1e-6)
        assert s.materials[m.material].kind == x.materials[ref.material].kind
    lo, hi = s.bounds()
    cam_pos = s.camera.to_world[:3, 3]
    assert cam_pos[2] > hi[2]  # in front of the (open) box, looking along -z
    np.testing.assert_allclose(s.camera.to_world[:3, 2], [0, 0, -1], atol=1e-12)


def test_mtl_mapping_rules(tmp_path):
    write(tmp_path, "m.mtl", """newmtl mirror
illum 5
Ks 0.9 0.9 0.9
newmtl glass
illum 7
Ni 1.7
newmtl glossy
Kd 0.5 0.4 0.3
Ks 0.3 0.3 0.3
Ns 98
newmtl matte
Kd 0.2 0.3 0.4 # comment
newmtl lamp
Kd 0.1 0.1 0.1
Ke 5 6 7
""")
    body = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
    for name in ("mirror", "glass", "glossy", "matte", "lamp"):
        body += f"usemtl {name}\nf 1 2 3\n"
    s = load_obj_scene(write(tmp_path, "s.obj", body))
    mats = {m.name: m for m in s.materials}
    assert mats["mirror"].kind == CONDUCTOR and np.allclose(mats["mirror"].specular.rgb, 0.9)
    assert mats["glass"].kind == DIELECTRIC and mats["glass"].int_ior == 1.7
    assert mats["glossy"].kind == ROUGHPLASTIC and mats["glossy"].distribution == "beckmann"
    assert mats["glossy"].alpha == pytest.approx(np.sqrt(2 / 100))
    assert mats["matte"].kind == DIFFUSE and np.allclose(mats["matte"].diffuse.rgb, [0.2, 0.3, 0.4])
    assert len(s.emitters) == 1 and np.allclose(s.emitters[0].radiance, [5, 6, 7])
    assert s.meshes[s.emitters[0].mesh].name == "lamp"


def test_missing_mtl_gives_warning_and_default_diffuse(tmp_path):
    s = load_obj_scene(write(tmp_path, "s.obj", "mtllib nope.mtl\nusemtl x\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"))
    assert any("nope.mtl" in w and "not found" in w for w in s.warnings)
    assert s.materials[0].kind == DIFFUSE and np.allclose(s.materials[0].diffuse.rgb, 0.5)


def test_map_kd_becomes_bitmap_texture(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((4, 2, 3), 255, np.uint8)).save(tmp_path / "t.png")
    write(tmp_path, "m.mtl", "newmtl tex\nKd 1 1 1\nmap_Kd -s 2 3 1 t.png\n")
    s = load_obj_scene(write(tmp_path, "s.obj", "mtllib m.mtl\nusemtl tex\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                                "vt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"))
    tex = s.materials[0].diffuse
    assert not tex.is_constant and tex.image.shape == (4, 2, 3) and tex.uv_scale == (2.0, 3.0)


# ------------------------------------------------------------------------------ single meshes


def test_quads_are_fan_triangulated_and_vertices_deduplicated_by_index_triple(tmp_path):
    p = write(tmp_path, "q.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n"
                                 "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0 0\n"
                                 "f 1/1 2/2 3/3 4/4\n"
                                 "f 2/2 5/1 3/5\n")  # vt 5 has the same value as vt 1 but a different index
    v, f, n, uv = load_obj_mesh(p)
    assert f.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5]]
    assert len(v) == 6  # (v3, vt5) is a new vertex: Mitsuba keys on indices, not values
    np.testing.assert_allclose(v[5], v[2])
    assert n is None  # no vn: the caller recomputes normals after to_world
    # uvs are stored as in the file (Mitsuba flips v and its bitmaps flip it back, see common.shapes)
    np.testing.assert_allclose(uv[:4], [[0, 0], [1, 0], [1, 1], [0, 1]])


def test_negative_indices_are_relative_to_the_vertices_read_so_far(tmp_path):
    p = write(tmp_path, "n.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf -3 -2 -1\n")
    v, f, _, _ = load_obj_mesh(p)
    np.testing.assert_allclose(v[f[1]], [[5, 5, 5], [6, 5, 5], [5, 6, 5]])


def test_vn_are_normalized_and_used_per_index(tmp_path):
    p = write(tmp_path, "vn.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nvn 0 1 1\nf 1//1 2//1 3//2\n")
    v, f, n, uv = load_obj_mesh(p)
    assert uv is None
    np.testing.assert_allclose(n, [[0, 0, 1], [0, 0, 1], [0, 2 ** -0.5, 2 ** -0.5]])


def test_smooth_normals_are_angle_weighted_like_mitsuba():
    # Mitsuba 3.9.1 gives every corner of a closed cube (no vn) the normal (+-1,+-1,+-1)/sqrt(3)
    lines = CUBE.splitlines()
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    quads = [[int(x) - 1 for x in ln.split()[1:]] for ln in lines if ln.startswith("f ")]
    tris = np.array([t for q in quads for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])])
    n = recompute_vertex_normals(v, tris)
    np.testing.assert_allclose(n, v / np.sqrt(3), atol=1e-12)
    # a vertex touched only by a degenerate triangle gets Mitsuba's fallback (1, 0, 0)
    n = recompute_vertex_normals(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.array([[0, 1, 2]]))
    np.testing.assert_allclose(n, [[1, 0, 0]] * 3)


def test_nonfinite_vertex_drops_its_triangles_with_warning(tmp_path):
    p = write(tmp_path, "nan.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nf 1 2 3\nf 1 2 4\n")
    warnings = []
    v, f, _, _ = load_obj_mesh(p, "nan.obj", warnings)
    assert f.tolist() == [[0, 1, 2]]
    assert any("nan.obj" in w and "non-finite" in w for w in warnings)


@pytest.mark.parametrize("text, line, what", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 99\n", 5, "face index 99 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", 4, "face index 0 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n", 5, "face index 2 out of range"),
    ("v 0 0 0\nv 1 abc 0\nv 0 1 0\nf 1 2 3\n", 2, "'abc' is not a number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3x\n", 4, "'3x' is not an integer"),
    ("v 0 0 0\nv 1 0\n", 2, "needs 3 coordinates"),
])
def test_malformed_obj_raises_scene_error_with_file_and_line(tmp_path, text, line, what):
    p = write(tmp_path, "bar.obj", text)
    with pytest.raises(SceneError) as e:
        load_obj_mesh(p, "meshes/bar.obj")
    assert str(e.value).startswith(f"meshes/bar.obj:{line}: ")
    assert what in str(e.value)


def test_missing_obj_file_raises_scene_error(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_obj_mesh(tmp_path / "nope.obj")
    with pytest.raises(SceneError, match="unknown scene format"):
        load_scene(tmp_path / "scene.fbx")


@needs_scenes
def test_fast_parser_agrees_with_exact_parser_on_shared_meshes():
    files = sorted(glob.glob(str(SCENES / "*" / "meshes" / "*.obj")))[:12] + \
        sorted(glob.glob(str(SCENES / "veach-bidir" / "models" / "*.obj")))[:6]
    assert files
    for f in files:
        raw = Path(f).read_bytes()
        a, b = _parse_fast(raw), _parse_slow(raw.decode(), f)
        assert a is not None, f
        for k in ("positions", "texcoords", "normals", "corners", "face_sizes"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=f"{f}: {k}")
