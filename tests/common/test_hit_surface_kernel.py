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


def test_offset_points_equal_the_numpy_offset_and_handle_grazing_and_nan():
    """Geometry.offset (compiled) moves points exactly as the numpy formula did: eps plus float32
    ulps of the centred coordinate, along ng to the side of ``towards`` (0: the normal's side);
    a NaN direction keeps the normal's side instead of making the origin NaN."""
    geom = Geometry(load_shared("cornell-box"))
    g = np.random.default_rng(3)
    n = 2000
    p = geom.center + g.normal(size=(n, 3)) * geom.extent * np.logspace(-3, 2, n)[:, None]
    ng = g.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    towards = g.normal(size=(n, 3))
    towards[:50] = 0.0  # exactly tangent
    towards[50:60] = np.cross(ng[50:60], g.normal(size=(10, 3)))  # grazing: dot ~ 0
    towards[60] = np.nan
    side = np.sign(np.einsum("ij,ij->i", ng, towards))
    side[side == 0] = 1.0
    scale = geom.eps + 4 * np.finfo(np.float32).eps * np.abs(p - geom.center).max(axis=1)
    want = p + ng * (side * scale)[:, None]
    got = geom.offset(p, ng, towards)
    dot = np.einsum("ij,ij->i", ng, towards)
    ok = np.isfinite(want).all(axis=1) & (np.abs(dot) > 1e-12)
    np.testing.assert_array_equal(got[ok], want[ok])
    np.testing.assert_array_equal(got[:50], want[:50])  # towards = 0: the normal's side
    # grazing within rounding (the dot's sign depends on summation order): either side, exactly
    for i in np.nonzero(np.isfinite(dot) & ~ok)[0]:
        assert any(np.array_equal(got[i], p[i] + ng[i] * (sgn * scale[i])) for sgn in (1.0, -1.0))
    np.testing.assert_array_equal(got[60], p[60] + ng[60] * scale[60])
    # explicit scales keep the numpy path; broadcasting one normal over many points works
    np.testing.assert_array_equal(geom.offset(p, ng, towards, scale=scale)[ok], want[ok])
    assert geom.offset(p[:3], ng[0], towards[:3]).shape == (3, 3)


def test_intersect_tmax_keeps_exactly_the_hits_closer_than_it():
    geom = Geometry(load_shared("cornell-box"))
    g = np.random.default_rng(4)
    o = np.tile(geom.center, (3000, 1))
    d = g.normal(size=(3000, 3))
    full = geom.intersect(o, d)
    for tmax in (0.0, 0.3 * geom.extent, 1e30):
        short = geom.intersect(o, d, tmax=tmax)
        np.testing.assert_array_equal(short.valid, full.valid & (full.t < tmax))
        np.testing.assert_array_equal(short.t[short.valid], full.t[short.valid])
