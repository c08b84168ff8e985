"""Uniform points on mesh triangles (common.geometry.Geometry.sample_triangles), compiled.

Why: emitters are sampled for every light walk and caustic photon of every set; the numpy form
was ~20 passes with temporaries over the points (~3 ms a frame's photon sets at 25 sets). The
arithmetic is the numpy form's, in float64 and in the same order, so the points are identical
(tests/common/test_geometry.py compares both).
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def sample(tri, faces, vertex_uvs, face_normal, smooth, vertex_normals, tri_idx, u, pos, normal, uv) -> None:
    """Point i on triangle tri_idx[i] from uniforms u[i] (square-root warp, barycentrics
    (1 - b1 - b2, b1, b2) with b1 = 1 - √u0, b2 = u1·√u0): position, normal (the interpolated
    vertex normal where the mesh has them and it is not degenerate, else the face normal) and
    texture coordinates."""
    for i in range(tri_idx.shape[0]):
        t = tri_idx[i]
        su = math.sqrt(u[i, 0])
        b1 = 1.0 - su
        b2 = u[i, 1] * su
        w0 = 1.0 - b1 - b2
        for a in range(3):
            pos[i, a] = w0 * tri[t, 0, a] + b1 * tri[t, 1, a] + b2 * tri[t, 2, a]
        f0, f1, f2 = faces[t, 0], faces[t, 1], faces[t, 2]
        for a in range(2):
            uv[i, a] = w0 * vertex_uvs[f0, a] + b1 * vertex_uvs[f1, a] + b2 * vertex_uvs[f2, a]
        n0, n1, n2 = face_normal[t, 0], face_normal[t, 1], face_normal[t, 2]
        if smooth[t]:
            s0 = w0 * vertex_normals[f0, 0] + b1 * vertex_normals[f1, 0] + b2 * vertex_normals[f2, 0]
            s1 = w0 * vertex_normals[f0, 1] + b1 * vertex_normals[f1, 1] + b2 * vertex_normals[f2, 1]
            s2 = w0 * vertex_normals[f0, 2] + b1 * vertex_normals[f1, 2] + b2 * vertex_normals[f2, 2]
            ln = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
            if ln > 1e-12:
                n0, n1, n2 = s0 / ln, s1 / ln, s2 / ln
        normal[i, 0] = n0
        normal[i, 1] = n1
        normal[i, 2] = n2
