"""The numpy form of common.geometry.Geometry.sample_triangles, kept as the oracle of its
compiled kernel (common.kernels.triangle_sampling)."""
from __future__ import annotations

import numpy as np


def sample_triangles(geom, tri_idx: np.ndarray, u: np.ndarray) -> tuple:
    """Geometry.sample_triangles as it was in numpy: (position, normal, uv)."""
    su = np.sqrt(u[:, 0])
    b1 = 1 - su
    b2 = u[:, 1] * su
    tri = geom._tri[tri_idx]
    pos = (1 - b1 - b2)[:, None] * tri[:, 0] + b1[:, None] * tri[:, 1] + b2[:, None] * tri[:, 2]
    f = geom.faces[tri_idx]
    vt = geom.vertex_uvs
    uv = (1 - b1 - b2)[:, None] * vt[f[:, 0]] + b1[:, None] * vt[f[:, 1]] + b2[:, None] * vt[f[:, 2]]
    # Emission follows the shading normal, as in Mitsuba (a mirroring to_world flips the
    # winding but not the vertex normals).
    n = geom.face_normal[tri_idx].copy()
    sm = geom.smooth[tri_idx]
    if sm.any():
        vn = geom.vertex_normals
        fs = f[sm]
        w0, w1, w2 = (1 - b1 - b2)[sm, None], b1[sm, None], b2[sm, None]
        ns = w0 * vn[fs[:, 0]] + w1 * vn[fs[:, 1]] + w2 * vn[fs[:, 2]]
        ln = np.linalg.norm(ns, axis=1)
        good = ln > 1e-12
        n[np.nonzero(sm)[0][good]] = ns[good] / ln[good, None]
    return pos, n, uv
