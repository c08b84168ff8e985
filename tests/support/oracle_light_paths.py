"""The numpy bounce of light walks and caustic photons (worker.vpl._light_walks,
worker.caustics._trace_photons before worker.kernels.light_paths): the oracle of
tests/worker/test_light_paths_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.lights import to_local, to_world


def continue_paths_numpy(sp, geom, sel, rows, pos, ns, ng, d, o, flux, u, col, survival=None, bounce=0):
    """As worker.light_paths.continue_paths; updates d, o, flux in place."""
    idx = rows[sel]
    wi = to_local(-d[idx], ns[sel])
    wo, weight, _pdf, _delta = bsdf.sample(sp.subset(sel), wi, u[idx, col], u[idx, col + 1:col + 3],
                                           mode="importance")
    wd = to_world(wo, ns[sel])
    if survival is not None:
        q = np.clip(np.max(weight, axis=1), 0.0, 0.95)
        survive = survival[idx, bounce] < q
        weight = np.where(survive[:, None], weight / np.maximum(q, 1e-12)[:, None], 0.0)
    flux[idx] = flux[idx] * weight
    d[idx] = wd
    o[idx] = geom.offset(pos[sel], ng[sel], wd)
    return idx[bsdf.carrying(flux[idx])]
