"""Occlusion in Embree packets (common.ray_packets, common.kernels.ray_packets) answers every
shadow ray as embreex's one-ray-per-call scene does on the same triangles: real scenes, rays
of every length (zero, huge, unbounded), along edges and through vertices, NaN directions,
batch sizes that are not a multiple of a packet's lanes, empty batches; the Geometry falls back to embreex
where the packets are not at hand."""
from __future__ import annotations

import numpy as np
import pytest
from embreex import rtcore as rtc
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from igi.bench.stress_scenes import load_shared
from igi.common import geometry as geometry_module
from igi.common.geometry import Geometry
from igi.common.kernels import ray_packets as kernels
from igi.common.ray_packets import PacketScene, packet_scene

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="Embree's C library not found beside embreex")


def _embreex_occluded(local, o, d, t):
    scene = rtcs.EmbreeScene(rtc.EmbreeDevice(), robust=False)
    _mesh = TriangleMesh(scene, local)  # noqa: F841 - the scene holds it
    return scene.run(o, d, query="OCCLUDED", dists=t.copy())


def _rays(g, geom, n, edges=None):
    """n rays from inside the scene aimed at triangles' vertices, edge midpoints and
    interiors; ``edges`` (a list): gets the mask of the rays aimed at a vertex or an edge."""
    local = geom._local
    o = ((g.random((n, 3)) - 0.5) * geom.extent).astype(np.float32)
    tri = g.integers(0, len(local), n)
    bary = g.choice([0.0, 0.5, 1.0 / 3.0], size=(n, 1))
    centroid = (local[tri, 0] + local[tri, 1] + local[tri, 2]) / 3.0
    target = np.where(bary == 1.0 / 3.0, centroid, local[tri, 0] * (1 - bary) + local[tri, 1] * bary)
    if edges is not None:
        edges.append(bary[:, 0] != 1.0 / 3.0)
    d = (target - o).astype(np.float32)
    dist = np.linalg.norm(d, axis=1)
    t = (dist * g.choice([0.5, 0.999, 1.0, 1.001, 2.0], n)).astype(np.float32)
    t[::13] = 0.0
    t[1::13] = 3.0e38
    d[5] = np.nan
    d[6] = 0.0
    return o, d, t


@pytest.mark.parametrize("name", ["cornell-box-sphere", "veach-ajar", "modern-hall"])
def test_packets_answer_every_ray_as_embreex_does(name):
    geom = Geometry(load_shared(name))
    g = np.random.default_rng(4)
    edges = []
    o, d, t = _rays(g, geom, 20011, edges)  # not a multiple of 8 or 16
    scene = packet_scene(geom._local)
    assert isinstance(scene, PacketScene)
    got = scene.run(o, d, query="OCCLUDED", dists=t)
    want = _embreex_occluded(geom._local, o, d, t)
    assert got.dtype == np.int32
    # (a ray meeting a shared edge or vertex exactly: see the next test)
    np.testing.assert_array_equal(got[~edges[0]] != -1, want[~edges[0]] != -1)
    assert np.mean((got != -1)[edges[0]] != (want != -1)[edges[0]]) < 0.005
    assert 0.05 < np.mean(got != -1) < 0.98  # both answers occur
    assert scene.run(o[:0], d[:0], query="OCCLUDED", dists=t[:0]).shape == (0,)


def test_the_geometry_traces_shadow_rays_in_packets_and_falls_back_to_embreex(monkeypatch):
    """The same answers either way, but where a ray meets a shared edge or vertex exactly:
    without the robust mode Embree's packet kernels (8 lanes with AVX2) and its one-ray kernel
    may decide such a hit differently (a few in a thousand of the rays aimed at edges here)."""
    geom = Geometry(load_shared("cornell-box"))
    assert isinstance(geom.shadow_bvh(), PacketScene)
    g = np.random.default_rng(1)
    edges = []
    o, d, t = _rays(g, geom, 3000, edges)
    t[::17] = np.inf  # clamped to 3e38 by the kernel as by np.minimum on embreex's path
    t[3] = np.nan
    packets = geom.occluded_local(o, d, t)
    monkeypatch.setattr(geometry_module, "packet_scene", lambda *a, **k: None)
    plain = Geometry(load_shared("cornell-box"))
    assert not isinstance(plain.shadow_bvh(), PacketScene)
    answer = plain.occluded_local(o, d, t)
    np.testing.assert_array_equal(answer[~edges[0]], packets[~edges[0]])
    assert np.mean(answer[edges[0]] != packets[edges[0]]) < 0.005


