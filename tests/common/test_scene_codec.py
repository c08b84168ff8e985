"""Scene <-> bytes without pickle, content hash, validation on decode, scene edits."""
from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest

from igi.bench.stress_scenes import mini_cornell
from tests.support.paths import SHARED
from igi.common import scene_codec as sc
from igi.common.scene import SceneError, Texture


def textured_scene():
    s = mini_cornell()
    s.materials[0].diffuse = Texture(image=np.random.default_rng(0).random((5, 7, 3), dtype=np.float32),
                                     uv_scale=(2.0, 3.0), name="noise")
    m = s.meshes[0]
    m.normals = np.tile([0.0, 1.0, 0.0], (len(m.vertices), 1))
    m.uvs = np.random.default_rng(1).random((len(m.vertices), 2))
    s.warnings = ["a warning"]
    return s


def assert_same(a, b, path="scene"):
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, path
        assert np.array_equal(a, b), path
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, (int, float)) and not isinstance(a, bool):
        assert a == b and isinstance(b, (int, float)), path
    else:
        assert a == b and type(a) is type(b), path


def test_round_trip_is_exact_and_deterministic():
    s = textured_scene()
    blob = sc.encode_scene(s)
    back = sc.decode_scene(blob, expected_hash=sc.scene_hash(blob))
    assert_same(s, back)
    assert sc.encode_scene(back) == blob  # deterministic: same content, same bytes, same hash
    assert back.digest() == s.digest()
    assert len(sc.scene_hash(blob)) == 64


@pytest.mark.parametrize("name", ["cornell-box-sphere", "veach-ajar"])  # veach-ajar: bitmap textures
def test_shared_scene_round_trip(name):
    from igi.common.loader import load_scene

    s = load_scene(SHARED / "scenes" / name / "scene.xml")
    blob = sc.encode_scene(s)
    assert_same(s, sc.decode_scene(blob, expected_hash=sc.scene_hash(blob)))


def test_the_cameras_reconstruction_filter_travels_with_the_scene():
    scene = mini_cornell()
    scene.camera = dataclasses.replace(scene.camera, rfilter="tent", rfilter_params=(1.5, 0.0))
    back = sc.decode_scene(sc.encode_scene(scene))
    assert (back.camera.rfilter, back.camera.rfilter_params) == ("tent", (1.5, 0.0))
    assert sc.scene_hash(sc.encode_scene(scene)) != sc.scene_hash(sc.encode_scene(mini_cornell()))


def test_corrupt_blobs_raise_scene_error():
    blob = sc.encode_scene(mini_cornell())
    for bad in (b"", b"garbage", blob[:-10], sc.MAGIC + b"\0" * 50, blob[:20] + b"x" + blob[21:]):
        with pytest.raises(SceneError):
            sc.decode_scene(bad)
    with pytest.raises(SceneError, match="hash"):
        sc.decode_scene(blob, expected_hash="0" * 64)


def _blob_of(tree) -> bytes:
    import lz4.frame

    return sc.MAGIC + lz4.frame.compress(msgpack.packb(tree, use_bin_type=True))


@pytest.mark.parametrize("mutate,match", [
    (lambda t: t["meshes"][0]["faces"].update(data=np.array([[0, 1, 99]] * 2, np.int32).tobytes()), "face index"),
    (lambda t: t["meshes"][0]["faces"].update(__nd__="|O"), "dtype"),
    (lambda t: t["meshes"][0]["vertices"].update(shape=[4, 3, 1000]), "bytes"),
    (lambda t: t["meshes"][0].update(material=17), "material index"),
    (lambda t: t["meshes"][0].update(evil="x"), "unknown"),
    (lambda t: t["meshes"][0].update(name=5), "string"),
    (lambda t: t["emitters"][0].update(mesh=99), "mesh index"),
    (lambda t: t.pop("camera"), "missing"),
    (lambda t: t["materials"][0]["diffuse"].update(uv_scale=[1, 2]), "tuple"),
    (lambda t: t["camera"].update(rfilter="sinc"), "unknown reconstruction filter 'sinc'"),
    (lambda t: t["camera"].update(aperture_radius=-1.0), "thin lens: aperture radius -1.0"),
    (lambda t: t["camera"].update(aperture_radius=0.1, focus_distance=0.0), "focus distance 0.0"),
    (lambda t: t["camera"].update(rfilter="gaussian", rfilter_params={"__tuple__": [float("nan"), 0.0]}),
     "not finite"),
])
def test_decode_validates_content(mutate, match):
    tree = sc.scene_to_dict(mini_cornell())
    mutate(tree)
    with pytest.raises(SceneError, match=match):
        sc.decode_scene(_blob_of(tree))


