"""Wavefront OBJ (+ MTL) loading with Mitsuba 3's semantics.

Two entry points:

- :func:`load_obj_mesh` reads one OBJ file as a single triangle mesh, the way Mitsuba 3's ``obj``
  shape does (used by the XML loader for ``<shape type="obj">``).
- :func:`load_obj_scene` reads an OBJ with its MTL library as a whole scene: one
  :class:`~common.scene.Mesh` per ``usemtl`` material, materials and area emitters from the MTL.

Mitsuba 3 OBJ semantics reproduced here (checked against Mitsuba 3.9.1's ``obj`` shape):

- ``usemtl``/``mtllib``/``g``/``o``/``s`` lines are ignored by the shape; polygons are
  fan-triangulated ``(0, i, i+1)``; faces with fewer than 3 corners make no triangle.
- Vertices are de-duplicated by their ``(v, vt, vn)`` *index* triple (not by value); vertex ids
  follow the first appearance of each triple in the file.
- ``vn`` normals are transformed with the inverse transpose of ``to_world`` and normalized.
  Without ``vn`` (and ``face_normals`` false) Mitsuba recomputes smooth vertex normals over the
  de-duplicated vertices, weighting each face normal by the corner angle
  (Thuermer & Wuethrich 1998); a vertex whose faces are all degenerate gets (1, 0, 0).
  Vertices split by a different ``vt`` index therefore get separate normals.
- ``vt``: Mitsuba flips v (``flip_tex_coords`` defaults to true: ``v_mitsuba = 1 - vt``), and its
  bitmap texture maps row 0 to ``v_mitsuba = 0``. :class:`~common.scene.Texture` maps row 0 to
  ``v = 1``, so meshes store ``1 - v_mitsuba``, which for a default OBJ is the raw ``vt`` value.
- Coordinates are parsed as float32 (as Mitsuba's ``strtof``) and kept as float64.

Deviations (deliberate): negative (relative) indices are resolved as the OBJ spec says (Mitsuba
rejects them); a face corner without ``vt``/``vn`` after one with them does not inherit the
previous corner's indices; triangles that use non-finite vertex data are dropped with a warning
(Mitsuba refuses the file).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .scene import (AREA, CONDUCTOR, DIELECTRIC, DIFFUSE, ROUGHPLASTIC, Camera, Emitter, Material, Mesh,
                    Scene, SceneError, Texture)
from .scene_root import SceneRoot, read_bytes
from .scene_warnings import SceneWarnings

log = logging.getLogger("igi.scene")

# ---------------------------------------------------------------------------------------------
# Generic mesh helpers (shared with the PLY and XML loaders)


def unit_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (rows), numerically robust (as Mitsuba's ``unit_angle``)."""
    dot = np.einsum("ij,ij->i", a, b)
    s = np.linalg.norm(a + b, axis=1)
    d = np.linalg.norm(a - b, axis=1)
    return np.where(dot < 0, np.pi - 2.0 * np.arcsin(np.minimum(s * 0.5, 1.0)),
                    2.0 * np.arcsin(np.minimum(d * 0.5, 1.0)))