def test_a_packet_scene_refuses_closest_hit_queries():
    scene = packet_scene(Geometry(load_shared("cornell-box"))._local)
    with pytest.raises(ValueError, match="occlusion queries only"):
        scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="INTERSECT")


@pytest.mark.parametrize("name", ["cornell-box-sphere", "veach-ajar", "modern-hall"])
def test_closest_hits_are_embreex_robust_hits(name):
    """The Geometry's closest hits through the packets (float64 rays rounded in the kernel)
    equal embreex's robust scene's on the same rays: triangle, barycentrics, distance; misses
    with u = v = 0 and t = tfar; short rays (tmax) stop early alike."""
    geom = Geometry(load_shared(name))
    assert isinstance(geom._packets, PacketScene)
    g = np.random.default_rng(9)
    n = 20011
    o = geom.center + (g.random((n, 3)) - 0.5) * geom.extent
    d = g.normal(size=(n, 3))
    d[7] = np.nan
    tmax = np.where(g.random(n) < 0.3, g.random(n) * geom.diagonal * 0.2, 3.0e38).astype(np.float32)
    for t in (None, tmax):
        valid, prim, u, v, tt = geom._packets.closest(o, d, t, geom.center)
        o32, d32 = (o - geom.center).astype(np.float32), d.astype(np.float32)
        r = geom._embree.run(o32, d32, output=1) if t is None else geom._embree.run(o32, d32, dists=t.copy(), output=1)
        want_valid = (r["geomID"] != -1) & (r["primID"] >= 0)
        np.testing.assert_array_equal(valid, want_valid)
        np.testing.assert_array_equal(prim, np.where(want_valid, r["primID"], -1))
        for got, key in ((u, "u"), (v, "v"), (tt, "tfar")):
            np.testing.assert_array_equal(got, r[key].astype(np.float64), err_msg=key)
        assert 0.1 < valid.mean() < 1.0


def test_embreex_closest_hit_scene_is_built_only_when_asked_for():
    """With the packet scenes at hand the triangles sit in one closest-hit BVH: embreex's
    robust scene is built only for a benchmark replay (or where the packets are missing)."""
    geom = Geometry(load_shared("cornell-box"))
    g = np.random.default_rng(3)
    o, d, t = _rays(g, geom, 500)
    geom.record = []
    hits = geom.intersect(o.astype(np.float64) + geom.center, d.astype(np.float64))
    assert geom._embree_scene is None
    assert geom.replay(geom.record) >= 0 and geom._embree_scene is not None
    r = geom._embree.run(o, d, output=1)
    np.testing.assert_array_equal(hits.prim, np.where((r["geomID"] != -1) & (r["primID"] >= 0), r["primID"], -1))


@pytest.mark.parametrize("features, lanes", [({"avx512f": True, "avx": True}, 16), ({"avx512f": False, "avx": True}, 8),
                                             ({"avx": False}, 4), ({}, 4)])
def test_packets_take_the_width_embree_runs_natively_on_the_cpu(monkeypatch, features, lanes):
    """16 lanes only where Embree has its AVX-512 kernels: a wider packet than the CPU's is
    split inside Embree (1.6x the time on an AVX2 EPYC); the module's width is this CPU's."""
    import llvmlite.binding as llb

    host = llb.get_host_cpu_features()
    assert kernels.LANES == (16 if host.get("avx512f", False) else 8 if host.get("avx", False) else 4)
    monkeypatch.setattr(llb, "get_host_cpu_features", lambda: features)
    assert kernels.native_lanes() == lanes
