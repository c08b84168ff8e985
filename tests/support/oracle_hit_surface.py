"""The numpy hit reconstruction that common.kernels.hit_surface replaced: a test oracle."""
from __future__ import annotations

import numpy as np

from igi.common.geometry import Hits


def surface_numpy(self, origins, directions, valid, prim, u, v, t) -> Hits:
    n = len(origins)
    p_idx = np.where(valid, prim, 0)
    f32 = np.float32
    u32 = u.astype(f32)[:, None]
    v32 = v.astype(f32)[:, None]
    # Positions from the centred float32 triangle (precise relative to the scene's size),
    # moved back to world space in float64.
    pos = (self._v0c[p_idx] + u32 * self._e1c[p_idx] + v32 * self._e2c[p_idx]).astype(np.float64)
    pos += self.center
    ng = self._fn32[p_idx]
    ns = ng
    sm_any = self._any_smooth
    if sm_any:
        sm = valid & self.smooth[p_idx]
        if sm.any():
            tn = self._tri_normals[p_idx[sm]]  # (k, 3, 3) float32
            w0 = 1 - u32[sm] - v32[sm]
            wn = w0 * tn[:, 0] + u32[sm] * tn[:, 1] + v32[sm] * tn[:, 2]
            ln = np.sqrt((wn * wn).sum(axis=1))
            good = ln > 1e-12
            wn = np.where(good[:, None], wn / np.maximum(ln, f32(1e-30))[:, None], ng[sm])
            ns = ng.copy()
            ns[sm] = wn
            # Mitsuba orients by the shading frame: flip ng to the shading normal's side.
            flip = (ng[sm] * wn).sum(axis=1) < 0
            if flip.any():
                ng = ng.copy()
                rows = np.nonzero(sm)[0][flip]
                ng[rows] = -ng[rows]
    if self.need_uv:
        f = self.faces[p_idx]
        vt = self.vertex_uvs
        w0d = (1.0 - u - v)[:, None]
        uv = w0d * vt[f[:, 0]] + u[:, None] * vt[f[:, 1]] + v[:, None] * vt[f[:, 2]]
    else:
        uv = np.zeros((n, 2))
    mat = np.where(valid, self.material_of[p_idx], -1).astype(np.int32)
    em = np.where(valid, self.emitter_of[p_idx], -1).astype(np.int32)
    mesh = np.where(valid, self.mesh_of[p_idx], -1).astype(np.int32)
    return Hits(valid, np.where(valid, t, np.inf), prim, pos, ng.astype(np.float64),
                ns.astype(np.float64), uv, mat, em, mesh)

