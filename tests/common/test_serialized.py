"""Mitsuba's .serialized meshes (common.serialized) as Mitsuba 3.9.1 reads them: files written by
tests/support/serialized_files.py, which Mitsuba 3.9.1 loaded to the same positions, faces,
uvs (the file's v, no flip) and normals while this reader was written."""
import struct
import zlib

import numpy as np
import pytest

from igi.common.mitsuba_xml import load_mitsuba
from igi.common.scene import SceneError
from igi.common.serialized import HEADER, load_serialized_mesh
from tests.support.serialized_files import write_serialized

RNG = np.random.default_rng(0)
V1, F1, N1, UV1 = RNG.random((5, 3)), np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4]]), RNG.normal(size=(5, 3)), RNG.random((5, 2))
V2, F2, UV2 = RNG.random((4, 3)) + 2, np.array([[0, 1, 2], [0, 2, 3]]), RNG.random((4, 2))
MESHES = [(V1, F1, N1, UV1, "first"), (V2, F2, None, UV2, "second")]


def _scene(tmp_path, shapes: str) -> str:
    p = tmp_path / "scene.xml"
    p.write_text(f'<scene version="3.0.0"><sensor type="perspective"/>{shapes}</scene>')
    return p


@pytest.mark.parametrize("version,double", [(4, False), (3, True)])
def test_meshes_read_by_shape_index_as_mitsuba_reads_them(tmp_path, version, double):
    write_serialized(tmp_path / "m.serialized", MESHES, version=version, double=double)
    s = load_mitsuba(_scene(tmp_path, "".join(
        f'<shape type="serialized"><string name="filename" value="m.serialized"/>'
        f'<integer name="shape_index" value="{i}"/></shape>' for i in (1, 0))))
    second, first = s.meshes
    tol = 1e-7 if not double else 0.0
    np.testing.assert_allclose(first.vertices, V1.astype(np.float32 if not double else np.float64), atol=tol)
    np.testing.assert_array_equal(first.faces, F1)
    np.testing.assert_allclose(first.normals, N1 / np.linalg.norm(N1, axis=1, keepdims=True), atol=1e-6)
    np.testing.assert_allclose(first.uvs, np.column_stack([UV1[:, 0], 1 - UV1[:, 1]]), atol=1e-7)  # (1 - Mitsuba's v)
    np.testing.assert_allclose(second.vertices, V2, atol=1e-6)
    np.testing.assert_array_equal(second.faces, F2)
    assert second.normals is not None and np.allclose(np.linalg.norm(second.normals, axis=1), 1)  # recomputed
    # Mitsuba's names: the one stored with the mesh (version 4), else file@index
    want = ("first", "second") if version == 4 else ("m.serialized@0", "m.serialized@1")
    assert (first.name, second.name) == want


def test_the_files_face_normals_flag_is_ignored_as_mitsuba_3_ignores_it(tmp_path):
    """Mitsuba 3.9.1 reads face_normals from the XML alone; flag 0x10 in the file changes nothing."""
    path = tmp_path / "m.serialized"
    write_serialized(path, MESHES[:1])
    data = bytearray(path.read_bytes())
    body = zlib.decompress(bytes(data[4:]))
    body = struct.pack("<I", struct.unpack_from("<I", body)[0] | 0x10) + body[4:]
    path.write_bytes(bytes(data[:4]) + zlib.compress(body) + struct.pack("<QI", 0, 1))
    shape = '<shape type="serialized"><string name="filename" value="m.serialized"/>{}</shape>'
    s = load_mitsuba(_scene(tmp_path, shape.format("")))
    assert s.meshes[0].normals is not None  # smooth: the file's normals
    s = load_mitsuba(_scene(tmp_path, shape.format('<boolean name="face_normals" value="true"/>')))
    assert s.meshes[0].normals is None  # flat only where the XML says so


def test_a_files_meshes_share_one_read_of_it(tmp_path, monkeypatch):
    from igi.common import mitsuba_shapes

    write_serialized(tmp_path / "m.serialized", MESHES)
    reads = []
    real = mitsuba_shapes.read_bytes
    monkeypatch.setattr(mitsuba_shapes, "read_bytes", lambda *a: reads.append(a[0]) or real(*a))
    s = load_mitsuba(_scene(tmp_path, "".join(
        f'<shape type="serialized"><string name="filename" value="m.serialized"/>'
        f'<integer name="shape_index" value="{i}"/></shape>' for i in (1, 0, 1))))
    assert len(s.meshes) == 3 and len(reads) == 1


def _broken(tmp_path, mutate) -> str:
    path = tmp_path / "m.serialized"
    write_serialized(path, MESHES)
    path.write_bytes(mutate(path.read_bytes()))
    return path


def _body(data: bytes) -> bytes:
    return zlib.decompressobj().decompress(data[4:])


@pytest.mark.parametrize("mutate,index,what", [
    (lambda d: b"", 0, "too short"),
    (lambda d: struct.pack("<HH", 0x1234, 4) + d[4:], 0, "header 0x1234"),
    (lambda d: struct.pack("<HH", HEADER, 5) + d[4:], 0, "version 5"),
    (lambda d: d[:40], 0, "truncated"),
    (lambda d: d, 2, "shape_index 2 is out of range"),
    (lambda d: d, -1, "must be nonnegative"),
    (lambda d: d[:4] + zlib.compress(_body(d)[:-8]), 0, "truncated"),
    (lambda d: d[:4] + zlib.compress(_body(d)[:-4] + struct.pack("<I", 99)), 0, "face index 99 out of range"),
    (lambda d: d[:4] + zlib.compress(_body(d)[:10] + struct.pack("<QQ", 1 << 40, 1) + _body(d)[26:]), 0,
     "claims 1099511627776 vertices .* more than the memory budget"),
    (lambda d: d[:4] + zlib.compress(b"\0" * 4 + b"x" * 5000), 0, "not terminated within 4096 bytes"),
    (lambda d: d[:-12] + struct.pack("<QI", 10 ** 9, 2), 1, "outside the file"),
    (lambda d: d[:4] + b"not zlib at all", 0, "malformed serialized mesh"),
])
def test_malformed_files_are_named(tmp_path, mutate, index, what):
    path = _broken(tmp_path, mutate)
    with pytest.raises(SceneError, match=what) as e:
        load_serialized_mesh(path, "m.serialized", index)
    assert "m.serialized" in str(e.value)


def test_a_missing_file_and_a_missing_filename_are_named(tmp_path):
    with pytest.raises(SceneError, match="nope.serialized"):
        load_mitsuba(_scene(tmp_path, '<shape type="serialized"><string name="filename" value="nope.serialized"/></shape>'))
    with pytest.raises(SceneError, match="needs a 'filename'"):
        load_mitsuba(_scene(tmp_path, '<shape type="serialized"/>'))
