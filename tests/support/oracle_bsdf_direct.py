"""The numpy form of BSDF-direct light (worker.shading.bsdf_direct before it was compiled into
worker.kernels.bsdf_direct): the compiled path's oracle in tests/worker/test_bsdf_direct_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.worker.shading import emitter_pdf


def bsdf_direct_numpy(lights, rays, albedo: np.ndarray, light_mis) -> np.ndarray:
    """(len(albedo), 3): each lit ray's MIS-weighted emission per unit albedo at its row."""
    out = np.zeros((len(albedo), 3))
    hits = rays.hits
    env = lights.environment()
    sel = rays.lit(env)
    if len(sel) == 0:
        return out
    ok, weight, pdf_b, delta, d = (a.take(sel, axis=0) for a in (rays.rows, rays.weight, rays.pdf, rays.delta,
                                                                 rays.direction))
    hits = hits.rows(sel)
    le = np.zeros((len(ok), 3))
    v = hits.valid
    if v.any():
        cos_front = -np.einsum("ij,ij->i", d[v], hits.ns[v])
        le[v] = lights.emitted_radiance(hits.emitter[v], cos_front)
    if np.any(env > 0) and (~v).any():
        le[~v] = env
    pl = emitter_pdf(lights, hits, v, d, light_mis)
    w_mis = np.where(delta, 1.0, pdf_b ** 2 / np.maximum(pdf_b ** 2 + pl ** 2, 1e-300))
    contrib = weight * le * w_mis[:, None] / np.maximum(albedo[ok], 1e-6)
    out[ok] = bsdf.finite_or_zero(contrib)
    return out
