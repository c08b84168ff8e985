"""Mitsuba 3's canonical shapes as triangle meshes in their local frame.

Every function returns ``(vertices (V,3) float64, faces (F,3) int32, normals (V,3) float64,
uvs (V,2) float64)``.

UV convention: :class:`common.scene.Texture.eval` maps bitmap row 0 to ``v = 1`` while Mitsuba 3's
bitmap texture maps row 0 to its surface ``v = 0`` (verified with Mitsuba 3.9.1). So every mesh
in a :class:`~common.scene.Scene` stores ``(u, 1 - v_mitsuba)``; the texture lookups then hit the
same texel as Mitsuba. Below, ``v_mitsuba`` is the value Mitsuba reports in ``si.uv``:

- rectangle: ``((x + 1) / 2, (y + 1) / 2)`` on ``[-1, 1]^2``, z = 0, normal +z
- cube: Mitsuba's own 24-vertex cube (per-face quads, uv (0,1),(1,1),(1,0),(0,0) per face)
- sphere: ``(phi / 2pi, theta / pi)`` with ``phi = atan2(y, x)`` in [0, 2pi), ``theta = acos(z)``
- disk: ``(r, phi / 2pi)``
- cylinder: ``(phi / 2pi, z)`` on the unit cylinder about +z, z in [0, 1]

Analytic Mitsuba shapes (sphere, disk, cylinder) are tessellated here; the sphere with 128 x 64
segments and smooth (exact) normals, the disk and the cylinder with 128 segments.
"""
from __future__ import annotations

import numpy as np


def _flip_v(uv_mitsuba: np.ndarray) -> np.ndarray:
    uv = np.array(uv_mitsuba, dtype=np.float64)
    uv[:, 1] = 1.0 - uv[:, 1]
    return uv


def rectangle():
    # Vertex order and triangulation as Mitsuba 3.9.1's rectangle mesh.
    v = np.array([[-1, -1, 0], [1, -1, 0], [-1, 1, 0], [1, 1, 0]], dtype=np.float64)
    f = np.array([[1, 2, 0], [1, 3, 2]], dtype=np.int32)
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    uv_m = (v[:, :2] + 1.0) * 0.5
    return v, f, n, _flip_v(uv_m)


# Mitsuba 3.9.1's cube mesh (vertex_positions/normals/texcoords/faces buffers of the `cube` shape).
_CUBE_P = [
    [1, -1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1],
    [1, 1, -1], [-1, 1, -1], [-1, 1, 1], [1, 1, 1],
    [1, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1],
    [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1],
    [-1, -1, 1], [-1, 1, 1], [-1, 1, -1], [-1, -1, -1],
    [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1],
]
_CUBE_N = [[0, -1, 0]] * 4 + [[0, 1, 0]] * 4 + [[1, 0, 0]] * 4 + [[0, 0, 1]] * 4 + [[-1, 0, 0]] * 4 + [[0, 0, -1]] * 4
_CUBE_UV = [[0, 1], [1, 1], [1, 0], [0, 0]] * 6
_CUBE_F = [[0, 1, 2], [3, 0, 2], [4, 5, 6], [7, 4, 6], [8, 9, 10], [11, 8, 10],
           [12, 13, 14], [15, 12, 14], [16, 17, 18], [19, 16, 18], [20, 21, 22], [23, 20, 22]]


def cube():
    v = np.array(_CUBE_P, dtype=np.float64)
    f = np.array(_CUBE_F, dtype=np.int32)
    n = np.array(_CUBE_N, dtype=np.float64)
    return v, f, n, _flip_v(np.array(_CUBE_UV, dtype=np.float64))


def sphere(center=(0.0, 0.0, 0.0), radius: float = 1.0, n_phi: int = 128, n_theta: int = 64):
    """UV sphere; vertices lie on the exact sphere, normals are the exact radial directions."""
    theta = np.linspace(0.0, np.pi, n_theta + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, n_phi + 1)
    th, ph = np.meshgrid(theta, phi, indexing="ij")  # (n_theta+1, n_phi+1)
    st = np.sin(th)
    d = np.stack([st * np.cos(ph), st * np.sin(ph), np.cos(th)], axis=-1).reshape(-1, 3)
    d[np.abs(d) < 1e-15] = 0.0
    uv_m = np.stack([ph / (2.0 * np.pi), th / np.pi], axis=-1).reshape(-1, 2)
    cols = n_phi + 1
    i, j = np.meshgrid(np.arange(n_theta), np.arange(n_phi), indexing="ij")
    a = (i * cols + j).ravel()
    b = ((i + 1) * cols + j).ravel()
    c = ((i + 1) * cols + j + 1).ravel()
    e = (i * cols + j + 1).ravel()
    ii = i.ravel()
    t1 = np.stack([a, b, c], axis=1)[ii != n_theta - 1]  # the bottom row's first triangle collapses
    t2 = np.stack([a, c, e], axis=1)[ii != 0]  # the top row's second triangle collapses
    f = np.concatenate([t1, t2]).astype(np.int32)
    v = np.asarray(center, dtype=np.float64) + float(radius) * d
    n = d * (1.0 if radius >= 0 else -1.0)
    return v, f, n, _flip_v(uv_m)


def disk(n_seg: int = 128):
    """Unit disk in z = 0, normal +z; one centre vertex per segment so that uv = (r, phi/2pi) is exact."""
    phi = np.linspace(0.0, 2.0 * np.pi, n_seg + 1)
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
    ring[np.abs(ring) < 1e-15] = 0.0
    mid = 0.5 * (phi[:-1] + phi[1:])
    centres = np.zeros((n_seg, 3))
    v = np.concatenate([ring, centres])
    uv_m = np.concatenate([np.stack([np.ones_like(phi), phi / (2 * np.pi)], axis=1),
                           np.stack([np.zeros(n_seg), mid / (2 * np.pi)], axis=1)])
    k = np.arange(n_seg)
    f = np.stack([n_seg + 1 + k, k, k + 1], axis=1).astype(np.int32)
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    return v, f, n, _flip_v(uv_m)


def cylinder(n_phi: int = 128):
    """Mitsuba's open cylinder in its local frame: radius 1 about +z from z = 0 to 1, no caps,
    normals outward; uv = (phi / 2pi, z). One band of quads (exact along z), smooth normals."""
    phi = np.linspace(0.0, 2.0 * np.pi, n_phi + 1)
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    ring[np.abs(ring) < 1e-15] = 0.0
    v = np.concatenate([np.column_stack([ring, np.zeros(n_phi + 1)]), np.column_stack([ring, np.ones(n_phi + 1)])])
    n = np.concatenate([np.column_stack([ring, np.zeros(n_phi + 1)])] * 2)
    uv_m = np.concatenate([np.stack([phi / (2 * np.pi), np.zeros_like(phi)], axis=1),
                           np.stack([phi / (2 * np.pi), np.ones_like(phi)], axis=1)])
    k = np.arange(n_phi)
    top = n_phi + 1 + k
    # counter-clockwise seen from outside: the geometric normal faces out, as the shading normals
    f = np.concatenate([np.stack([k, k + 1, top + 1], axis=1), np.stack([k, top + 1, top], axis=1)]).astype(np.int32)
    return v, f, n, _flip_v(uv_m)


def flip_normals(faces: np.ndarray, normals: np.ndarray | None):
    """Mitsuba's ``flip_normals``: reverse the winding (geometric normal) and negate shading normals."""
    f = np.ascontiguousarray(np.asarray(faces)[:, ::-1])
    n = None if normals is None else -np.asarray(normals)
    return f, n
