"""The numpy form of BSDF-direct light (worker.shading.bsdf_direct before it was compiled into
worker.kernels.bsdf_direct): the compiled path's oracle in tests/worker/test_bsdf_direct_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf


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
        # (the product's sum of three products, left to right: numpy's einsum adds x and z first)
        dv, nv = d[v], hits.ns[v]
        cos_front = -(dv[:, 0] * nv[:, 0] + dv[:, 1] * nv[:, 1] + dv[:, 2] * nv[:, 2])
        le[v] = lights.emitted_radiance(hits.emitter[v], cos_front)
    if np.any(env > 0) and (~v).any():
        le[~v] = env if lights.env_map is None else lights.environment_radiance(d[~v])
    # emitter_pdf's solid-angle pdf, its cosine summed left to right as above
    pl = np.zeros(len(d))
    if v.any():
        pl[v] = (lights.area_pdf(hits.emitter[v], light_mis.emitter_pmf) * hits.t[v] ** 2
                 / np.maximum(np.abs(cos_front), 1e-7))
    if (~v).any() and np.any(env > 0):
        g = light_mis.env_guide
        pl[~v] = g.pmf * g.pdf(d[~v]) if g is not None else lights.environment_pdfs(d[~v], light_mis.emitter_pmf)
    pl = pl * light_mis.direct_count
    w_mis = np.where(delta, 1.0, pdf_b ** 2 / np.maximum(pdf_b ** 2 + pl ** 2, 1e-300))
    contrib = weight * le * w_mis[:, None] / np.maximum(albedo[ok], 1e-6)
    out[ok] = bsdf.finite_or_zero(contrib)
    return out
