"""The compiled BSDF sampling of the end points' continuation rays (worker.kernels.bsdf_rays via
worker.shading.trace_bsdf_rays) gives the numpy form's rays bit for bit
(tests/support/oracle_bsdf_rays.py): diffuse, glossy, plastic and textured end points, a subset
of them, grazing and NaN directions."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from igi.bench.stress_scenes import eye_end_points, load_shared
from igi.common import bsdf
from igi.worker.kernels import bsdf_rays as br
from igi.worker.renderer import Renderer
from tests.support.oracle_bsdf_rays import sample_rays_numpy

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN inputs


@pytest.mark.parametrize("name", ["cornell-box-glossy", "modern-hall", "veach-ajar"])
@pytest.mark.parametrize("subset", [False, True])
def test_sampled_rays_equal_the_numpy_rays(name, subset):
    r = Renderer(load_shared(name))
    end = eye_end_points(r, 48, 36)
    wi = end.wi.copy()
    wi[::9, 2] = 0.0  # grazing
    wi[4] = np.nan
    end = dataclasses.replace(end, wi=wi)
    g = np.random.default_rng(2)
    ok = np.sort(g.choice(len(end), len(end) // 2, replace=False)) if subset else np.arange(len(end))
    want = sample_rays_numpy(r.geom, end, ok, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    n = len(ok)
    u1, u2 = rng.random(n), rng.random((n, 2))
    P, prow = bsdf.packed_rows(end.sp)
    out = (np.empty(n, np.int64), np.empty((n, 3)), np.empty(n), np.empty(n, bool), np.empty((n, 3)), np.empty((n, 3)))
    c = br.sample_rays(P, prow, ok, end.wi, end.ns, end.position, end.ng, u1, u2, True, *r.geom.offset_terms(), *out)
    assert 0 < len(want[0]) < n + 1
    for name_, got, w in zip(("rows", "weight", "pdf", "delta", "direction", "origin"), out, want):
        np.testing.assert_array_equal(got[:c], w, err_msg=name_)
