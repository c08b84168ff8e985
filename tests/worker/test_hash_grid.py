import numpy as np
import pytest
from scipy.spatial import cKDTree

from igi.worker.hash_grid import HashGrid


def _pairs(pidx, qidx):
    return set(zip(qidx.tolist(), pidx.tolist()))


def _kdtree_pairs(points, queries, r):
    res = cKDTree(points).query_ball_point(queries, r)
    return {(q, int(p)) for q, ps in enumerate(res) for p in ps}


def _brute_pairs(points, queries, r):
    d = points[None, :, :] - queries[:, None, :]
    q, p = np.nonzero(np.einsum("qpk,qpk->qp", d, d) <= r * r)
    return set(zip(q.tolist(), p.tolist()))


def _check(points, queries, r):
    pidx, qidx = HashGrid(points, r).query(queries)
    got = _pairs(pidx, qidx)
    assert len(got) == len(pidx), "a photon was reported twice for one query"
    assert got == _kdtree_pairs(points, queries, r)
    return got


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_neighbours_equal_kdtree_for_random_points(seed):
    rng = np.random.default_rng(seed)
    pts = rng.random((3000, 3))
    qs = rng.random((2000, 3))
    got = _check(pts, qs, 0.04)
    assert len(got) > 500  # the test exercised real neighbourhoods


def test_neighbours_equal_kdtree_for_clustered_points():
    rng = np.random.default_rng(3)
    centres = rng.random((10, 3))
    pts = (centres[rng.integers(0, 10, 4000)] + rng.normal(0, 0.01, (4000, 3)))
    qs = centres[rng.integers(0, 10, 500)] + rng.normal(0, 0.02, (500, 3))
    _check(pts, qs, 0.015)


def test_points_exactly_on_cell_borders():
    r = 0.25  # exact in binary: lattice coordinates, r and r^2 carry no rounding
    g = np.arange(-4, 5) * (r / 2)  # multiples of r/2: cell borders (2r), centres and between
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pidx, qidx = HashGrid(lattice, r).query(lattice)
    got = _pairs(pidx, qidx)
    # Photons at distance exactly r count (<= r), as in cKDTree.
    assert got == _brute_pairs(lattice, lattice, r)
    assert got == _kdtree_pairs(lattice, lattice, r)
    d = lattice[pidx] - lattice[qidx]
    assert np.any(np.isclose(np.einsum("ij,ij->i", d, d), r * r))


def test_balls_touching_cell_borders_with_non_dyadic_radius():
    # Photons on or half-way between cell borders, queries exactly r away along one axis:
    # rounding of x/(2r) decides the cells here. A plain floor(x/(2r) - 0.5) lower corner
    # loses some of these photons (about 1 in 10^4 for r = 0.013); the grid must lose none.
    r = 0.013
    rng = np.random.default_rng(4)
    n = 200_000
    pts = rng.integers(-1000, 1000, (n, 3)) * (2 * r) + rng.choice([0, r, -r, 2 * r], (n, 3))
    step = np.zeros((n, 3))
    step[np.arange(n), rng.integers(0, 3, n)] = rng.choice([-r, r], n)
    qs = pts + step
    d = pts - qs
    own = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= r * r)
    assert len(own) > n // 2
    pidx, qidx = HashGrid(pts, r).query(qs)
    found = _pairs(pidx, qidx)
    assert all((int(i), int(i)) in found for i in own)
    assert found == _kdtree_pairs(pts, qs, r)


@pytest.mark.parametrize("offset", [-1e7, -3.3e6, 1e6, 1e7])
def test_negative_and_huge_coordinates(offset):
    rng = np.random.default_rng(5)
    pts = offset + rng.random((2000, 3)) * 2.0
    qs = offset + rng.random((1000, 3)) * 2.0
    got = _check(pts, qs, 0.05)
    assert len(got) > 100


def test_mixed_signs_and_spread_over_huge_extent():
    # A box of 2e7 per axis with r = 1e-3 holds 1e30 cells: the packed key must not collide.
    rng = np.random.default_rng(6)
    anchors = rng.uniform(-1e7, 1e7, (50, 3))
    pts = anchors[rng.integers(0, 50, 3000)] + rng.random((3000, 3)) * 0.01
    qs = anchors[rng.integers(0, 50, 1000)] + rng.random((1000, 3)) * 0.01
    got = _check(pts, qs, 1e-3)
    assert len(got) > 50


