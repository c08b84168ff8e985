"""Mitsuba's ``.serialized`` meshes (``<shape type="serialized">``), the binary format of
Mitsuba 0.5/0.6 that Mitsuba 3 still reads and many published scenes use.

A file is a run of meshes, each a little-endian ``uint16`` 0x041C, a ``uint16`` version (3 or
4) and a zlib stream holding: ``uint32`` flags (0x1 vertex normals, 0x2 texture coordinates,
0x8 vertex colours, 0x2000 double precision; 0x10, face normals, Mitsuba 3 ignores), the mesh's name (version 4:
UTF-8, NUL-terminated), ``uint64`` vertex and triangle counts, the positions, normals, uvs and
colours (those present, float32 or float64) and the triangles (``uint32``, ``uint64`` past 2³²
vertices). The file ends with each mesh's offset (``uint64``; version 3: ``uint32``) and a
``uint32`` mesh count: ``shape_index`` reads the mesh at its offset.

Like Mitsuba 3's ``ply`` (and unlike its ``obj``), the texture coordinates are the file's: meshes
in a :class:`~common.scene.Scene` store ``1 - v_mitsuba`` (:mod:`common.shapes`), so the uvs
returned are ``(u, 1 - v)``.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from .obj_mtl import drop_nonfinite
from .scene import SceneError
from .limits import fmt_bytes, memory_budget
from .scene_root import read_bytes

HEADER = 0x041C
VERSIONS = (3, 4)
HAS_NORMALS, HAS_TEXCOORDS, HAS_COLORS, DOUBLE_PRECISION = 0x1, 0x2, 0x8, 0x2000
# (flag 0x10, "face normals", is not read: Mitsuba 3 takes face_normals from the XML alone)
MAX_NAME = 4096  # bytes of a mesh's name (version 4)


def load_serialized_mesh(path, display: str | None = None, shape_index: int = 0,
                         warnings: list[str] | None = None, data: bytes | None = None) -> tuple:
    """Mesh ``shape_index`` of a ``.serialized`` file: ``(vertices, faces int32, normals|None,
    uvs|None, name)`` in the file's space, ``name`` the one stored with it ("" in version 3).
    ``data``: the file's bytes, where the caller holds them (its meshes share one file)."""
    path = Path(path)
    display = display or str(path)
    if data is None:
        data = read_bytes(path, display)
    try:
        return _load(memoryview(data), display, shape_index, warnings)
    except SceneError:
        raise
    except (ValueError, struct.error, zlib.error, OverflowError, MemoryError) as e:
        raise SceneError(f"{display}: malformed serialized mesh ({e})") from None


def _load(data: memoryview, display: str, shape_index: int, warnings: list[str] | None) -> tuple:
    if len(data) < 4:
        raise SceneError(f"{display}: not a Mitsuba serialized file (too short)")
    header, version = struct.unpack_from("<HH", data, 0)
    if header != HEADER:
        raise SceneError(f"{display}: not a Mitsuba serialized file (header 0x{header:04X}, expected 0x041C)")
    if version not in VERSIONS:
        raise SceneError(f"{display}: serialized format version {version} is not supported (3 or 4)")
    if shape_index < 0:
        raise SceneError(f"{display}: shape_index {shape_index} must be nonnegative")
    start = 0 if shape_index == 0 else _offset(data, display, version, shape_index)
    if struct.unpack_from("<HH", data, start) != (HEADER, version):
        raise SceneError(f"{display}: mesh {shape_index} does not start with the serialized header")
    what = f"{display}: mesh {shape_index}"
    z = zlib.decompressobj()
    # the header first (flags, name, counts), then exactly the bytes its counts need: a small
    # file cannot inflate past what it claims, and what it claims is held to the memory budget
    raw = z.decompress(data[start + 4:], 4 + MAX_NAME + 16)
    pos = 4
    if len(raw) < 4:
        raise SceneError(f"{what}'s data is truncated")
    (flags,) = struct.unpack_from("<I", raw, 0)
    name = ""
    if version == 4:
        end = raw.find(b"\0", 4)
        if end < 0:
            raise SceneError(f"{what}'s name is not terminated within {MAX_NAME} bytes")
        name = bytes(raw[4:end]).decode("utf-8", errors="replace")
        pos = end + 1
    if len(raw) < pos + 16:
        raise SceneError(f"{what}'s data is truncated")
    nv, nt = struct.unpack_from("<QQ", raw, pos)
    pos += 16
    real = np.dtype("<f8") if flags & DOUBLE_PRECISION else np.dtype("<f4")
    index = np.dtype("<u8") if nv > 0xFFFFFFFF else np.dtype("<u4")
    columns = 3 + 3 * bool(flags & HAS_NORMALS) + 2 * bool(flags & HAS_TEXCOORDS) + 3 * bool(flags & HAS_COLORS)
    need = pos + nv * columns * real.itemsize + nt * 3 * index.itemsize
    if need > memory_budget():
        raise SceneError(f"{what} claims {nv} vertices and {nt} triangles ({fmt_bytes(need)}), more than the "
                         f"memory budget of {fmt_bytes(memory_budget())}")
    raw = bytes(raw) + z.decompress(z.unconsumed_tail, need - len(raw)) if need > len(raw) else bytes(raw)
    if len(raw) < need:
        raise SceneError(f"{what}'s data is truncated ({len(raw)} of {need} bytes)")

    def array(cols: int, dtype: np.dtype, count: int) -> np.ndarray:
        nonlocal pos
        out = np.frombuffer(raw, dtype, count * cols, pos).reshape(count, cols)
        pos += count * cols * dtype.itemsize
        return out.astype(np.int64 if dtype.kind == "u" else np.float64)

    V = array(3, real, nv)
    N = array(3, real, nv) if flags & HAS_NORMALS else None
    UV = array(2, real, nv) if flags & HAS_TEXCOORDS else None
    if flags & HAS_COLORS:
        array(3, real, nv)  # (vertex colours: not used)
    F = array(3, index, nt)
    if len(F) and F.max() >= nv:
        bad = int(F[F >= nv][0])
        raise SceneError(f"{what}: face index {bad} out of range (it has {nv} vertices)")
    if N is not None:
        ln = np.linalg.norm(N, axis=1, keepdims=True)
        N = np.where(ln > 0, N / np.where(ln > 0, ln, 1.0), 0.0)
    if UV is not None:
        UV[:, 1] = 1.0 - UV[:, 1]
    faces = drop_nonfinite(display, V, F.astype(np.int32), N, UV, warnings)
    return V, faces, N, UV, name


def _offset(data: memoryview, display: str, version: int, shape_index: int) -> int:
    """The byte offset of mesh ``shape_index`` from the end-of-file dictionary."""
    if len(data) < 8:
        raise SceneError(f"{display}: no end-of-file dictionary of meshes")
    (count,) = struct.unpack_from("<I", data, len(data) - 4)
    if shape_index >= count:
        raise SceneError(f"{display}: shape_index {shape_index} is out of range (the file holds {count} meshes)")
    size = 8 if version == 4 else 4
    at = len(data) - 4 - size * (count - shape_index)
    if at < 4:
        raise SceneError(f"{display}: the end-of-file dictionary of {count} meshes does not fit the file")
    (offset,) = struct.unpack_from("<Q" if size == 8 else "<I", data, at)
    if offset + 4 > at:
        raise SceneError(f"{display}: mesh {shape_index}'s offset {offset} lies outside the file")
    return int(offset)
