"""Compiled hit reconstruction (common.kernels.hit_surface) equals the numpy original
(tests/oracle_hit_surface.py) on real scenes: smooth and flat meshes, textured uvs, misses."""
from __future__ import annotations

import numpy as np
import pytest

from tests.support.oracle_hit_surface import surface_numpy
from igi.bench.stress_scenes import load_shared
from igi.common.geometry import Geometry


@pytest.mark.parametrize("name", ["cornell-box-sphere", "modern-hall", "veach-ajar"])
def test_reconstruction_matches_numpy(name):
    scene = load_shared(name)
    geom = Geometry(scene)
    geom.need_uv = True
    g = np.random.default_rng(1)
    n = 4000
    o = np.tile(geom.center, (n, 1)) + (g.random((n, 3)) - 0.5) * 0.2 * geom.extent
    d = g.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    o32 = (o - geom.center).astype(np.float32)
    r = geom._embree.run(o32, d.astype(np.float32), output=1)
    prim = r["primID"].astype(np.int64)
    valid = (r["geomID"] != -1) & (prim >= 0)
    prim = np.where(valid, prim, -1)
    u, v, t = (r[k].astype(np.float64) for k in ("u", "v", "tfar"))
    valid[::97] = False  # some misses
    prim[::97] = -1
    got = geom._surface(o, d, valid, prim, u, v, t)
    want = surface_numpy(geom, o, d, valid, prim, u, v, t)
    assert valid.sum() > n // 2
    for f in ("valid", "prim", "material", "emitter", "mesh", "t"):
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
    for f in ("position", "ng", "ns", "uv"):
        np.testing.assert_allclose(getattr(got, f), getattr(want, f), rtol=0, atol=0,
                                   err_msg=f)
    # ng is turned to the shading normal's side, as in the original
    assert np.all(np.einsum("ij,ij->i", got.ng[valid], got.ns[valid]) >= -1e-6)