@pytest.mark.parametrize("r", [1e-9, 1e-4, 3.0, 1e6])
def test_tiny_and_huge_radius(r):
    rng = np.random.default_rng(7)
    pts = rng.random((500, 3))
    qs = np.concatenate([rng.random((300, 3)), pts[:50] + r * 0.5 * rng.random((50, 3))])
    got = _check(pts, qs, r)
    if r >= 3.0:
        # every photon is within reach of every query of the unit cube
        assert sum(q < 300 for q, _ in got) == 500 * 300
    if r <= 1e-4:
        assert len(got) >= 50  # the near copies were found


def test_empty_grid_returns_nothing():
    g = HashGrid(np.empty((0, 3)), 0.1)
    pidx, qidx = g.query(np.random.default_rng(0).random((10, 3)))
    assert len(pidx) == 0 and len(qidx) == 0
    assert pidx.dtype == np.int64
    e = g.gather(np.zeros((4, 3)), None, np.empty((0, 3)))
    assert e.shape == (4, 3) and np.all(e == 0)


def test_no_queries_and_non_finite_queries_find_nothing():
    pts = np.random.default_rng(0).random((100, 3))
    g = HashGrid(pts, 0.1)
    assert len(g.query(np.empty((0, 3)))[0]) == 0
    q = np.array([[np.inf, 0.5, 0.5], [np.nan, 0, 0], [1e300, 0, 0], [-1e300, 1e300, 0]])
    assert len(g.query(q)[0]) == 0


def test_pairs_are_grouped_by_query():
    rng = np.random.default_rng(8)
    pidx, qidx = HashGrid(rng.random((1000, 3)), 0.1).query(rng.random((200, 3)))
    assert np.all(np.diff(qidx) >= 0)


def test_invalid_radius_and_points_raise():
    with pytest.raises(ValueError):
        HashGrid(np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError):
        HashGrid(np.zeros((3, 3)), np.nan)
    with pytest.raises(ValueError):
        HashGrid(np.array([[0.0, np.inf, 0.0]]), 0.1)


def test_gather_constant_kernel_is_power_over_disc_area():
    rng = np.random.default_rng(9)
    r = 0.05
    pts = rng.random((2000, 3))
    power = rng.random((2000, 3))
    qs = rng.random((100, 3))
    got = HashGrid(pts, r).gather(qs, None, power)
    ref = np.zeros((100, 3))
    for q, ps in enumerate(cKDTree(pts).query_ball_point(qs, r)):
        ref[q] = power[ps].sum(0) / (np.pi * r * r)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kernel", ["constant", "cone", "epanechnikov"])
def test_gather_kernels_are_normalized(kernel):
    # Photons of a uniform flux density on a plane: every normalized kernel estimates it.
    rng = np.random.default_rng(10)
    n = 400_000
    pts = np.column_stack([rng.random(n), rng.random(n), np.zeros(n)])
    power = np.full(n, 1.0 / n)  # total power 1 on the unit square: irradiance 1
    qs = np.column_stack([0.3 + 0.4 * rng.random(50), 0.3 + 0.4 * rng.random(50), np.zeros(50)])
    e = HashGrid(pts, 0.05).gather(qs, None, power, kernel=kernel)
    assert e.shape == (50,)
    assert abs(e.mean() - 1.0) < 0.02


