"""The numpy bounce of light walks and caustic photons (worker.vpl._light_walks,
worker.caustics._trace_photons before worker.kernels.light_paths): the oracle of
tests/worker/test_light_paths_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.lights import to_local, to_world


def shading_normal_correction(wi, wo, ns, ng):
    """Veach's |wi·ns| |wo·ng| / (|wi·ng| |wo·ns|) per row (1 where ns is ng; 0 where wi runs
    along the true surface or wo along the shading one)."""
    ci_s, ci_g = np.abs(np.sum(wi * ns, 1)), np.abs(np.sum(wi * ng, 1))
    co_s, co_g = np.abs(np.sum(wo * ns, 1)), np.abs(np.sum(wo * ng, 1))
    ok = (ci_g > 1e-9) & (co_s > 1e-9)
    corr = np.where(ok, ci_s / np.where(ok, ci_g, 1.0) * (co_g / np.where(ok, co_s, 1.0)), 0.0)
    return np.where(np.all(ns == ng, axis=1), 1.0, corr)


def continue_paths_numpy(sp, geom, sel, rows, pos, ns, ng, d, o, flux, u, col, survival=None, bounce=0, bumped=None):
    """As worker.light_paths.continue_paths; updates d, o, flux in place."""
    idx = rows[sel]
    wi = to_local(-d[idx], ns[sel])
    wo, weight, _pdf, _delta = bsdf.sample(sp.subset(sel), wi, u[idx, col], u[idx, col + 1:col + 3],
                                           mode="importance")
    wd = to_world(wo, ns[sel])
    if bumped is not None:
        corr = shading_normal_correction(-d[idx], wd, ns[sel], ng[sel])
        weight = weight * np.where(bumped[sel], corr, 1.0)[:, None]
    if survival is not None:
        q = np.clip(np.max(weight, axis=1), 0.0, 0.95)
        survive = survival[idx, bounce] < q
        weight = np.where(survive[:, None], weight / np.maximum(q, 1e-12)[:, None], 0.0)
    flux[idx] = flux[idx] * weight
    d[idx] = wd
    o[idx] = geom.offset(pos[sel], ng[sel], wd)
    return idx[bsdf.carrying(flux[idx])]
