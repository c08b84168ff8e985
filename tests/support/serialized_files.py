"""Mitsuba ``.serialized`` files written for tests (the format of common.serialized; Mitsuba
3.9.1 reads these back)."""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from igi.common.serialized import DOUBLE_PRECISION, HAS_NORMALS, HAS_TEXCOORDS, HEADER

SINGLE_PRECISION = 0x1000


def write_serialized(path, meshes: list[tuple], version: int = 4, double: bool = False) -> None:
    """Write ``meshes`` — (vertices, faces, normals|None, uvs in Mitsuba's v|None, name) each —
    as a ``.serialized`` file (Mitsuba 3 reads it back)."""
    real = "<f8" if double else "<f4"
    out = bytearray()
    offsets = []
    for V, F, N, UV, name in meshes:
        offsets.append(len(out))
        flags = (HAS_NORMALS if N is not None else 0) | (HAS_TEXCOORDS if UV is not None else 0)
        flags |= DOUBLE_PRECISION if double else SINGLE_PRECISION
        body = struct.pack("<I", flags)
        if version == 4:
            body += name.encode() + b"\0"
        body += struct.pack("<QQ", len(V), len(F))
        for a in (V, N, UV):
            if a is not None:
                body += np.ascontiguousarray(a, real).tobytes()
        body += np.ascontiguousarray(F, "<u4").tobytes()
        out += struct.pack("<HH", HEADER, version) + zlib.compress(body)
    for o in offsets:
        out += struct.pack("<Q" if version == 4 else "<I", o)
    out += struct.pack("<I", len(meshes))
    Path(path).write_bytes(bytes(out))
