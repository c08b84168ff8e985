"""common.geometry.Geometry: shadow rays (occlusion queries, on their own BVH without Embree's
robust mode) decide what the closest-hit queries decide, and the benchmark hooks see both."""
from __future__ import annotations

import numpy as np

from igi.common import bundled
from igi.common.geometry import Geometry
from igi.common.loader import load_scene


def _segments(geom: Geometry, n: int, seed: int):
    """Segments between random points on the scene's triangles, offset off their surfaces."""
    rng = np.random.default_rng(seed)
    tri = rng.integers(0, len(geom.faces), (2, n))
    a, na, _ = geom.sample_triangles(tri[0], rng.random((n, 2)))
    b, nb, _ = geom.sample_triangles(tri[1], rng.random((n, 2)))
    oa = geom.offset(a, na, b - a)
    ob = geom.offset(b, nb, a - b)
    seg = ob - oa
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-3 * geom.diagonal
    return oa[keep], seg[keep] / length[keep, None], length[keep]


def test_a_segment_is_occluded_exactly_where_the_closest_hit_lies_before_its_end():
    scene = load_scene(bundled.resolve("cornell-box"))
    geom = Geometry(scene)
    o, d, length = _segments(geom, 200_000, 1)
    blocked = geom.occluded(o, d, length)
    t = geom.intersect(o, d).t
    hit_before = t < length
    clear = np.abs(t - length) > 1e-4 * geom.diagonal  # not a tie at the segment's end
    assert 0.2 < blocked.mean() < 0.8  # the box's spheres and blocks hide many pairs
    wrong = (blocked != hit_before) & clear
    assert wrong.sum() <= 2e-5 * len(o), int(wrong.sum())  # an edge now and then, never a pattern
    # the centred float32 entry point agrees with the float64 one
    local = (o - geom.center).astype(np.float32)
    assert np.array_equal(geom.occluded_local(local, d.astype(np.float32), length.astype(np.float32)),
                          geom.occluded(o, d, length))


def test_the_embree_timer_and_replay_cover_both_bvhs():
    scene = load_scene(bundled.resolve("cornell-box"))
    geom = Geometry(scene)
    o, d, length = _segments(geom, 2000, 2)
    geom.record = []
    geom.time_embree(True)
    blocked = geom.occluded(o, d, length)
    hits = geom.intersect(o, d)
    geom.time_embree(False)
    assert geom.counters["occluded_seconds"] > 0 and geom.counters["intersect_seconds"] > 0
    assert [kind for kind, *_ in geom.record] == ["occluded", "intersect"]
    seen = []

    class Spy:  # which BVH the replay sends each batch to
        def __init__(self, scene, name):  # (no ``inner``: replay would unwrap it as the timer)
            self.scene, self.name = scene, name

        def run(self, *a, **k):
            seen.append((self.name, k.get("query", "INTERSECT")))
            return self.scene.run(*a, **k)

    geom._embree, geom._shadow = Spy(geom._embree, "robust"), Spy(geom._shadow, "shadow")
    assert geom.replay(geom.record) > 0
    assert seen == [("shadow", "OCCLUDED"), ("robust", "INTERSECT")]
    geom._embree, geom._shadow = geom._embree.scene, geom._shadow.scene
    assert np.array_equal(geom.occluded(o, d, length), blocked)  # the timer changed nothing
    assert np.array_equal(geom.intersect(o, d).prim, hits.prim)


def test_compiled_triangle_sampling_equals_the_numpy_form():
    """Geometry.sample_triangles (common.kernels.triangle_sampling) gives the numpy form's
    positions, normals (interpolated vertex normals on smooth meshes, the face normal else) and
    uvs bit for bit, on scenes with smooth spheres and textured meshes, at the square's corners
    and edges too."""
    from tests.support import oracle_geometry
    from tests.support.paths import SHARED

    for path in (bundled.resolve("cornell-box"), SHARED / "scenes/cornell-box-sphere/scene.xml",
                 SHARED / "scenes/modern-hall/scene.xml"):
        geom = Geometry(load_scene(str(path)))
        rng = np.random.default_rng(3)
        n = 20_000
        tri = rng.integers(0, len(geom.faces), n)
        u = rng.random((n, 2))
        u[:8] = [[0, 0], [1, 1], [0, 1], [1, 0], [0.5, 0], [0, 0.5], [1, 0.5], [0.5, 1]]
        got = geom.sample_triangles(tri, u)
        want = oracle_geometry.sample_triangles(geom, tri, u)
        for a, b in zip(got, want):
            assert a.shape == b.shape and np.array_equal(a, b)
        assert geom.smooth[tri].any() or path == bundled.resolve("cornell-box")
