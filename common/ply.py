"""Minimal PLY reader for ``<shape type="ply">``.

Supports ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` files with a ``vertex``
element (``x y z``, optional ``nx ny nz``, optional ``u v`` / ``s t`` / ``texture_u texture_v``)
and a ``face`` element with a ``vertex_indices`` (or ``vertex_index``) list; polygons are
fan-triangulated. Other elements are skipped.

Mitsuba 3's ``ply`` shape does *not* flip texture coordinates (unlike its ``obj`` shape): its
surface ``v`` is the file's ``v``. Meshes in a :class:`~common.scene.Scene` store ``1 - v_mitsuba``
(see :mod:`common.shapes`), so the returned uvs are ``(u, 1 - v)``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .obj_mtl import _warn, drop_nonfinite
from .scene import SceneError
from .scene_root import read_bytes

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class _Element:
    def __init__(self, name: str, count: int, line: int):
        self.name = name
        self.count = count
        self.line = line
        self.props: list[tuple] = []  # (name, type) or (name, "list", count_type, item_type)


def _parse_header(f, display: str):
    magic = f.readline()
    if magic.strip() != b"ply":
        raise SceneError(f"{display}:1: not a PLY file (missing 'ply' magic)")
    fmt = None
    elements: list[_Element] = []
    lineno = 1
    while True:
        raw = f.readline()
        lineno += 1
        if not raw:
            raise SceneError(f"{display}:{lineno}: unexpected end of file in the header")
        parts = raw.decode("ascii", errors="replace").split()
        if not parts:
            continue
        kw = parts[0]
        if kw == "end_header":
            break
        if kw in ("comment", "obj_info"):
            continue
        if kw == "format":
            if len(parts) < 2 or parts[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise SceneError(f"{display}:{lineno}: unsupported PLY format '{' '.join(parts[1:])}'")
            fmt = parts[1]
        elif kw == "element":
            try:
                elements.append(_Element(parts[1], int(parts[2]), lineno))
            except (IndexError, ValueError):
                raise SceneError(f"{display}:{lineno}: malformed element line") from None
            if elements[-1].count < 0:
                raise SceneError(f"{display}:{lineno}: negative element count")
        elif kw == "property":
            if not elements:
                raise SceneError(f"{display}:{lineno}: property before any element")
            if len(parts) >= 5 and parts[1] == "list":
                if parts[2] not in _TYPES or parts[3] not in _TYPES:
                    raise SceneError(f"{display}:{lineno}: unknown PLY type in '{raw.decode().strip()}'")
                elements[-1].props.append((parts[4], "list", _TYPES[parts[2]], _TYPES[parts[3]]))
            elif len(parts) >= 3:
                if parts[1] not in _TYPES:
                    raise SceneError(f"{display}:{lineno}: unknown PLY type '{parts[1]}'")
                elements[-1].props.append((parts[2], _TYPES[parts[1]]))
            else:
                raise SceneError(f"{display}:{lineno}: malformed property line")
        else:
            raise SceneError(f"{display}:{lineno}: unexpected header line '{raw.decode(errors='replace').strip()}'")
    if fmt is None:
        raise SceneError(f"{display}: PLY header has no 'format' line")
    return fmt, elements, lineno


def _read_binary(buf: memoryview, pos: int, el: _Element, endian: str, display: str):
    """Returns (dict name -> array or list-array, new position)."""
    is_list = [len(p) == 4 for p in el.props]
    if not any(is_list):
        dt = np.dtype([(p[0], endian + p[1]) for p in el.props])
        need = dt.itemsize * el.count
        if pos + need > len(buf):
            raise SceneError(f"{display}: truncated PLY data in element '{el.name}'")
        arr = np.frombuffer(buf, dtype=dt, count=el.count, offset=pos)
        return {p[0]: arr[p[0]] for p in el.props}, pos + need
    if sum(is_list) == 1 and is_list[0] and el.count > 0:
        # Typical face element: one list property first, maybe scalars after. Try the uniform-size
        # fast path (every face has the same corner count).
        name, _, ct, it = el.props[0]
        cdt = np.dtype(endian + ct)
        if pos + cdt.itemsize > len(buf):
            raise SceneError(f"{display}: truncated PLY data in element '{el.name}'")
        n0 = int(np.frombuffer(buf, dtype=cdt, count=1, offset=pos)[0])
        fields = [("n", endian + ct), ("idx", endian + it, (n0,))] + [(p[0], endian + p[1]) for p in el.props[1:]]
        dt = np.dtype(fields)
        need = dt.itemsize * el.count
        if pos + need <= len(buf):
            arr = np.frombuffer(buf, dtype=dt, count=el.count, offset=pos)
            if bool(np.all(arr["n"] == n0)):
                out = {name: (np.full(el.count, n0, np.int64), arr["idx"].reshape(el.count, n0).astype(np.int64))}
                for p in el.props[1:]:
                    out[p[0]] = arr[p[0]]
                return out, pos + need
    # General (slow) path
    cols: dict[str, list] = {p[0]: [] for p in el.props}
    for _ in range(el.count):
        for p in el.props:
            if len(p) == 4:
                cdt, idt = np.dtype(endian + p[2]), np.dtype(endian + p[3])
                if pos + cdt.itemsize > len(buf):
                    raise SceneError(f"{display}: truncated PLY data in element '{el.name}'")
                n = int(np.frombuffer(buf, dtype=cdt, count=1, offset=pos)[0])
                pos += cdt.itemsize
                if n < 0 or pos + n * idt.itemsize > len(buf):
                    raise SceneError(f"{display}: truncated PLY data in element '{el.name}'")
                cols[p[0]].append(np.frombuffer(buf, dtype=idt, count=n, offset=pos).astype(np.int64))
                pos += n * idt.itemsize
            else:
                dt = np.dtype(endian + p[1])
                if pos + dt.itemsize > len(buf):
                    raise SceneError(f"{display}: truncated PLY data in element '{el.name}'")
                cols[p[0]].append(np.frombuffer(buf, dtype=dt, count=1, offset=pos)[0])
                pos += dt.itemsize
    out = {}
    for p in el.props:
        if len(p) == 4:
            lists = cols[p[0]]
            sizes = np.array([len(x) for x in lists], dtype=np.int64)
            flat = np.concatenate(lists) if lists else np.zeros(0, np.int64)
            out[p[0]] = (sizes, flat)
        else:
            out[p[0]] = np.array(cols[p[0]])
    return out, pos


def _read_ascii(lines: list[str], start: int, header_lines: int, el: _Element, display: str):
    out: dict[str, list] = {p[0]: [] for p in el.props}
    for i in range(el.count):
        li = start + i
        if li >= len(lines):
            raise SceneError(f"{display}: unexpected end of file in element '{el.name}' "
                             f"({i} of {el.count} read)")
        lineno = header_lines + li + 1
        toks = lines[li].split()
        k = 0
        try:
            for p in el.props:
                if len(p) == 4:
                    n = int(toks[k])
                    k += 1
                    out[p[0]].append([int(t) for t in toks[k:k + n]])
                    if len(out[p[0]][-1]) != n:
                        raise IndexError
                    k += n
                else:
                    out[p[0]].append(float(toks[k]))
                    k += 1
        except IndexError:
            raise SceneError(f"{display}:{lineno}: too few values for element '{el.name}'") from None
        except ValueError:
            raise SceneError(f"{display}:{lineno}: value '{toks[k]}' is not a number") from None
    res = {}
    for p in el.props:
        if len(p) == 4:
            lists = out[p[0]]
            sizes = np.array([len(x) for x in lists], dtype=np.int64)
            flat = np.array([v for x in lists for v in x], dtype=np.int64)
            res[p[0]] = (sizes, flat)
        else:
            res[p[0]] = np.array(out[p[0]], dtype=np.float64)
    return res, start + el.count


def load_ply_mesh(path, display: str | None = None, warnings: list[str] | None = None):
    """Read a PLY mesh: ``(vertices, faces int32, normals|None, uvs|None)`` in the file's space.

    ``uvs`` are in the scene convention (``(u, 1 - v)``, see the module docstring).
    """
    path = Path(path)
    display = display or str(path)
    try:
        return _load_ply(path, display, warnings)
    except SceneError:
        raise
    except (ValueError, IndexError, KeyError, TypeError, OverflowError) as e:
        raise SceneError(f"{display}: malformed PLY data ({e})") from None


def _load_ply(path: Path, display: str, warnings: list[str] | None):
    data = read_bytes(path, display)
    import io

    f = io.BytesIO(data)
    fmt, elements, header_lines = _parse_header(f, display)
    body_start = f.tell()
    values: dict[str, dict] = {}
    if fmt == "ascii":
        lines = [ln for ln in data[body_start:].decode("ascii", errors="replace").splitlines()]
        pos = 0
        for el in elements:
            values[el.name], pos = _read_ascii(lines, pos, header_lines, el, display)
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        buf = memoryview(data)
        pos = body_start
        for el in elements:
            values[el.name], pos = _read_binary(buf, pos, el, endian, display)
    if "vertex" not in values:
        raise SceneError(f"{display}: PLY file has no 'vertex' element")
    vx = values["vertex"]
    for c in ("x", "y", "z"):
        if c not in vx:
            raise SceneError(f"{display}: PLY vertex element has no '{c}' property")
    V = np.stack([np.asarray(vx[c], dtype=np.float64) for c in ("x", "y", "z")], axis=1)
    nv = len(V)
    N = None
    if all(c in vx for c in ("nx", "ny", "nz")):
        N = np.stack([np.asarray(vx[c], dtype=np.float64) for c in ("nx", "ny", "nz")], axis=1)
        ln = np.linalg.norm(N, axis=1, keepdims=True)
        N = np.where(ln > 0, N / np.where(ln > 0, ln, 1.0), 0.0)
    UV = None
    for un, vn in (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t")):
        if un in vx and vn in vx:
            UV = np.stack([np.asarray(vx[un], dtype=np.float64), 1.0 - np.asarray(vx[vn], dtype=np.float64)], axis=1)
            break
    faces = np.zeros((0, 3), np.int64)
    fe = values.get("face")
    if fe:
        key = "vertex_indices" if "vertex_indices" in fe else ("vertex_index" if "vertex_index" in fe else None)
        if key is None:
            raise SceneError(f"{display}: PLY face element has no 'vertex_indices' list")
        sizes, flat = fe[key]
        if flat.ndim == 2:  # uniform fast path
            flat = flat.ravel()
        if len(flat) and (flat.min() < 0 or flat.max() >= nv):
            bad = int(flat[(flat < 0) | (flat >= nv)][0])
            raise SceneError(f"{display}: face index {bad} out of range (the file has {nv} vertices)")
        from .obj_mtl import _fan

        tri = _fan(sizes)
        faces = flat[tri]
        short = int((sizes < 3).sum())
        if short:
            _warn(warnings, f"{display}: ignored {short} face(s) with fewer than 3 corners")
    faces = faces.astype(np.int32)
    faces = drop_nonfinite(display, V, faces, N, UV, warnings)
    return V, faces, N, UV
