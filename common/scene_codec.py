"""Scene <-> bytes without pickle, the content hash that names a scene blob, and scene edits.

Encoding
--------
A :class:`~common.scene.Scene` becomes a tree of msgpack-able values: every dataclass
(Scene, Mesh, Material, Texture, Emitter, Camera) a map of its fields in declaration order,
every numpy array ``{"__nd__": dtype-string, "shape": [...], "data": raw little-endian bytes}``,
tuples ``{"__tuple__": [...]}``. The tree is packed with msgpack and compressed with an LZ4 frame;
the blob starts with :data:`MAGIC`. Nothing is ever unpickled: decoding only builds the known
dataclasses from validated plain values, so a hostile blob can at worst raise
:class:`~common.scene.SceneError`.

The field lists come from the dataclasses themselves (``dataclasses.fields``), so a field the
scene model gains later is carried without a change here (fields absent from an old blob take
their defaults). Decoding validates every value against the field's annotation, array dtypes
against a small whitelist, sizes against :data:`MAX_SCENE_BYTES`, and the cross references a
renderer indexes with (face indices < vertex count, material/emitter/mesh indices in range,
array shapes).

Content hash
------------
:func:`scene_hash` is the sha256 hex digest of the blob. Encoding is deterministic (same scene
content -> same bytes in every process), so the hash names the scene: workers cache blobs by it
and the master sends a blob to a worker only when the worker does not list its hash.

Edits
-----
Small deltas, msgpack-able dicts, applied by master and workers alike with :func:`apply_edit`
(every edit bumps the scene version; see ``common/protocol.py``)::

    {"op": "transform_mesh", "mesh": 3, "matrix": [16 floats, row-major affine 4x4]}
        vertices <- M·v, shading normals <- normalize(M^-T·n); the mesh's area emitter moves
        with it. ``mesh`` may be an index or a mesh name.
    {"op": "set_material", "material": 0, "param": "diffuse", "value": [0.8, 0.2, 0.2]}
        param in MATERIAL_PARAMS: textures (diffuse, specular, specular_transmittance) take an
        RGB triple or a scalar (-> constant texture), alpha/int_ior/ext_ior a scalar, eta/k an
        RGB triple.
    {"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [10, 10, 10]}
        param in EMITTER_PARAMS. ``position`` of an area emitter translates its mesh so that
        the mesh's vertex centroid lands on the position.

:func:`apply_edit` never mutates its input: it returns a new Scene that shares every unchanged
mesh / material / emitter with the old one.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import re
from typing import Any

import msgpack
import numpy as np

from . import reconstruction_filter
from .limits import MAX_COORD
from . import scene as scene_mod
from .scene import Camera, Emitter, Material, Mesh, Scene, SceneError, Texture

MAGIC = b"IGISCN1\n"
MAX_SCENE_BYTES = 2 << 30  # decompressed size limit of one scene (2 GiB)
MAX_DEPTH = 8  # nesting depth of the value tree

_ALLOWED_DTYPES = {"<f2", "<f4", "<f8", "<i4", "<i8", "<u4", "<u8", "|u1", "<u2", "<i2", "|i1", "|b1"}
_CLASSES = {cls.__name__: cls for cls in (Scene, Mesh, Material, Texture, Emitter, Camera)}


# --------------------------------------------------------------------------- encoding

def _enc(value: Any, depth: int = 0) -> Any:
    if depth > MAX_DEPTH:
        raise SceneError("scene encoding: value tree too deep")
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        if a.dtype.byteorder == ">":
            a = a.astype(a.dtype.newbyteorder("<"))
        dt = a.dtype.str
        if dt not in _ALLOWED_DTYPES:
            raise SceneError(f"scene encoding: array dtype {a.dtype} not supported")
        return {"__nd__": dt, "shape": list(a.shape), "data": a.tobytes()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out = {}
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            if str(f.type) == "float" and isinstance(v, (int, np.integer)) and not isinstance(v, bool):
                v = float(v)  # one encoding per value: 45 and 45.0 hash alike
            out[f.name] = _enc(v, depth + 1)
        return out
    if isinstance(value, tuple):
        return {"__tuple__": [_enc(v, depth + 1) for v in value]}
    if isinstance(value, list):
        return [_enc(v, depth + 1) for v in value]
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        return value
    raise SceneError(f"scene encoding: cannot encode {type(value).__name__}")


def scene_to_dict(scene: Scene) -> dict:
    """The msgpack-able tree of a scene (no pickle, arrays as raw bytes + dtype + shape)."""
    return _enc(scene)


def encode_scene(scene: Scene) -> bytes:
    """Deterministic blob: MAGIC + LZ4 frame of the msgpack tree."""
    import lz4.frame

    packed = msgpack.packb(scene_to_dict(scene), use_bin_type=True)
    return MAGIC + lz4.frame.compress(packed, compression_level=0, content_checksum=True)


def scene_hash(blob: bytes) -> str:
    """Content hash of a scene blob: the id workers cache it under."""
    return hashlib.sha256(blob).hexdigest()


# --------------------------------------------------------------------------- decoding

def _dec_array(d: dict, where: str) -> np.ndarray:
    if set(d) != {"__nd__", "shape", "data"}:
        raise SceneError(f"{where}: malformed array")
    dt, shape, data = d["__nd__"], d["shape"], d["data"]
    if not isinstance(dt, str) or dt not in _ALLOWED_DTYPES:
        raise SceneError(f"{where}: array dtype {dt!r} not allowed")
    if (not isinstance(shape, list) or len(shape) > 4
            or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**31 for s in shape)):
        raise SceneError(f"{where}: bad array shape {shape!r}")
    if not isinstance(data, bytes):
        raise SceneError(f"{where}: array data is not bytes")
    dtype = np.dtype(dt)
    n = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if n * dtype.itemsize != len(data):
        raise SceneError(f"{where}: array of shape {shape} {dt} needs {n * dtype.itemsize} bytes, got {len(data)}")
    return np.frombuffer(data, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="), copy=True)


def _split_union(ann: str) -> list[str]:
    parts, depth, cur = [], 0, ""
    for ch in ann:
        if ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        if ch == "|" and depth == 0:
            parts.append(cur.strip())
            cur = ""
        else:
            cur += ch
    parts.append(cur.strip())
    return parts


def _dec_typed(value: Any, ann: str, where: str, depth: int) -> Any:
    """Decode ``value`` for a field annotated ``ann`` (the annotation string of scene.py)."""
    if depth > MAX_DEPTH:
        raise SceneError(f"{where}: value tree too deep")
    ann = ann.strip().strip("'\"")
    options = _split_union(ann)
    if len(options) > 1:
        if value is None and "None" in options:
            return None
        errors = []
        for opt in options:
            if opt == "None":
                continue
            try:
                return _dec_typed(value, opt, where, depth)
            except SceneError as e:
                errors.append(str(e))
        raise SceneError(errors[0] if errors else f"{where}: bad value")
    if ann in ("np.ndarray", "numpy.ndarray", "ndarray"):
        if not isinstance(value, dict) or "__nd__" not in value:
            raise SceneError(f"{where}: expected an array")
        return _dec_array(value, where)
    if ann == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{where}: expected a number, got {type(value).__name__}")
        return float(value)
    if ann == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{where}: expected an integer, got {type(value).__name__}")
        return value
    if ann == "bool":
        if not isinstance(value, bool):
            raise SceneError(f"{where}: expected a bool")
        return value
    if ann == "str":
        if not isinstance(value, str):
            raise SceneError(f"{where}: expected a string")
        return value
    if ann == "None":
        if value is not None:
            raise SceneError(f"{where}: expected nothing")
        return None
    m = re.fullmatch(r"(list|tuple)\[(.*)\]", ann)
    if m:
        outer, inner = m.group(1), m.group(2)
        if outer == "tuple":
            if not isinstance(value, dict) or set(value) != {"__tuple__"} or not isinstance(value["__tuple__"], list):
                raise SceneError(f"{where}: expected a tuple")
            items = value["__tuple__"]
            types = [t.strip() for t in inner.split(",")]
            if len(types) == 2 and types[1] == "...":
                types = [types[0]] * len(items)
            if len(types) != len(items):
                raise SceneError(f"{where}: expected {len(types)} values, got {len(items)}")
            return tuple(_dec_typed(v, t, f"{where}[{i}]", depth + 1) for i, (v, t) in enumerate(zip(items, types)))
        if not isinstance(value, list):
            raise SceneError(f"{where}: expected a list")
        return [_dec_typed(v, inner, f"{where}[{i}]", depth + 1) for i, v in enumerate(value)]
    if ann in _CLASSES:
        return _dec_class(_CLASSES[ann], value, where, depth + 1)
    raise SceneError(f"{where}: cannot decode a field of type {ann}")


def _dec_class(cls, value: Any, where: str, depth: int = 0):
    if not isinstance(value, dict):
        raise SceneError(f"{where}: expected a {cls.__name__} map")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    extra = set(value) - set(fields)
    if extra:
        raise SceneError(f"{where}: unknown {cls.__name__} field(s) {sorted(map(str, extra))}")
    kwargs = {}
    for name, f in fields.items():
        if name in value:
            kwargs[name] = _dec_typed(value[name], str(f.type), f"{where}.{name}", depth)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise SceneError(f"{where}: missing {cls.__name__} field {name!r}")
    return cls(**kwargs)


def _check_shape(a: np.ndarray | None, where: str, cols: int, rows: int | None = None) -> None:
    if a is None:
        return
    if a.ndim != 2 or a.shape[1] != cols or (rows is not None and a.shape[0] != rows):
        want = f"({rows if rows is not None else 'N'}, {cols})"
        raise SceneError(f"{where}: shape {a.shape}, expected {want}")


def validate_scene(scene: Scene) -> None:
    """Cross references and shapes a renderer relies on; raises SceneError naming the problem."""
    nmat, nem, nmesh = len(scene.materials), len(scene.emitters), len(scene.meshes)
    for i, m in enumerate(scene.meshes):
        w = f"mesh {i} ({m.name})"
        _check_shape(m.vertices, w + " vertices", 3)
        _check_shape(m.faces, w + " faces", 3)
        if m.faces.dtype.kind not in "iu":
            raise SceneError(f"{w}: faces are not integers")
        nv = len(m.vertices)
        if m.faces.size and (m.faces.min() < 0 or m.faces.max() >= nv):
            raise SceneError(f"{w}: face index outside 0..{nv - 1}")
        _check_shape(m.normals, w + " normals", 3, nv)
        _check_shape(m.uvs, w + " uvs", 2, nv)
        if not 0 <= m.material < nmat:
            raise SceneError(f"{w}: material index {m.material} outside 0..{nmat - 1}")
        if not -1 <= m.emitter < nem:
            raise SceneError(f"{w}: emitter index {m.emitter} outside -1..{nem - 1}")
    for i, mat in enumerate(scene.materials):
        if not np.isfinite(mat.bump_scale):
            raise SceneError(f"material {i} ({mat.name}) bump_scale: {mat.bump_scale} is not finite")
        for tname in ("diffuse", "specular", "specular_transmittance", "opacity", "normal_map", "bump_map"):
            t = getattr(mat, tname)
            if t is None and tname in ("opacity", "normal_map", "bump_map"):
                continue
            if t.image is None and (t.rgb is None or t.rgb.shape != (3,)):
                raise SceneError(f"material {i} ({mat.name}) {tname}: constant texture needs 3 values")
            if t.image is not None and (t.image.ndim != 3 or t.image.shape[2] != 3 or 0 in t.image.shape):
                raise SceneError(f"material {i} ({mat.name}) {tname}: image shape {t.image.shape}")
    for i, e in enumerate(scene.emitters):
        if e.kind == scene_mod.AREA and not 0 <= e.mesh < nmesh:
            raise SceneError(f"emitter {i} ({e.name}): mesh index {e.mesh} outside 0..{nmesh - 1}")
        for vname in ("radiance", "intensity", "irradiance", "position", "direction"):
            if np.shape(getattr(e, vname)) != (3,):
                raise SceneError(f"emitter {i} ({e.name}) {vname}: expected 3 values")
        if e.image is not None and (e.kind != scene_mod.CONSTANT or e.image.ndim != 3 or e.image.shape[2] != 3
                                    or e.image.shape[0] < 3 or e.image.shape[1] < 2):
            raise SceneError(f"emitter {i} ({e.name}): environment map image shape {e.image.shape}")
        if e.to_world is not None and (np.shape(e.to_world) != (3, 3) or not np.allclose(
                np.asarray(e.to_world, np.float64) @ np.asarray(e.to_world, np.float64).T, np.eye(3), atol=1e-4)):
            raise SceneError(f"emitter {i} ({e.name}) to_world: expected a 3x3 rotation")
    skies = [e for e in scene.emitters if e.kind == scene_mod.CONSTANT]
    if len(skies) > 1 and any(e.image is not None for e in skies):
        raise SceneError("only one environment emitter (constant or envmap) per scene, as in Mitsuba 3")
    if np.shape(scene.camera.to_world) != (4, 4):
        raise SceneError("camera to_world: expected a 4x4 matrix")
    reconstruction_filter.validate(scene.camera.rfilter, scene.camera.rfilter_params)
    if not (0 <= scene.camera.aperture_radius <= MAX_COORD and 1e-6 <= scene.camera.focus_distance <= MAX_COORD):
        raise SceneError(f"camera thin lens: aperture radius {scene.camera.aperture_radius} must be in [0, "
                         f"{MAX_COORD:g}], focus distance {scene.camera.focus_distance} in [1e-06, {MAX_COORD:g}]")


def scene_from_dict(tree: Any) -> Scene:
    scene = _dec_class(Scene, tree, "scene")
    validate_scene(scene)
    return scene


def decode_scene(blob: bytes, expected_hash: str | None = None) -> Scene:
    """Scene from :func:`encode_scene`'s blob; SceneError on any malformed content.

    With ``expected_hash`` the blob must hash to it (a corrupted or substituted blob is refused).
    """
    import lz4.frame

    if not isinstance(blob, (bytes, bytearray, memoryview)):
        raise SceneError("scene blob: not bytes")
    blob = bytes(blob)
    if expected_hash is not None and scene_hash(blob) != expected_hash:
        raise SceneError("scene blob: content hash mismatch")
    if not blob.startswith(MAGIC):
        raise SceneError("scene blob: bad magic (not an igi scene blob)")
    try:
        d = lz4.frame.LZ4FrameDecompressor()
        packed = d.decompress(blob[len(MAGIC):], max_length=MAX_SCENE_BYTES)
        if not d.eof:
            raise SceneError("scene blob: truncated or larger than the limit")
    except SceneError:
        raise
    except Exception as e:  # lz4 raises RuntimeError on corrupt frames
        raise SceneError(f"scene blob: corrupt compressed data ({e})") from None
    try:
        tree = msgpack.unpackb(packed, raw=False, strict_map_key=True, max_bin_len=MAX_SCENE_BYTES)
    except Exception as e:
        raise SceneError(f"scene blob: not msgpack ({type(e).__name__})") from None
    return scene_from_dict(tree)


# --------------------------------------------------------------------------- edits

EDIT_OPS = ("transform_mesh", "set_material", "set_emitter")
MATERIAL_PARAMS = {  # name -> "tex" (RGB or scalar -> constant texture), "float", "rgb"
    "diffuse": "tex", "specular": "tex", "specular_transmittance": "tex",
    "alpha": "float", "int_ior": "float", "ext_ior": "float", "eta": "rgb", "k": "rgb",
}
EMITTER_PARAMS = {"radiance": "rgb", "intensity": "rgb", "irradiance": "rgb", "position": "rgb",
                  "direction": "rgb", "cutoff_angle": "float", "beam_width": "float"}


def _index(scene_list: list, ref: Any, what: str) -> int:
    if isinstance(ref, bool):
        raise ValueError(f"edit: {what} reference must be an index or a name")
    if isinstance(ref, int):
        if not 0 <= ref < len(scene_list):
            raise ValueError(f"edit: {what} index {ref} outside 0..{len(scene_list) - 1}")
        return ref
    if isinstance(ref, str):
        for i, item in enumerate(scene_list):
            if item.name == ref:
                return i
        raise ValueError(f"edit: no {what} named {ref!r}")
    raise ValueError(f"edit: {what} reference must be an index or a name")


def _finite(value: Any, n: int | tuple, what: str) -> np.ndarray:
    if isinstance(value, bool):
        raise ValueError(f"edit: {what} must be numeric")
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"edit: {what} must be numeric") from None
    sizes = n if isinstance(n, tuple) else (n,)
    if a.ndim > 1 or a.size not in sizes:
        raise ValueError(f"edit: {what} needs {' or '.join(map(str, sizes))} number(s)")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"edit: {what} must be finite")
    return a.reshape(-1)


def validate_edit(scene: Scene, edit: Any) -> None:
    """Raise ValueError naming the problem when ``edit`` cannot be applied to ``scene``."""
    apply_edit(scene, edit)


def apply_edit(scene: Scene, edit: dict) -> Scene:
    """A new Scene with ``edit`` applied (see the module docstring); ValueError on a bad edit."""
    if not isinstance(edit, dict):
        raise ValueError("edit: expected a map")
    op = edit.get("op")
    if op not in EDIT_OPS:
        raise ValueError(f"edit: unknown op {op!r} (one of {', '.join(EDIT_OPS)})")
    new = copy.copy(scene)
    if op == "transform_mesh":
        _keys(edit, {"op", "mesh", "matrix"})
        i = _index(scene.meshes, edit["mesh"], "mesh")
        m = _finite(edit["matrix"], 16, "matrix").reshape(4, 4)
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError("edit: matrix must be affine (last row 0 0 0 1)")
        lin = m[:3, :3]
        if abs(np.linalg.det(lin)) < 1e-12:
            raise ValueError("edit: matrix is singular")
        mesh = copy.copy(scene.meshes[i])
        mesh.vertices = scene.meshes[i].vertices @ lin.T + m[:3, 3]
        if mesh.normals is not None:
            nrm = scene.meshes[i].normals @ np.linalg.inv(lin)  # (M^-T n)^T = n^T M^-1
            ln = np.linalg.norm(nrm, axis=1, keepdims=True)
            mesh.normals = np.where(ln > 0, nrm / np.where(ln > 0, ln, 1), nrm)
        new.meshes = list(scene.meshes)
        new.meshes[i] = mesh
    elif op == "set_material":
        _keys(edit, {"op", "material", "param", "value"})
        i = _index(scene.materials, edit["material"], "material")
        param = edit["param"]
        if param not in MATERIAL_PARAMS:
            raise ValueError(f"edit: unknown material parameter {param!r} (one of {', '.join(MATERIAL_PARAMS)})")
        mat = copy.copy(scene.materials[i])
        kind = MATERIAL_PARAMS[param]
        if kind == "tex":
            v = _finite(edit["value"], (1, 3), param)
            setattr(mat, param, Texture.constant(np.broadcast_to(v, (3,))))
        elif kind == "rgb":
            setattr(mat, param, _finite(edit["value"], 3, param).copy())
        else:
            v = float(_finite(edit["value"], 1, param)[0])
            if param == "alpha" and not v > 0:
                raise ValueError("edit: alpha must be > 0")
            if param in ("int_ior", "ext_ior") and not v > 0:
                raise ValueError(f"edit: {param} must be > 0")
            setattr(mat, param, v)
        new.materials = list(scene.materials)
        new.materials[i] = mat
    else:  # set_emitter
        _keys(edit, {"op", "emitter", "param", "value"})
        i = _index(scene.emitters, edit["emitter"], "emitter")
        param = edit["param"]
        if param not in EMITTER_PARAMS:
            raise ValueError(f"edit: unknown emitter parameter {param!r} (one of {', '.join(EMITTER_PARAMS)})")
        em = copy.copy(scene.emitters[i])
        if EMITTER_PARAMS[param] == "float":
            setattr(em, param, float(_finite(edit["value"], 1, param)[0]))
        else:
            v = _finite(edit["value"], 3, param).copy()
            if param in ("radiance", "intensity", "irradiance") and np.any(v < 0):
                raise ValueError(f"edit: {param} must be >= 0")
            if param == "direction":
                n = np.linalg.norm(v)
                if n == 0:
                    raise ValueError("edit: direction must be non-zero")
                v = v / n
            if param == "radiance" and em.image is not None:
                # a map's radiance is its mean: the edit scales the map to the new mean, per channel
                # (never to 0: its pixels would be lost, and no later edit could bring them back)
                old = np.asarray(em.radiance, np.float64)
                if np.any(v <= 0) or np.any(old <= 0):
                    raise ValueError("edit: an environment map's radiance can be scaled, not set to 0 in a channel")
                em.image = (em.image * (v / old)).astype(np.float32)
            setattr(em, param, v)
            if param == "position" and em.kind == scene_mod.AREA and 0 <= em.mesh < len(scene.meshes):
                mesh = copy.copy(scene.meshes[em.mesh])
                centre = scene.meshes[em.mesh].vertices.mean(axis=0) if len(mesh.vertices) else np.zeros(3)
                mesh.vertices = scene.meshes[em.mesh].vertices + (v - centre)
                new.meshes = list(scene.meshes)
                new.meshes[em.mesh] = mesh
        new.emitters = list(scene.emitters)
        new.emitters[i] = em
    new.warnings = list(scene.warnings)
    return new


def _keys(edit: dict, allowed: set) -> None:
    missing = allowed - set(edit)
    extra = set(edit) - allowed
    if missing:
        raise ValueError(f"edit {edit.get('op')}: missing {sorted(missing)}")
    if extra:
        raise ValueError(f"edit {edit.get('op')}: unknown key(s) {sorted(map(str, extra))}")
