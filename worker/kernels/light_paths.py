"""One bounce of the paths that leave the lights (instant radiosity's light walks, caustic
photons: Wald et al. 2002 §4, §4.1), fused: at each hit the BSDF is sampled in importance mode
with the path's own quasi-random numbers, the walk's Russian roulette applied past its bounce
limit, the flux multiplied, the next ray turned to world space and offset off the surface, and
the paths that still carry light listed — one pass instead of a dozen numpy passes per bounce.

The math is the kernels' own (common.kernels.bsdf.sample, shading_frame, hit_surface), applied
in the order of the numpy form it replaced, so the paths are bit-identical to it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per path.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def continue_paths(P, prow, sel, rows, pos, ns, ng, d, o, flux, u, col, roulette, survival, bounce,
                   center, eps, ulps, out_rows) -> int:
    """For the hits ``j = sel[t]`` (surface parameters at ``P[.][prow[j]]``, position, normals)
    of paths ``r = rows[j]``: sample the BSDF at -d[r] with u[r, col : col + 3] (importance
    mode); with ``roulette``, keep the path with probability q = clip(max weight, 0, 0.95)
    (uniform ``survival[r, bounce]``) and divide by q; flux[r] *= weight; d[r], o[r] = the new
    direction and the offset origin. Paths whose flux still carries light (positive in some
    channel, finite in all) are written to ``out_rows`` in order; returns how many."""
    c = 0
    for t in range(sel.shape[0]):
        j = sel[t]
        r = rows[j]
        nx, ny, nz = ns[j, 0], ns[j, 1], ns[j, 2]
        wix, wiy, wiz = shading_frame.to_local(-d[r, 0], -d[r, 1], -d[r, 2], nx, ny, nz)
        ox, oy, oz, w0, w1, w2, _p, _delta = kb.sample(P, prow[j], wix, wiy, wiz, u[r, col], u[r, col + 1],
                                                       u[r, col + 2], False)
        dx, dy, dz = shading_frame.to_world(ox, oy, oz, nx, ny, nz)
        if roulette:
            q = np.maximum(np.maximum(w0, w1), w2)  # NaN propagates, as numpy's max
            if not math.isnan(q):
                q = min(max(q, 0.0), 0.95)
            if survival[r, bounce] < q:
                s = max(q, 1e-12)
                w0, w1, w2 = w0 / s, w1 / s, w2 / s
            else:
                w0, w1, w2 = 0.0, 0.0, 0.0
        f0 = flux[r, 0] * w0
        f1 = flux[r, 1] * w1
        f2 = flux[r, 2] * w2
        flux[r, 0], flux[r, 1], flux[r, 2] = f0, f1, f2
        d[r, 0], d[r, 1], d[r, 2] = dx, dy, dz
        o[r, 0], o[r, 1], o[r, 2] = offset_point(pos[j, 0], pos[j, 1], pos[j, 2], ng[j, 0], ng[j, 1], ng[j, 2],
                                                 dx, dy, dz, center, eps, ulps)
        if kb.carries(f0, f1, f2):
            out_rows[c] = r
            c += 1
    return c