def test_transform_mesh_moves_vertices_and_normals_only_of_that_mesh():
    s = textured_scene()
    before = s.meshes[0].vertices.copy()
    m = np.eye(4)
    m[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90° about z
    m[:3, 3] = [1, 2, 3]
    e = sc.apply_edit(s, {"op": "transform_mesh", "mesh": "floor", "matrix": m.ravel().tolist()})
    assert np.allclose(e.meshes[0].vertices, before @ m[:3, :3].T + [1, 2, 3])
    assert np.allclose(e.meshes[0].normals, [-1.0, 0.0, 0.0])
    assert np.array_equal(s.meshes[0].vertices, before), "the input scene is not mutated"
    assert e.meshes[1] is s.meshes[1]
    assert sc.scene_hash(sc.encode_scene(e)) != sc.scene_hash(sc.encode_scene(s))


def test_material_and_emitter_edits():
    s = mini_cornell()
    e = sc.apply_edit(s, {"op": "set_material", "material": "red", "param": "diffuse", "value": [0.1, 0.2, 0.3]})
    assert np.allclose(e.materials[1].diffuse.rgb, [0.1, 0.2, 0.3]) and np.allclose(s.materials[1].diffuse.rgb, [0.7, 0.1, 0.1])
    e = sc.apply_edit(e, {"op": "set_material", "material": 0, "param": "alpha", "value": 0.3})
    assert e.materials[0].alpha == 0.3
    e = sc.apply_edit(e, {"op": "set_emitter", "emitter": "light", "param": "radiance", "value": [1, 2, 3]})
    assert np.allclose(e.emitters[0].radiance, [1, 2, 3])
    e2 = sc.apply_edit(e, {"op": "set_emitter", "emitter": 0, "param": "position", "value": [1.0, 1.5, 1.0]})
    li = e.emitters[0].mesh
    assert np.allclose(e2.meshes[li].vertices.mean(axis=0), [1.0, 1.5, 1.0])
    assert np.allclose(e2.emitters[0].position, [1.0, 1.5, 1.0])


@pytest.mark.parametrize("edit,match", [
    ("nope", "map"),
    ({"op": "delete_everything"}, "unknown op"),
    ({"op": "transform_mesh", "mesh": 99, "matrix": np.eye(4).ravel().tolist()}, "outside"),
    ({"op": "transform_mesh", "mesh": "nope", "matrix": np.eye(4).ravel().tolist()}, "no mesh"),
    ({"op": "transform_mesh", "mesh": 0, "matrix": [0.0] * 15 + [1.0]}, "singular"),
    ({"op": "transform_mesh", "mesh": 0, "matrix": [1.0] * 16}, "affine"),
    ({"op": "transform_mesh", "mesh": 0, "matrix": [float("nan")] * 16}, "finite"),
    ({"op": "transform_mesh", "mesh": 0}, "missing"),
    ({"op": "set_material", "material": 0, "param": "evil", "value": 1}, "unknown material parameter"),
    ({"op": "set_material", "material": 0, "param": "alpha", "value": -1}, "alpha"),
    ({"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [-1, 0, 0]}, ">= 0"),
    ({"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [1, 2]}, "3 number"),
    ({"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [1, 2, 3], "x": 1}, "unknown key"),
])
def test_bad_edits_raise_value_error(edit, match):
    with pytest.raises(ValueError, match=match):
        sc.apply_edit(mini_cornell(), edit)
