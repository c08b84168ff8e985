"""The caustic photon estimate at the end points (Wald et al. 2002 §4.1; Jensen's density
estimate with a constant kernel over the disc of radius r), compiled: for the (photon, end
point) pairs the hashed-grid query found, the photons that arrived on the side the eye sees
and within the path-length limit add power × f / |cos| / albedo / (π r²) to their end point
— one pass instead of a dozen numpy passes over the pairs and a BSDF parameter subset.

Sums run in the pairs' order (grouped by end point, as the query returns them), with the
arithmetic of the numpy form it replaced, so the estimates are bit-identical to it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame

_NEG_MAX = -np.finfo(np.float64).max  # numpy's nan_to_num puts -inf there


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per pair.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def estimate(pi, qi, direction, depth, power, ns, wi, segments, max_depth, P, prow, albedo, area, out) -> None:
    """out[qi[k]] += the contribution of photon pi[k] at end point qi[k] (per unit albedo),
    for every pair k: photon ``direction`` (toward where it came from), light-path ``depth``,
    ``power``; end point shading normal ``ns``, local ``wi``, eye ``segments``, BSDF row
    ``prow`` of P, ``albedo``; ``area`` π r²; ``max_depth`` < 0: no limit."""
    for k in range(pi.shape[0]):
        p = pi[k]
        e = qi[k]
        nx, ny, nz = ns[e, 0], ns[e, 1], ns[e, 2]
        dx, dy, dz = direction[p, 0], direction[p, 1], direction[p, 2]
        wz = wi[e, 2]
        # np.sign of the eye's side (0 on the tangent plane, NaN stays NaN)
        side = 1.0 if wz > 0 else (-1.0 if wz < 0 else (0.0 if wz == 0 else wz))
        # einsum("ij,ij->i")'s summation order for three terms
        if not ((dx * nx + dz * nz) + dy * ny) * side > 0:
            continue  # photons arriving on the other side: thin walls must not leak caustics
        if max_depth >= 0 and segments[e] + depth[p] > max_depth:
            continue
        lx, ly, lz = shading_frame.to_local(dx, dy, dz, nx, ny, nz)
        r, g, b, _pdf = kb.eval_pdf(P, prow[e], wi[e, 0], wi[e, 1], wz, lx, ly, lz)
        cos = max(abs(lz), 1e-6)  # eval includes |cos θ|; the photon estimate uses f alone
        f = (r / cos, g / cos, b / cos)
        for c in range(3):
            v = power[p, c] * f[c] / max(albedo[e, c], 1e-6) / area
            if math.isnan(v) or v == math.inf:
                v = 0.0
            elif v == -math.inf:
                v = _NEG_MAX
            out[e, c] += v
