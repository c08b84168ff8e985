"""The compiled chain bounce (worker.kernels.specular_chain through worker.shading.delta_bounce)
gives exactly the rays of the numpy bounce it replaced (tests/support/oracle_specular_chain.py),
with per-material and per-point (textured) parameters, on grazing, NaN and empty inputs."""
from __future__ import annotations

import numpy as np
import pytest

from igi.bench.stress_scenes import load_shared
from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.scene import CONDUCTOR, DIELECTRIC, DIFFUSE, PLASTIC, THINDIELECTRIC, Material, Texture
from igi.worker.shading import delta_bounce
from tests.support.oracle_specular_chain import delta_bounce_numpy

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN inputs


def _materials(textured: bool) -> list[Material]:
    mats = [Material("mirror", CONDUCTOR),
            Material("gold", CONDUCTOR, eta=np.array([0.2, 0.4, 1.4]), k=np.array([3.6, 2.4, 1.8])),
            Material("glass", DIELECTRIC, int_ior=1.5),
            Material("thin", THINDIELECTRIC, int_ior=1.33, specular_transmittance=Texture.constant([0.9, 0.8, 0.7])),
            Material("plastic", PLASTIC),  # samples its diffuse layer too: not delta
            Material("wall", DIFFUSE)]
    if textured:
        img = np.random.default_rng(5).random((4, 4, 3)).astype(np.float32)
        mats.append(Material("tinted mirror", CONDUCTOR, specular=Texture(image=img, filter="nearest")))
    return mats


def _vertices(rng, n: int, n_mats: int, geom: Geometry):
    pos = geom.center + (rng.random((n, 3)) - 0.5) * geom.extent
    ns = rng.normal(size=(n, 3))
    ns /= np.linalg.norm(ns, axis=1)[:, None]
    ng = ns.copy()
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    graze = np.arange(0, n, 7)  # arrival exactly in the tangent plane, and just off it
    t = np.cross(ns[graze], rng.normal(size=(len(graze), 3)))
    d[graze] = t / np.linalg.norm(t, axis=1)[:, None] + ns[graze] * rng.choice([0.0, 1e-9, -1e-9], len(graze))[:, None]
    d[5] = np.nan
    ns[11] = np.nan
    thr = rng.random((n, 3)) * 2
    thr[13] = [np.inf, 1.0, 1.0]
    seg = rng.integers(1, 9, n)
    mat = rng.integers(-1, n_mats, n)  # -1: NULL
    uv = rng.random((n, 2))
    return pos, ns, ng, d, thr, seg, mat, uv


@pytest.mark.parametrize("textured", [False, True])
@pytest.mark.parametrize("max_depth", [-1, 5])
@pytest.mark.parametrize("delta_only", [True, False])
def test_bounce_equals_the_numpy_bounce(textured, max_depth, delta_only):
    geom = Geometry(load_shared("cornell-box"))
    mats = _materials(textured)
    g = np.random.default_rng(7)
    n = 3000
    pos, ns, ng, d, thr, seg, mat, uv = _vertices(g, n, len(mats), geom)
    src = np.sort(g.choice(n, 2000, replace=False))
    got = delta_bounce(mats, geom, src, pos, ns, ng, d, thr, seg, mat, uv, max_depth, np.random.default_rng(1),
                       delta_only=delta_only)
    want = delta_bounce_numpy(mats, geom, src, pos, ns, ng, d, thr, seg, mat, uv, max_depth,
                              np.random.default_rng(1), delta_only=delta_only)
    assert 200 < len(want[0]) < len(src)  # some rays die (diffuse, NULL, NaN, depth), most live
    for name, a, b in zip(("src", "throughput", "segments", "direction", "origin"), got, want):
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert np.isfinite(got[1]).all() and np.isfinite(got[3]).all()


def test_empty_bounce_returns_empty_rays():
    geom = Geometry(load_shared("cornell-box"))
    z3 = np.zeros((0, 3))
    out = delta_bounce(_materials(False), geom, np.zeros(0, np.int64), z3, z3, z3, z3, z3, np.zeros(0, np.int64),
                       np.zeros(0, np.int64), np.zeros((0, 2)), -1, np.random.default_rng(0))
    assert [len(a) for a in out] == [0] * 5


@pytest.mark.parametrize("textured", [False, True])
def test_packed_rows_of_gathered_points_hold_each_points_parameters(textured):
    """bsdf.packed_rows of gathered points: row[j] of P holds point j's parameters, as pack(gather(...))
    has them at row j (per material where no texture is read, per point otherwise)."""
    mats = _materials(textured)
    g = np.random.default_rng(3)
    mat = g.integers(-2, len(mats) + 1, 500)  # out of range on both sides: NULL
    uv = g.random((500, 2))
    P, row = bsdf.packed_rows(bsdf.gather(mats, mat, uv))
    want = bsdf.pack(bsdf.gather(mats, mat, uv))
    assert len(P) == len(want)
    per_point = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 14, 15, 16)  # the tables (12, 13) are shared
    for f in per_point:
        np.testing.assert_array_equal(P[f][row], want[f], err_msg=f"P[{f}]")
    assert (len(P[0]) == len(mat)) == textured  # textured points: per point; else one row per material


def _lensed(monkeypatch, compiled: bool, max_depth: int, sky: bool):
    """worker.indirect_caustics.lensed_arrivals on cornell-box-sphere's end points (96×72): the
    sky seen through the chains, the chains' ends (as one array), the next draw of its generator
    and the rays it traced, with its chains followed by the compiled kernel (``compiled``) or by
    its numpy loop."""
    from igi.worker.arrivals import _FIELDS
    from igi.worker.indirect_caustics import lensed_arrivals
    from tests.support.end_points import traced_end_points

    scene, r, eye, rays, _d2, g = traced_end_points(monkeypatch, "cornell-box-sphere", compiled, sky, max_depth, 3)
    before = r.geom.counters["intersect_rays"]
    sky_light, ends = lensed_arrivals(scene, r.geom, r.lights, eye.end, rays, max_depth, 8, g)
    table = np.column_stack([np.asarray(getattr(ends, f), np.float64).reshape(len(ends), -1) for f in _FIELDS])
    return sky_light, table, g.random(), r.geom.counters["intersect_rays"] - before


@pytest.mark.parametrize("max_depth", [-1, 4])
@pytest.mark.parametrize("sky", [False, True])
def test_compiled_chains_equal_the_numpy_chains(monkeypatch, max_depth, sky):
    """kernels.specular_chain.follow_chains, whole chains in one call, gives lensed_arrivals
    what its numpy loop gave bit for bit: the sky, the chains' ends, the generator's draws, the
    rays traced."""
    got = _lensed(monkeypatch, True, max_depth, sky)
    monkeypatch.undo()
    want = _lensed(monkeypatch, False, max_depth, sky)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2:] == want[2:]
    assert len(got[1]) > 100  # chains did pass through the ball to a surface


def test_a_lit_sky_seen_through_the_chains_adds_light(monkeypatch):
    dark = _lensed(monkeypatch, True, -1, False)[0]
    lit = _lensed(monkeypatch, True, -1, True)[0]
    assert (lit.sum(axis=1) > dark.sum(axis=1) + 1e-9).sum() > 50
