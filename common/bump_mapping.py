"""The tables hit reconstruction perturbs shading normals by (common.kernels.bump_mapping):
Mitsuba's ``normalmap`` and ``bumpmap`` materials, and each of their triangles' dp/du, dp/dv."""
from __future__ import annotations

import numpy as np

from .kernels.bump_mapping import BUMP_MAP, MAP_COLUMNS, NORMAL_MAP


def no_bumps() -> tuple:
    """The tables of a scene without normal or bump maps (empty, of the kernels' types)."""
    return (np.zeros(0, np.int32), np.zeros((0, 6)), np.zeros((0, MAP_COLUMNS)), np.zeros(0, np.float32))


def triangle_tangents(vertices: np.ndarray, faces: np.ndarray, vertex_uvs: np.ndarray) -> np.ndarray:
    """(F, 6): each triangle's dp/du and dp/dv, the position's derivatives along its uv (as
    Mitsuba's meshes compute them); zeros where the uv are degenerate (the kernel then takes
    any tangent)."""
    p = vertices[faces]
    t = vertex_uvs[faces]
    dp0, dp1 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    duv0, duv1 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = duv0[:, 0] * duv1[:, 1] - duv0[:, 1] * duv1[:, 0]
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (duv1[:, 1:2] * dp0 - duv0[:, 1:2] * dp1) * inv
    dpdv = (duv0[:, 0:1] * dp1 - duv1[:, 0:1] * dp0) * inv
    out = np.concatenate([dpdu, dpdv], axis=1)
    return np.where(np.isfinite(out), out, 0.0)


def bump_tables(materials: list, material_of: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                vertex_uvs: np.ndarray) -> tuple:
    """``(tri_row (F,), tangents (R, 6), maps (M, 14), bitmap atlas)`` as
    common.kernels.bump_mapping.perturb reads them, tangents for every triangle whose material
    has a map (an emitting one too: Mitsuba perturbs its BSDF as any other); :func:`no_bumps`
    where none has."""
    maps = np.zeros((len(materials), MAP_COLUMNS))
    parts, base = [], 0
    for i, mat in enumerate(materials):
        t = mat.normal_map if mat.normal_map is not None else mat.bump_map
        if t is None:
            continue
        kind = NORMAL_MAP if mat.normal_map is not None else BUMP_MAP
        if t.is_constant:
            if kind == BUMP_MAP:
                continue  # a constant height has no gradient
            maps[i, 0] = kind
            maps[i, 10] = mat.flip_invalid_normals
            maps[i, 11:14] = t.rgb
            continue
        img = np.ascontiguousarray(t.image, np.float32)
        maps[i, :11] = (kind, base, img.shape[0], img.shape[1], *t.uv_scale, *t.uv_offset, t.filter == "nearest",
                        mat.bump_scale, mat.flip_invalid_normals)
        parts.append(img.reshape(-1))
        base += img.size
    perturbed = maps[material_of, 0] > 0 if len(material_of) else np.zeros(0, bool)
    if not perturbed.any():
        return no_bumps()
    idx = np.flatnonzero(perturbed)
    tri_row = np.full(len(material_of), -1, np.int32)
    tri_row[idx] = np.arange(len(idx), dtype=np.int32)
    tangents = np.ascontiguousarray(triangle_tangents(vertices, faces[idx], vertex_uvs))
    pixels = np.concatenate(parts) if parts else np.zeros(0, np.float32)
    return tri_row, tangents, maps, pixels
