"""The numpy photon estimate of worker.caustics.gather_photons (before
worker.kernels.photon_estimate): the oracle of tests/worker/test_photon_estimate_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.lights import to_local


def gather_photons_numpy(end, photons, albedo, max_depth):
    out = np.zeros((len(end), 3))
    if len(end) == 0 or photons.grid is None or len(photons) == 0:
        return out
    pi_idx, qi = photons.grid.query(end.position)
    if len(pi_idx) == 0:
        return out
    eye_side = np.sign(end.wi[qi, 2])
    same = np.einsum("ij,ij->i", photons.direction[pi_idx], end.ns[qi]) * eye_side > 0
    if max_depth >= 0:
        same &= end.segments[qi] + photons.depth[pi_idx] <= max_depth
    pi_idx, qi = pi_idx[same], qi[same]
    if len(qi) == 0:
        return out
    wo_local = to_local(photons.direction[pi_idx], end.ns[qi])
    f = bsdf.eval(end.sp.subset(qi), end.wi[qi], wo_local, mode="radiance")
    f = f / np.maximum(np.abs(wo_local[:, 2]), 1e-6)[:, None]
    contrib = photons.power[pi_idx] * f / np.maximum(albedo[qi], 1e-6) / (np.pi * photons.radius ** 2)
    np.add.at(out, qi, np.nan_to_num(contrib, nan=0.0, posinf=0.0))
    return out
