"""The numpy sampling of worker.shading.trace_bsdf_rays (before worker.kernels.bsdf_rays):
the oracle of tests/worker/test_bsdf_rays_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.lights import to_world


def sample_rays_numpy(geom, end, ok, rng):
    """(ok, weight, pdf, delta, directions, origins) of the end points ``ok`` whose BSDF
    sample carries light."""
    wo, weight, pdf_b, delta = bsdf.sample(end.sp.subset(ok), end.wi[ok], rng.random(len(ok)),
                                           rng.random((len(ok), 2)), mode="radiance")
    live = np.flatnonzero(bsdf.carrying(weight))
    ok, wo, weight, pdf_b, delta = (a.take(live, axis=0) for a in (ok, wo, weight, pdf_b, delta))
    d = to_world(wo, end.ns[ok])
    return ok, weight, pdf_b, delta, d, geom.offset(end.position[ok], end.ng[ok], d)
