"""Rays against a few bounding spheres: does a ray (unit direction) start inside or point
into any of them? Used to skip BSDF-sampled direct-light rays that provably miss every area
emitter (common.lights.LightSampler.may_reach_emitter)."""
from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def any_hit(o, d, centres, radii2, out):
    """out[i] = ray i starts inside some sphere, or some sphere's centre lies ahead of it
    (t_ca > 0) within its radius of the ray's line."""
    for i in range(o.shape[0]):
        hit = False
        for e in range(centres.shape[0]):
            c0 = centres[e, 0] - o[i, 0]
            c1 = centres[e, 1] - o[i, 1]
            c2 = centres[e, 2] - o[i, 2]
            cc = c0 * c0 + c1 * c1 + c2 * c2
            tca = c0 * d[i, 0] + c1 * d[i, 1] + c2 * d[i, 2]
            if cc <= radii2[e] or (tca > 0 and cc - tca * tca <= radii2[e]):
                hit = True
                break
        out[i] = hit