def recompute_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted smooth vertex normals, as Mitsuba 3's ``Mesh::recompute_vertex_normals``.

    Degenerate faces contribute nothing; a vertex without any contribution gets (1, 0, 0).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    nv = len(v)
    out = np.zeros((nv, 3))
    if len(f):
        p = [v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        ln = np.linalg.norm(n, axis=1)
        valid = ln > 0
        f = f[valid]
        p = [q[valid] for q in p]
        n = n[valid] / ln[valid, None]
        for k in range(3):
            e1 = p[(k + 1) % 3] - p[k]
            e2 = p[(k + 2) % 3] - p[k]
            e1 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
            e2 = e2 / np.linalg.norm(e2, axis=1, keepdims=True)
            w = n * unit_angle(e1, e2)[:, None]
            for c in range(3):
                out[:, c] += np.bincount(f[:, k], weights=w[:, c], minlength=nv)
    ln = np.linalg.norm(out, axis=1)
    good = ln > 0
    out[good] /= ln[good, None]
    out[~good] = (1.0, 0.0, 0.0)
    return out


def drop_nonfinite(name: str, vertices, faces, normals, uvs, warnings: list[str] | None):
    """Drop triangles that use a vertex with non-finite position, normal or uv (warning names the mesh)."""
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if normals is not None:
        bad |= ~np.all(np.isfinite(normals), axis=1)
    if uvs is not None:
        bad |= ~np.all(np.isfinite(uvs), axis=1)
    if not bad.any() or len(faces) == 0:
        return faces
    drop = bad[faces].any(axis=1)
    if drop.any():
        _warn(warnings, f"{name}: dropped {int(drop.sum())} triangle(s) with non-finite (NaN/Inf) vertex data")
        faces = faces[~drop]
    return faces


def remove_degenerate(name: str, vertices, faces, warnings: list[str] | None):
    """Remove zero-area triangles; returns (faces, removed_count)."""
    if len(faces) == 0:
        return faces, 0
    p0, p1, p2 = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    area2 = np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    bad = ~(area2 > 0)
    n = int(bad.sum())
    if n:
        _warn(warnings, f"{name}: removed {n} degenerate (zero-area) triangle(s)")
        faces = faces[~bad]
    return faces, n


def _warn(warnings: list[str] | None, msg: str) -> None:
    if isinstance(warnings, SceneWarnings):
        warnings.add(msg)  # (logs the first few of a kind)
        return
    log.warning(msg)
    if warnings is not None:
        warnings.append(msg)


# ---------------------------------------------------------------------------------------------
# OBJ parsing


@dataclass
class ObjData:
    """Raw OBJ content: value pools and per-corner 0-based indices (-1 = absent)."""

    positions: np.ndarray  # (nv, 3)
    texcoords: np.ndarray  # (nvt, 2) raw vt (u, v)
    normals: np.ndarray  # (nvn, 3)
    corners: np.ndarray  # (nc, 3) int64: v, vt, vn
    face_sizes: np.ndarray  # (nf,) int64 corner count per polygon
    face_group: np.ndarray | None = None  # (nf,) index into groups (usemtl names), slow path only
    groups: list[str] = field(default_factory=list)
    mtllibs: list[str] = field(default_factory=list)
    mtllib_lines: list[int] = field(default_factory=list)  # the line of each mtllib (slow parser)
    short_faces: int = 0  # faces with fewer than 3 corners (no triangle)


def _read_text(path: Path, display: str) -> str:
    return read_bytes(path, display).decode("utf-8", errors="replace")


def _parse_fast(data: bytes) -> ObjData | None:
    """Vectorized (numpy, byte-level) parse for the common case; None where anything is unusual
    (then the exact per-line parser runs and reports errors with line numbers)."""
    buf = np.frombuffer(data, dtype=np.uint8)
    n = buf.size
    empty = ObjData(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                    np.zeros(0, np.int64))
    if n == 0:
        return empty
    starts = np.concatenate(([0], np.flatnonzero(buf == 10) + 1))
    starts = starts[starts < n]
    c0 = buf[starts]
    if bool(np.any((c0 == 32) | (c0 == 9))):
        return None  # indented lines: let the slow path handle them
    c1 = buf[np.minimum(starts + 1, n - 1)]
    c2 = buf[np.minimum(starts + 2, n - 1)]
    ws1 = ((c1 == 32) | (c1 == 9)) & (starts + 1 < n)
    ws2 = ((c2 == 32) | (c2 == 9)) & (starts + 2 < n)
    V, F = ord("v"), ord("f")
    is_v = (c0 == V) & ws1
    is_vt = (c0 == V) & (c1 == ord("t")) & ws2
    is_vn = (c0 == V) & (c1 == ord("n")) & ws2
    is_f = (c0 == F) & ws1
    cls = np.zeros(len(starts), dtype=np.int8)
    cls[is_v], cls[is_vt], cls[is_vn], cls[is_f] = 1, 2, 3, 4
    mark = np.zeros(n, dtype=np.int32)
    mark[starts[1:]] = 1
    line_of = np.cumsum(mark, dtype=np.int32)
    bcls = cls[line_of]
    w = buf.copy()
    w[starts[cls > 0]] = 32  # blank the keywords
    w[starts[(cls == 2) | (cls == 3)] + 1] = 32

    def floats(k: int, dim: int):
        cnt = int((cls == k).sum())
        if cnt == 0:
            return np.zeros((0, dim))
        body = w[bcls == k].tobytes()
        try:
            a = np.fromstring(body, dtype=np.float64, sep=" ")
        except ValueError:
            return None
        if a.size != dim * cnt:
            # e.g. "vt u v w" or "v x y z r g b": keep the first `dim` values of every line
            try:
                rows = [ln.split()[:dim] for ln in body.decode("latin-1").split("\n")]
                return np.array(rows[:cnt], dtype=np.float64).reshape(-1, dim)
            except ValueError:
                return None
        return a.reshape(-1, dim)

    P, T, N = floats(1, 3), floats(2, 2), floats(3, 3)
    if P is None or T is None or N is None:
        return None
    nf = int(is_f.sum())
    if nf == 0:
        return ObjData(P, T, N, np.zeros((0, 3), np.int64), np.zeros(0, np.int64))
    sel = bcls == 4
    fa = w[sel]
    isws = (fa == 32) | (fa == 9) | (fa == 10) | (fa == 13)
    tokstart = ~isws & np.concatenate(([True], isws[:-1]))
    frank = np.cumsum(cls == 4) - 1  # line -> face index
    face_of = frank[line_of[sel]]
    counts = np.bincount(face_of[tokstart], minlength=nf).astype(np.int64)
    nc = int(tokstart.sum())
    slash = fa == ord("/")
    tok_id = np.cumsum(tokstart) - 1
    per_tok = np.bincount(tok_id[slash], minlength=nc) if slash.any() else np.zeros(nc, np.int64)
    k = int(per_tok[0]) if nc else 0
    if k > 2 or not bool(np.all(per_tok == k)):
        return None
    if k == 2:
        dbl = slash & np.concatenate((slash[1:], [False]))
        per_dbl = np.bincount(tok_id[dbl], minlength=nc)
        if bool(np.all(per_dbl == 1)):
            fields, layout = 2, (0, -1, 1)
        elif bool(np.all(per_dbl == 0)):
            fields, layout = 3, (0, 1, 2)
        else:
            return None
    elif k == 1:
        fields, layout = 2, (0, 1, -1)
    else:
        fields, layout = 1, (0, -1, -1)
    fa = fa.copy()
    fa[slash] = 32
    try:
        ints = np.fromstring(fa.tobytes(), dtype=np.int64, sep=" ")
    except ValueError:
        return None
    if ints.size != nc * fields:
        return None
    ints = ints.reshape(nc, fields)
    if (ints <= 0).any():
        return None  # relative indices or zero: the slow path resolves / reports them
    corners = np.full((nc, 3), -1, dtype=np.int64)
    for dst, src in enumerate(layout):
        if src >= 0:
            corners[:, dst] = ints[:, src] - 1
    # The fast path checks indices against the totals only; anything out of range goes to the slow
    # path, which reports it with its line number.
    if (corners[:, 0] >= len(P)).any() or (corners[:, 1] >= len(T)).any() or (corners[:, 2] >= len(N)).any():
        return None
    return ObjData(P, T, N, corners, counts, short_faces=int((counts < 3).sum()))


def _parse_slow(text: str, display: str) -> ObjData:
    """Per-line parser: exact, reports the first problem as ``file:line: message``."""
    P: list[tuple[float, float, float]] = []
    T: list[tuple[float, float]] = []
    N: list[tuple[float, float, float]] = []
    corners: list[tuple[int, int, int]] = []
    sizes: list[int] = []
    fgroup: list[int] = []
    groups: list[str] = []
    group_index: dict[str, int] = {}
    current = -1
    mtllibs: list[str] = []
    mtllib_lines: list[int] = []
    short = 0

    def num(tok: str, lineno: int, what: str) -> float:
        try:
            return float(tok)
        except ValueError:
            raise SceneError(f"{display}:{lineno}: {what} '{tok}' is not a number") from None

    for lineno, raw in enumerate(text.splitlines(), 1):
        ln = raw.split("#", 1)[0].strip() if "#" in raw else raw.strip()
        if not ln:
            continue
        parts = ln.split()
        kw = parts[0]
        if kw == "v":
            if len(parts) < 4:
                raise SceneError(f"{display}:{lineno}: vertex needs 3 coordinates, got {len(parts) - 1}")
            P.append((num(parts[1], lineno, "vertex coordinate"), num(parts[2], lineno, "vertex coordinate"),
                      num(parts[3], lineno, "vertex coordinate")))
        elif kw == "vt":
            if len(parts) < 2:
                raise SceneError(f"{display}:{lineno}: texture coordinate needs at least 1 value")
            u = num(parts[1], lineno, "texture coordinate")
            v = num(parts[2], lineno, "texture coordinate") if len(parts) > 2 else 0.0
            T.append((u, v))
        elif kw == "vn":
            if len(parts) < 4:
                raise SceneError(f"{display}:{lineno}: normal needs 3 components, got {len(parts) - 1}")
            N.append((num(parts[1], lineno, "normal component"), num(parts[2], lineno, "normal component"),
                      num(parts[3], lineno, "normal component")))
        elif kw == "f":
            toks = parts[1:]
            if len(toks) < 3:
                short += 1
                continue
            for tok in toks:
                fields = tok.split("/")
                if len(fields) > 3 or fields[0] == "":
                    raise SceneError(f"{display}:{lineno}: malformed face corner '{tok}'")
                idx = [-1, -1, -1]
                pools = (len(P), len(T), len(N))
                names = ("vertex", "texture coordinate", "normal")
                for j, fs in enumerate(fields):
                    if fs == "":
                        continue
                    try:
                        i = int(fs)
                    except ValueError:
                        raise SceneError(f"{display}:{lineno}: face index '{fs}' is not an integer") from None
                    n = pools[j]
                    a = i - 1 if i > 0 else n + i  # negative: relative to the data read so far
                    if i == 0 or not 0 <= a < n:
                        raise SceneError(
                            f"{display}:{lineno}: face index {i} out of range "
                            f"({names[j]} count so far: {n})")
                    idx[j] = a
                corners.append((idx[0], idx[1], idx[2]))
            sizes.append(len(toks))
            if current < 0:
                current = group_index.setdefault("", len(groups))
                if current == len(groups):
                    groups.append("")
            fgroup.append(current)
        elif kw == "usemtl":
            name = ln[len(kw):].strip()
            if name not in group_index:
                group_index[name] = len(groups)
                groups.append(name)
            current = group_index[name]
        elif kw == "mtllib":
            rest = ln[len(kw):].strip()
            if rest:
                mtllibs.append(rest)
                mtllib_lines.append(lineno)
        # o, g, s, l, p, cstype, ... are ignored, as Mitsuba's obj shape does.
    return ObjData(
        positions=np.array(P, dtype=np.float64).reshape(-1, 3),
        texcoords=np.array(T, dtype=np.float64).reshape(-1, 2),
        normals=np.array(N, dtype=np.float64).reshape(-1, 3),
        corners=np.array(corners, dtype=np.int64).reshape(-1, 3),
        face_sizes=np.array(sizes, dtype=np.int64),
        face_group=np.array(fgroup, dtype=np.int64),
        groups=groups,
        mtllibs=mtllibs,
        mtllib_lines=mtllib_lines,
        short_faces=short,
    )


def parse_obj(path, display: str | None = None, need_groups: bool = False) -> ObjData:
    path = Path(path)
    display = display or str(path)
    raw = read_bytes(path, display)
    data = None if need_groups else _parse_fast(raw)
    if data is None:
        data = _parse_slow(raw.decode("utf-8", errors="replace"), display)
    return data


def _fan(face_sizes: np.ndarray, face_mask: np.ndarray | None = None) -> np.ndarray:
    """Triangle corner indices (T, 3) into the corner array, fanning each polygon around corner 0."""
    sizes = np.asarray(face_sizes, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if len(sizes) else np.zeros(0, np.int64)
    ntri = np.maximum(sizes - 2, 0)
    if face_mask is not None:
        ntri = np.where(face_mask, ntri, 0)
    total = int(ntri.sum())
    if total == 0:
        return np.zeros((0, 3), np.int64)
    if bool(np.all((ntri == 1) | (ntri == 0))):
        s = starts[ntri == 1]
        return np.stack([s, s + 1, s + 2], axis=1)
    face = np.repeat(np.arange(len(sizes)), ntri)
    first = np.cumsum(ntri) - ntri
    i = np.arange(total) - np.repeat(first, ntri) + 1
    s = starts[face]
    return np.stack([s, s + i, s + i + 1], axis=1)


def assemble(data: ObjData, face_mask: np.ndarray | None = None, flip_tex_coords: bool = True):
    """Triangulate and de-duplicate like Mitsuba: returns (vertices, faces, normals|None, uvs|None,
    missing_normal_mask|None), all in the file's space. ``normals`` rows are unnormalized ``vn``
    values; rows of vertices without a ``vn`` index are zero and flagged in the mask."""
    tri = _fan(data.face_sizes, face_mask)
    used = tri.ravel()
    keys = data.corners[used]
    if len(keys) == 0:
        empty = np.zeros((0, 3))
        return empty, np.zeros((0, 3), np.int32), None, None, None
    nvt = len(data.texcoords) + 1
    nvn = len(data.normals) + 1
    if (len(data.positions) + 1) * nvt * nvn < 2**62:
        k = ((keys[:, 0] + 1) * nvt + (keys[:, 1] + 1)) * nvn + (keys[:, 2] + 1)
        _, first, inverse = np.unique(k, return_index=True, return_inverse=True)
    else:
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(first, kind="stable")  # vertex ids in order of first appearance
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    faces = rank[inverse].reshape(-1, 3).astype(np.int32)
    ukeys = keys[first[order]]
    # Mitsuba parses with strtof: round to float32 precision.
    vertices = data.positions[ukeys[:, 0]].astype(np.float32).astype(np.float64)
    uvs = None
    has_vt = ukeys[:, 1] >= 0
    if has_vt.any():
        t = data.texcoords.astype(np.float32).astype(np.float64)
        uvs = np.zeros((len(ukeys), 2))
        uvs[has_vt] = t[ukeys[has_vt, 1]]
        if not flip_tex_coords:  # Mitsuba then uses vt as is -> scene convention is 1 - v
            uvs[:, 1] = 1.0 - uvs[:, 1]
    normals = None
    missing = None
    has_vn = ukeys[:, 2] >= 0
    if has_vn.any():
        n = data.normals.astype(np.float32).astype(np.float64)
        normals = np.zeros((len(ukeys), 3))
        normals[has_vn] = n[ukeys[has_vn, 2]]
        missing = ~has_vn if not has_vn.all() else None
    return vertices, faces, normals, uvs, missing


def load_obj_mesh(path, display: str | None = None, warnings: list[str] | None = None,
                  flip_tex_coords: bool = True):
    """Load one OBJ file as a single mesh, as Mitsuba 3's ``obj`` shape does.

    Returns ``(vertices (V,3) float64, faces (F,3) int32, normals (V,3)|None, uvs (V,2)|None)`` in the
    file's own space. ``normals`` are the file's ``vn`` (normalized; None when the file has none:
    the caller recomputes them after ``to_world``); ``uvs`` are in the scene convention
    (``1 - v_mitsuba``, see the module docstring). Triangles using non-finite data are dropped
    with a warning. Raises :class:`SceneError` naming file and line for malformed content.
    """
    path = Path(path)
    display = display or str(path)
    data = parse_obj(path, display)
    if data.short_faces:
        _warn(warnings, f"{display}: ignored {data.short_faces} face(s) with fewer than 3 corners")
    v, f, n, uv, missing = assemble(data, flip_tex_coords=flip_tex_coords)
    f = drop_nonfinite(display, v, f, n, uv, warnings)
    if n is not None:
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)
        if missing is not None:
            n[missing] = recompute_vertex_normals(v, f)[missing]
    return v, f, n, uv


# ---------------------------------------------------------------------------------------------
# MTL + whole-scene loading


@dataclass
class MtlMaterial:
    name: str
    line: int
    values: dict[str, list[float]] = field(default_factory=dict)
    illum: int | None = None
    map_kd: str | None = None
    map_kd_line: int = 0
    map_kd_scale: tuple[float, float] = (1.0, 1.0)
    map_kd_offset: tuple[float, float] = (0.0, 0.0)


def parse_mtl(path, display: str | None = None, warnings: list[str] | None = None) -> dict[str, MtlMaterial]:
    path = Path(path)
    display = display or str(path)
    text = _read_text(path, display)
    mats: dict[str, MtlMaterial] = {}
    cur: MtlMaterial | None = None
    for lineno, raw in enumerate(text.splitlines(), 1):
        ln = raw.split("#", 1)[0].strip()  # trailing comments ("Kd 0.6 0.1 0.1 # red")
        if not ln:
            continue
        parts = ln.split()
        kw = parts[0]
        if kw == "newmtl":
            name = ln[len(kw):].strip()
            cur = MtlMaterial(name, lineno)
            mats[name] = cur
            continue
        if cur is None:
            raise SceneError(f"{display}:{lineno}: '{kw}' before any 'newmtl'")
        if kw in ("Kd", "Ks", "Ke", "Ka", "Tf", "Ns", "Ni", "d", "Tr", "Pe", "Pr", "Pm"):
            args = parts[1:]
            if args and args[0] in ("spectral", "xyz"):
                _warn(warnings, f"{display}:{lineno}: '{kw} {args[0]}' is not supported, ignored")
                continue
            try:
                vals = [float(a) for a in args]
            except ValueError:
                bad = next(a for a in args if not _is_float(a))
                raise SceneError(f"{display}:{lineno}: {kw} value '{bad}' is not a number") from None
            if not vals:
                raise SceneError(f"{display}:{lineno}: {kw} needs a value")
            cur.values[kw] = vals
        elif kw == "illum":
            try:
                cur.illum = int(parts[1])
            except (IndexError, ValueError):
                raise SceneError(f"{display}:{lineno}: illum needs an integer") from None
        elif kw == "map_Kd":
            args = parts[1:]
            scale_uv, offset_uv = [1.0, 1.0], [0.0, 0.0]
            i = 0
            nargs = {"-s": 3, "-o": 3, "-t": 3, "-mm": 2, "-bm": 1, "-boost": 1, "-blendu": 1, "-blendv": 1,
                     "-cc": 1, "-clamp": 1, "-imfchan": 1, "-texres": 1, "-type": 1}
            while i < len(args) and args[i] in nargs:
                opt, cnt = args[i], nargs[args[i]]
                vals = args[i + 1:i + 1 + cnt]
                if opt in ("-s", "-o"):
                    nums = []
                    for a in vals:
                        if not _is_float(a):
                            break
                        nums.append(float(a))
                    cnt = len(nums)
                    if opt == "-s" and nums:
                        scale_uv = [nums[0], nums[1] if len(nums) > 1 else 1.0]
                    elif opt == "-o" and nums:
                        offset_uv = [nums[0], nums[1] if len(nums) > 1 else 0.0]
                i += 1 + cnt
            if i >= len(args):
                raise SceneError(f"{display}:{lineno}: map_Kd needs a file name")
            cur.map_kd = " ".join(args[i:])
            cur.map_kd_line = lineno
            cur.map_kd_scale = (scale_uv[0], scale_uv[1])
            cur.map_kd_offset = (offset_uv[0], offset_uv[1])
        # other statements (map_Ks, bump, ...) are ignored
    return mats


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _rgb(vals: list[float] | None, default) -> np.ndarray:
    if not vals:
        return np.broadcast_to(np.asarray(default, dtype=np.float64), (3,)).copy()
    if len(vals) < 3:
        return np.full(3, float(vals[0]))
    return np.array(vals[:3], dtype=np.float64)


# McGuire's CornellBox-Original.mtl light radiance; the Sphere/Glossy/Water MTLs give "Ke 1 1 1"
# with a renderer-specific power "Pe 10" instead (see /work/shared/scenes/README.md).
MCGUIRE_LIGHT_RADIANCE = (17.0, 12.0, 4.0)


def mtl_to_material(m: MtlMaterial, base_dir: Path, display: str, warnings: list[str] | None,
                    texture_cache: dict | None = None,
                    root: SceneRoot | None = None) -> tuple[Material, np.ndarray | None]:
    """Map one MTL material to a :class:`Material` and an emitted radiance (or None).

    Mapping (as the shared scenes' README "Conversion notes"):

    - ``illum 5`` (or, without ``illum``, a near-perfect mirror: ``Ks >= 0.9``, ``Ns >= 500``,
      no ``Kd``) -> ``conductor`` with ``material="none"`` and ``specular_reflectance = Ks``;
    - ``illum 4/6/7/9`` (or, without ``illum``, ``Ni != 1`` together with a transmission
      ``Tf``/``d < 1``/``Tr > 0``) -> ``dielectric`` with ``int_ior = Ni`` (``ext_ior = 1``);
    - ``Ks > 0`` with ``Ns`` -> ``roughplastic``, Beckmann, ``alpha = sqrt(2 / (Ns + 2))``,
      ``diffuse_reflectance = Kd``, ``int_ior = 1.5``, ``ext_ior = 1``;
    - otherwise ``diffuse`` with ``Kd`` (``map_Kd`` -> bitmap texture, bilinear);
    - ``Ke > 0`` -> area emitter with radiance ``Ke``; an MTL that gives ``Pe`` (a non-standard
      light power) uses McGuire's standard ``17 12 4`` instead, with a warning.
    ``Tf`` (transmission filter) is otherwise ignored.

    A ``map_Kd`` outside ``root`` (when given) raises :class:`SceneRootError`; one that cannot be
    read is a warning (the material keeps ``Kd``).
    """
    vals = m.values
    kd = _rgb(vals.get("Kd"), 0.5)
    ks = _rgb(vals.get("Ks"), 0.0)
    ns = vals["Ns"][0] if "Ns" in vals else None
    ni = vals["Ni"][0] if "Ni" in vals else None
    transmissive = ("Tf" in vals and max(vals["Tf"]) > 0) or ("d" in vals and vals["d"][0] < 1) or \
                   ("Tr" in vals and vals["Tr"][0] > 0)
    illum = m.illum
    name = m.name
    if illum == 5 or (illum is None and ks.max() >= 0.9 and (ns or 0) >= 500 and "Kd" not in vals):
        mat = Material(name=name, kind=CONDUCTOR, specular=Texture.constant(ks if ks.max() > 0 else 1.0))
    elif illum in (4, 6, 7, 9) or (illum is None and ni is not None and ni != 1.0 and transmissive):
        mat = Material(name=name, kind=DIELECTRIC, int_ior=float(ni if ni else 1.5), ext_ior=1.0)
    elif ks.max() > 0 and ns is not None:
        mat = Material(name=name, kind=ROUGHPLASTIC, diffuse=Texture.constant(kd),
                       alpha=float(math.sqrt(2.0 / (max(ns, 0.0) + 2.0))), distribution="beckmann",
                       int_ior=1.5, ext_ior=1.0)
    else:
        mat = Material(name=name, kind=DIFFUSE, diffuse=Texture.constant(kd))
    if m.map_kd and mat.kind in (DIFFUSE, ROUGHPLASTIC):
        from .image_io import read_image

        tex_path = (base_dir / m.map_kd.replace("\\", "/"))
        if root is not None:
            tex_path = root.check(tex_path, f"{display}:{m.map_kd_line or m.line}", m.map_kd, "map_Kd texture")
        key = str(tex_path.resolve())
        if texture_cache is not None and key in texture_cache:
            img = texture_cache[key]
        else:
            try:
                img = read_image(tex_path)
            except SceneError as e:
                _warn(warnings, f"{display}:{m.line}: material '{name}': map_Kd {e}; using Kd")
                img = None
            if texture_cache is not None:
                texture_cache[key] = img
        if img is not None:
            mat.diffuse = Texture(image=img, filter="bilinear", uv_scale=m.map_kd_scale,
                                  uv_offset=m.map_kd_offset, name=m.map_kd)
    radiance = None
    ke = _rgb(vals.get("Ke"), 0.0)
    if ke.max() > 0:
        if "Pe" in vals:
            _warn(warnings, f"{display}:{m.line}: material '{name}' gives 'Ke {' '.join(map(str, vals['Ke']))}' "
                            f"with renderer-specific 'Pe'; using McGuire's radiance 17 12 4 instead")
            radiance = np.array(MCGUIRE_LIGHT_RADIANCE)
        else:
            radiance = ke
    return mat, radiance


def default_obj_camera(lo: np.ndarray, hi: np.ndarray) -> Camera:
    """640x480, horizontal FOV 39.3077 deg, looking along -z at the bounding-box centre from
    ``+z``, far enough back that the whole box fits in both the horizontal and the vertical FOV
    (measured from the box's front face, plus 5 %)."""
    from .transform import look_at

    width, height, fov = 640, 480, 39.3077
    centre = 0.5 * (lo + hi)
    ext = np.maximum(hi - lo, 1e-6)
    tx = math.tan(math.radians(fov) / 2)
    ty = tx * height / width
    dist = max(0.5 * ext[0] / tx, 0.5 * ext[1] / ty) * 1.05 + 0.5 * ext[2]
    origin = centre + np.array([0.0, 0.0, dist])
    to_world = look_at(origin, centre, [0.0, 1.0, 0.0])
    return Camera(to_world=to_world, fov=fov, fov_axis="x", width=width, height=height,
                  near_clip=max(dist * 1e-3, 1e-4))


def load_obj_scene(path, root: str | Path | None = None) -> Scene:
    """Load an OBJ (+ its MTL libraries) as a whole scene; see :func:`mtl_to_material` for the
    material mapping and :func:`default_obj_camera` for the camera. One mesh per ``usemtl`` name.

    The MTL libraries and their textures must lie inside ``root`` (default: the OBJ's folder)
    after symlinks and ``..``: :class:`SceneRootError` names the line that leads outside."""
    path = Path(path)
    display = str(path)
    if not path.is_file():
        raise SceneError(f"{display}: file not found")
    try:
        return _load_obj_scene(path, display, SceneRoot.for_scene(path, root))
    except SceneError:
        raise
    except (ValueError, IndexError, KeyError, TypeError, OverflowError) as e:
        raise SceneError(f"{display}: cannot load scene ({type(e).__name__}: {e})") from e


def _load_obj_scene(path: Path, display: str, root: SceneRoot) -> Scene:
    warnings = SceneWarnings(log)
    data = parse_obj(path, display, need_groups=True)
    if data.short_faces:
        _warn(warnings, f"{display}: ignored {data.short_faces} face(s) with fewer than 3 corners")
    base = path.parent
    mtl: dict[str, MtlMaterial] = {}
    mtl_display: dict[str, str] = {}
    for lib, line in zip(data.mtllibs, data.mtllib_lines):
        lib_path = root.check(base / lib.replace("\\", "/"), f"{display}:{line}", lib, "material library")
        if not lib_path.is_file():
            _warn(warnings, f"{display}: material library '{lib}' not found; using diffuse 0.5")
            continue
        for k, v in parse_mtl(lib_path, lib, warnings).items():
            mtl[k] = v
            mtl_display[k] = lib
    materials: list[Material] = []
    emitters: list[Emitter] = []
    meshes: list[Mesh] = []
    mat_index: dict[str, tuple[int, np.ndarray | None]] = {}
    cache: dict = {}
    for gi, gname in enumerate(data.groups):
        mask = data.face_group == gi
        v, f, n, uv, missing = assemble(data, mask)
        if len(f) == 0:
            continue
        mesh_name = gname or "default"
        f = drop_nonfinite(f"{display} ({mesh_name})", v, f, n, uv, warnings)
        if n is None:
            n = recompute_vertex_normals(v, f)
        else:
            ln = np.linalg.norm(n, axis=1, keepdims=True)
            n = np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)
            if missing is not None:
                n[missing] = recompute_vertex_normals(v, f)[missing]
        f, _ = remove_degenerate(f"{display} ({mesh_name})", v, f, warnings)
        if len(f) == 0:
            continue
        if gname not in mat_index:
            if gname in mtl:
                mat, radiance = mtl_to_material(mtl[gname], base, mtl_display[gname], warnings, cache, root)
            else:
                if gname:
                    _warn(warnings, f"{display}: material '{gname}' not found in the MTL library; using diffuse 0.5")
                mat, radiance = Material(name=mesh_name, kind=DIFFUSE), None
            materials.append(mat)
            mat_index[gname] = (len(materials) - 1, radiance)
        mi, radiance = mat_index[gname]
        mesh = Mesh(name=mesh_name, vertices=v, faces=f, material=mi, normals=n, uvs=uv)
        if radiance is not None:
            emitters.append(Emitter(kind=AREA, radiance=radiance.copy(), mesh=len(meshes), name=mesh_name))
            mesh.emitter = len(emitters) - 1
        meshes.append(mesh)
    if not meshes:
        raise SceneError(f"{display}: no triangles")
    lo = np.min([m.vertices[m.faces.ravel()].min(axis=0) for m in meshes], axis=0)
    hi = np.max([m.vertices[m.faces.ravel()].max(axis=0) for m in meshes], axis=0)
    if not emitters:
        _warn(warnings, f"{display}: no emitter (no material with Ke > 0)")
    warnings.summarize()
    return Scene(meshes=meshes, materials=materials, emitters=emitters, camera=default_obj_camera(lo, hi),
                 source=display, warnings=list(warnings))
