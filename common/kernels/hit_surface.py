"""Hit reconstruction from Embree's (primID, u, v, t): position from the centred float32
triangle, geometric and interpolated shading normal (ng turned to the shading normal's side,
as Mitsuba orients by the shading frame), texture coordinates, material/emitter/mesh ids; and
the scale-aware ray-origin offset off a hit surface."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .bump_mapping import perturb


@njit(cache=True, nogil=True, error_model="numpy")
def reconstruct(valid, prim, u, v, t, d, center, v0c, e1c, e2c, fn32, smooth, tri_normals, faces,
                vertex_uvs, need_uv, material_of, emitter_of, mesh_of, bumps,
                pos, ng, ns, uv, tt, mat, em, mesh):
    """``bumps``: the normal and bump maps' tables (common.bump_mapping.bump_tables; empty: none),
    which perturb the shading normal after ng has been turned to the interpolated one's side
    (``d``: the rays' directions, which the perturbation may depend on)."""
    one = np.float32(1.0)
    tri_row, tangents, maps, pixels = bumps
    bumped = tri_row.shape[0] > 0
    for i in range(valid.shape[0]):
        ok = valid[i]
        p = prim[i] if ok else 0
        u32 = np.float32(u[i])
        v32 = np.float32(v[i])
        for a in range(3):
            pos[i, a] = np.float64(v0c[p, a] + u32 * e1c[p, a] + v32 * e2c[p, a]) + center[a]
        g0, g1, g2 = fn32[p, 0], fn32[p, 1], fn32[p, 2]
        s0, s1, s2 = g0, g1, g2
        if ok and smooth[p]:
            w0 = one - u32 - v32
            a0 = w0 * tri_normals[p, 0, 0] + u32 * tri_normals[p, 1, 0] + v32 * tri_normals[p, 2, 0]
            a1 = w0 * tri_normals[p, 0, 1] + u32 * tri_normals[p, 1, 1] + v32 * tri_normals[p, 2, 1]
            a2 = w0 * tri_normals[p, 0, 2] + u32 * tri_normals[p, 1, 2] + v32 * tri_normals[p, 2, 2]
            ln = np.float32(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2))
            if ln > 1e-12:
                inv = max(ln, np.float32(1e-30))
                s0, s1, s2 = a0 / inv, a1 / inv, a2 / inv
                if g0 * s0 + g1 * s1 + g2 * s2 < 0:
                    g0, g1, g2 = -g0, -g1, -g2
        if need_uv:
            w = 1.0 - u[i] - v[i]
            f0, f1, f2 = faces[p, 0], faces[p, 1], faces[p, 2]
            for c in range(2):
                uv[i, c] = w * vertex_uvs[f0, c] + u[i] * vertex_uvs[f1, c] + v[i] * vertex_uvs[f2, c]
        else:
            uv[i, 0] = 0.0
            uv[i, 1] = 0.0
        ng[i, 0], ng[i, 1], ng[i, 2] = g0, g1, g2
        if ok and bumped:
            ns[i, 0], ns[i, 1], ns[i, 2] = perturb(p, material_of[p], uv[i, 0], uv[i, 1], s0, s1, s2, g0, g1, g2,
                                                   d[i, 0], d[i, 1], d[i, 2], tri_row, tangents, maps, pixels)
        else:
            ns[i, 0], ns[i, 1], ns[i, 2] = s0, s1, s2
        if ok:
            tt[i] = t[i]
            mat[i] = material_of[p]
            em[i] = emitter_of[p]
            mesh[i] = mesh_of[p]
        else:
            tt[i] = np.inf
            mat[i] = -1
            em[i] = -1
            mesh[i] = -1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def offset_point(px, py, pz, nx, ny, nz, tx, ty, tz, center, eps, ulps):
    """Point p moved off its surface along ng = n to the side t points to, by the scene epsilon
    plus ``ulps`` float32 ulps of the centred coordinate's largest component."""
    m = max(max(max(0.0, abs(px - center[0])), abs(py - center[1])), abs(pz - center[2]))
    scale = eps + ulps * m
    dot = nx * tx + ny * ty + nz * tz
    side = -1.0 if dot < 0.0 else 1.0  # 0 (and NaN): the normal's side
    return px + nx * (side * scale), py + ny * (side * scale), pz + nz * (side * scale)


@njit(cache=True, nogil=True, error_model="numpy")
def offset_points(p, ng, towards, center, eps, ulps, out):
    """``p`` moved off its surface along ``ng`` to the side ``towards`` points to
    (:func:`offset_point` per row; common.geometry.Geometry.offset fused: one pass instead of
    six numpy ones per bounce)."""
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = offset_point(p[i, 0], p[i, 1], p[i, 2], ng[i, 0], ng[i, 1], ng[i, 2],
                                                       towards[i, 0], towards[i, 1], towards[i, 2], center,
                                                       eps, ulps)
