"""The end points' BSDF-sampled continuation rays (worker.shading.trace_bsdf_rays), compiled:
each listed end point samples its BSDF at its own wi, and those whose sample carries light
come back, in order, with the sample's weight, pdf and delta flag, the world direction and the
origin offset off the surface — one pass instead of a BSDF parameter pack, a sample call and
five numpy passes per batch. The math is the kernels' own, in the numpy form's order: the rays
are bit-identical to it.
"""
from __future__ import annotations

from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per point.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def sample_rays(P, prow, src, wi, ns, pos, ng, u1, u2, radiance, center, eps, ulps,
                out_src, out_w, out_pdf, out_delta, out_d, out_o) -> int:
    """End points ``i = src[j]`` sample their BSDF (row ``prow[i]`` of P) at local ``wi[i]``
    with (u1[j], u2[j]); the samples that carry light (positive in some channel, finite in
    all) are written in order: i, weight, pdf, delta, world direction (shading frame of
    ns[i]) and the origin pos[i] offset along ng[i] to the ray's side. Returns how many."""
    c = 0
    for j in range(src.shape[0]):
        i = src[j]
        ox, oy, oz, w0, w1, w2, p, delta = kb.sample(P, prow[i], wi[i, 0], wi[i, 1], wi[i, 2], u1[j], u2[j, 0],
                                                     u2[j, 1], radiance)
        if not kb.carries(w0, w1, w2):
            continue
        dx, dy, dz = shading_frame.to_world(ox, oy, oz, ns[i, 0], ns[i, 1], ns[i, 2])
        out_src[c] = i
        out_w[c, 0], out_w[c, 1], out_w[c, 2] = w0, w1, w2
        out_pdf[c] = p
        out_delta[c] = delta
        out_d[c, 0], out_d[c, 1], out_d[c, 2] = dx, dy, dz
        out_o[c, 0], out_o[c, 1], out_o[c, 2] = offset_point(pos[i, 0], pos[i, 1], pos[i, 2], ng[i, 0], ng[i, 1],
                                                              ng[i, 2], dx, dy, dz, center, eps, ulps)
        c += 1
    return c