def test_gather_same_side_tests():
    r = 0.1
    pts = np.array([[0, 0, 0.01], [0, 0, -0.01], [0.02, 0, 0]])
    power = np.array([1.0, 10.0, 100.0])
    pn = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0]])  # a thin wall: two sides
    pdir = np.array([[0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0]])  # the third arrived from below
    q = np.zeros((1, 3))
    qn = np.array([[0, 0, 1.0]])
    g = HashGrid(pts, r)
    area = np.pi * r * r
    assert g.gather(q, qn, power)[0] * area == pytest.approx(111.0)
    assert g.gather(q, qn, power, photon_normals=pn)[0] * area == pytest.approx(101.0)
    assert g.gather(q, qn, power, photon_dirs=pdir)[0] * area == pytest.approx(1.0)
    with pytest.raises(ValueError):
        g.gather(q, None, power, photon_normals=pn)
    with pytest.raises(ValueError):
        g.gather(q, qn, power, kernel="gauss")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_query_equals_numpy_query_pair_for_pair(seed):
    """The compiled query returns exactly the numpy implementation's pairs, in its order,
    including balls on cell borders and non-finite queries."""
    g = np.random.default_rng(seed)
    r = 0.25
    pts = np.concatenate([g.random((400, 3)) * 4 - 2, np.round(g.random((100, 3)) * 16) * (r / 2)])
    grid = HashGrid(pts, r)
    q = np.concatenate([g.random((300, 3)) * 5 - 2.5, pts[:50] + r * np.array([1.0, 0, 0]),
                        np.array([[np.nan, 0, 0], [np.inf, 1, 1], [1e300, 0, 0]])])
    got = grid.query(q)
    want = grid._query_numpy(q)
    assert len(want[0]) > 0
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_occupancy_bitmap_skips_only_cells_without_photons():
    """The query with the grid's occupancy bitmap finds exactly what it finds without it."""
    g = np.random.default_rng(11)
    pts = np.concatenate([g.normal(0.5, 0.05, (300, 3)), g.random((50, 3))])
    grid = HashGrid(pts, 0.02)
    assert len(grid._occupied) > 0  # a small key space keeps a bitmap
    qs = g.random((4000, 3))
    qs[:300] = pts[:300] + g.normal(0, 0.01, (300, 3))  # many queries near photons
    with_bits = _pairs(*grid.query(qs))
    assert len(with_bits) > 100
    grid._occupied = np.empty(0, np.uint8)
    assert _pairs(*grid.query(qs)) == with_bits == _kdtree_pairs(pts, qs, 0.02)


def _numpy_built(points, r) -> HashGrid:
    g = HashGrid(np.zeros((0, 3)), r)  # then the numpy build over the same points
    g.points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    g._build_numpy(g.points)
    return g


@pytest.mark.parametrize("case", ["uniform", "clustered", "lattice", "one photon", "one cell", "negative",
                                  "duplicates", "wide box"])
def test_compiled_build_equals_the_numpy_build(case):
    """The compiled build (worker.kernels.hash_grid_build) gives the numpy build's grid: key
    space, stable photon order, cell ranges and occupancy bitmap, bit for bit."""
    rng = np.random.default_rng(7)
    r = 0.05
    pts = {"uniform": rng.random((700, 3)),
           "clustered": rng.normal(0, 0.02, (500, 3)) + rng.random((5, 3))[rng.integers(0, 5, 500)],
           "lattice": np.stack(np.meshgrid(*(np.arange(-3, 4) * r,) * 3, indexing="ij"), -1).reshape(-1, 3),
           "one photon": np.array([[0.3, -0.2, 7.0]]),
           "one cell": np.full((9, 3), 0.01),
           "negative": -rng.random((300, 3)) * 40,
           "duplicates": np.repeat(rng.random((20, 3)), 6, axis=0),
           "wide box": rng.random((200, 3)) * 2e3}[case]
    got, want = HashGrid(pts, r), _numpy_built(pts, r)
    assert got._axes is None and want._axes is None
    for name in ("_origin", "_ext", "_order", "_keys", "_starts", "_counts", "_occupied"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    q = rng.random((50, 3)) if case != "negative" else -rng.random((50, 3)) * 40
    for a, b in zip(got.query(q), want.query(q)):
        assert np.array_equal(a, b)


def test_compiled_build_refuses_non_finite_and_overflowing_photons():
    with pytest.raises(ValueError, match="finite"):
        HashGrid(np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]), 0.1)
    with pytest.raises(ValueError, match="finite"):
        HashGrid(np.array([[np.inf, 0.0, 0.0]]), 0.1)
    with pytest.raises(ValueError, match="overflow"):
        HashGrid(np.array([[0.0, 0.0, 0.0], [1e300, 0.0, 0.0]]), 0.1)


def test_huge_key_space_is_ranked_by_the_numpy_build():
    """Photons so far apart for the radius that the box has >= 2^62 cells: the compiled build
    hands over to the rank-mapped numpy build, and queries still find every neighbour."""
    pts = np.array([[0.0, 0.0, 0.0], [1e15, 1e15, 1e15], [1e15 + 1e-4, 1e15, 1e15], [-3e14, 2e14, 5.0]])
    g = HashGrid(pts, 1e-3)
    assert g._axes is not None
    pidx, qidx = g.query(pts)
    assert _pairs(pidx, qidx) == _brute_pairs(pts, pts, 1e-3)
