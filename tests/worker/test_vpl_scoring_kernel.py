"""worker.kernels.vpl_scoring against the pair list it replaced (the gather's pair_weights, then
the numpy originals in tests/support/oracle_vpl_scoring.py) on real scenes' end points: glossy
rows, spot and point columns, several runs of rows, NaN/Inf end points, empty inputs; and
pair_luminance on random pairs with non-finite colours and factors."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common import bsdf
from igi.worker.kernels import vpl_scoring as vs
from tests.support import oracle_vpl_scoring as oracle


def _oracle_draws(geom, end, sl, vpls, cols, col_range, eye_weight, samples, column_u):
    """The scoring's draws the long way: pair_weights' live pairs (the gather's array path),
    their luminance (pair_luminance), a stable walk along each column (the numpy oracle) and
    np.unique's distinct pairs in first-drawn order."""
    from igi.worker import shading

    pi, pj, w, row, pl, _o, _d, _t, _inner = shading._pair_rays(geom, end, sl, vpls, cols, -1, col_range)
    plain = np.empty(len(pi))
    vs.pair_luminance(pi, pj, w, np.zeros(0, bool), np.zeros((0, 3)), cols.color, eye_weight, plain)
    draw, share = oracle.systematic_pairs_sorted(pj, plain, len(vpls), samples, column_u)
    first = np.sort(np.unique(draw, return_index=True)[1])
    u = draw[first]
    inv = np.searchsorted(first, np.arange(len(draw)), side="right") - 1
    return pi[u], pj[u], w[u], pl[u], plain[u], pj[draw], share, inv


def _runs(n: int, m: int):
    """Column ranges per row: a run of 300 rows (more than a staging block) on the first half
    of the columns, one on the rest, and rows with no columns."""
    lo, hi = np.zeros(n, np.int64), np.zeros(n, np.int64)
    a, b = min(300, n // 2), (3 * n) // 4
    lo[:a], hi[:a] = 0, m // 2
    lo[a:b], hi[a:b] = m // 2, m
    lo[b:], hi[b:] = m, m
    return lo, hi


@pytest.mark.parametrize("name,extra", [("cornell-box-sphere", False), ("cornell-box-glossy", False),
                                        ("cornell-box", True), ("veach-ajar", False)])
@pytest.mark.parametrize("samples", [1, 8, 32])
def test_scored_draws_equal_a_walk_along_each_columns_pair_list_bit_for_bit(name, extra, samples):
    """No pair list (each run's block weighed, summed and walked down its columns) draws the
    same pairs, in the same order, with the same shares and luminances, as the pair list: on
    glossy rows, spot and point columns, runs longer than a block, rows with no columns."""
    from igi.bench.stress_scenes import eye_end_points, load_shared, with_extra_lights
    from igi.worker import shading
    from igi.worker.renderer import Renderer
    from igi.worker.vpl import build_vpl_set

    scene = load_shared(name)
    r = Renderer(with_extra_lights(scene) if extra else scene)
    end = eye_end_points(r, 32, 24)
    vpls = build_vpl_set(r.scene, r.geom, r.lights, 0, 3, 8 if extra else 4, 40, 4)
    c2 = 1e-3 * r.geom.diagonal ** 2
    cols = shading.vpl_columns(vpls, r.geom, c2)
    m = len(vpls)
    col_range = _runs(len(end), m)
    albedo = bsdf.albedo(end.sp, end.wi).astype(np.float64)
    eye_weight = albedo * end.throughput
    column_u = np.random.default_rng(samples).random(m)
    sl = slice(0, len(end))
    got = shading._scored_draws(r.geom, end, sl, vpls, cols, -1, col_range, eye_weight, samples, column_u)
    want = _oracle_draws(r.geom, end, sl, vpls, cols, col_range, eye_weight, samples, column_u)
    assert len(want[5]) > samples * 10  # many columns drawn: not vacuous
    for g, w in zip(got[:8], want):
        assert g.dtype == w.dtype and np.array_equal(g, w)


def test_scored_draws_skip_nonfinite_end_points_and_take_no_rows():
    """NaN/Inf end points weigh nothing (never drawn), as in the pair list; no rows: no draws."""
    from igi.bench.stress_scenes import eye_end_points, load_shared, with_nonfinite_positions
    from igi.worker import shading
    from igi.worker.renderer import Renderer
    from igi.worker.vpl import build_vpl_set

    r = Renderer(load_shared("cornell-box"))
    end = with_nonfinite_positions(eye_end_points(r, 24, 24), 3, 5)
    vpls = build_vpl_set(r.scene, r.geom, r.lights, 0, 1, 4, 30, 4)
    cols = shading.vpl_columns(vpls, r.geom, 1e-3 * r.geom.diagonal ** 2)
    m = len(vpls)
    rng_range = (np.zeros(len(end), np.int64), np.full(len(end), m, np.int64))
    eye_weight = bsdf.albedo(end.sp, end.wi).astype(np.float64) * end.throughput
    u = np.random.default_rng(2).random(m)
    sl = slice(0, len(end))
    got = shading._scored_draws(r.geom, end, sl, vpls, cols, -1, rng_range, eye_weight, 16, u)
    want = _oracle_draws(r.geom, end, sl, vpls, cols, rng_range, eye_weight, 16, u)
    for g, w in zip(got[:8], want):
        assert np.array_equal(g, w)
    assert len(got[0]) and not np.any(np.isin(got[0], np.arange(0, len(end), 3)))
    none = shading._scored_draws(r.geom, end, slice(0, 0), vpls, cols, -1, rng_range, eye_weight, 16, u)
    assert all(len(a) == 0 for a in none[:8])


def test_scored_draws_refuse_a_column_in_two_runs():
    """Each run's columns are drawn once its block is summed: a column shared by two runs of
    rows would be drawn from part of its pairs, so it is refused."""
    from igi.bench.stress_scenes import eye_end_points, load_shared
    from igi.worker import shading
    from igi.worker.renderer import Renderer
    from igi.worker.vpl import build_vpl_set

    r = Renderer(load_shared("cornell-box"))
    end = eye_end_points(r, 8, 8)
    vpls = build_vpl_set(r.scene, r.geom, r.lights, 0, 1, 4, 30, 4)
    cols = shading.vpl_columns(vpls, r.geom, 1e-3 * r.geom.diagonal ** 2)
    m = len(vpls)
    lo, hi = np.zeros(len(end), np.int64), np.full(len(end), m, np.int64)
    hi[10:] = m // 2  # rows 10… take a part of the first run's columns
    eye_weight = np.ones((len(end), 3))
    with pytest.raises(ValueError, match="two runs"):
        shading._scored_draws(r.geom, end, slice(0, len(end)), vpls, cols, -1, (lo, hi), eye_weight, 4,
                              np.full(m, 0.5))


def test_pair_luminance_matches_numpy_and_zeroes_non_finite_pairs():
    g = np.random.default_rng(9)
    n, m, e = 2000, 50, 300
    pi, pj = g.integers(0, e, n), g.integers(0, m, n)
    w = g.random(n).astype(np.float32)
    color = g.random((m, 3)) * 10
    eye = g.random((e, 3))
    color[3] = np.nan
    color[4, 1] = np.inf
    eye[5] = -1.0  # negative light: clipped to 0
    none_blocked, no_factor = np.zeros(0, bool), np.zeros((0, 3))
    out = np.empty(n)
    vs.pair_luminance(pi, pj, w, none_blocked, no_factor, color, eye, out)
    np.testing.assert_allclose(out, oracle.pair_luminance(pi, pj, w, none_blocked, no_factor, color, eye), rtol=1e-12)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and out.max() > 0
    # with shadow rays' answers and per-pair BSDF factors (a NaN factor: 0)
    blocked = g.random(n) < 0.3
    factor = g.random((n, 3)) * 2
    factor[7] = np.nan
    got = np.empty(n)
    vs.pair_luminance(pi, pj, w, blocked, factor, color, eye, got)
    np.testing.assert_allclose(got, oracle.pair_luminance(pi, pj, w, blocked, factor, color, eye), rtol=1e-12)
    assert np.all(got[blocked] == 0) and got[~blocked].max() > 0 and got[7] == 0
    vs.pair_luminance(pi[:0], pj[:0], w[:0], none_blocked, no_factor, color, eye, out[:0])  # empty: no error


@pytest.mark.parametrize("seed", range(8))
def test_acceptance_solves_for_tau_bit_for_bit_as_numpy(seed):
    """The compiled solve for τ (one sort, a running sum, a scan) gives the numpy form's
    probabilities bit for bit: heavy-tailed scores, ties, zeros, a few lit candidates."""
    g = np.random.default_rng(seed)
    n = int(g.integers(2, 400))
    phi = g.lognormal(0, 3, n) * (g.random(n) > 0.3)
    phi[: n // 10] = phi[0]  # ties
    if seed == 7:
        phi[:] = 0.0
        phi[:2] = 1.0  # fewer lit than the target: no τ
    phi[0] = max(phi[0], 1e-3)
    target = n / 8 if seed % 2 else n / 3
    for mix in (0.5, 1.0):
        floor = max(min(0.02, 0.5 * target / n), (1.0 - mix) * target / n)
        want = oracle.acceptance(phi, target, mix, floor)
        out = np.full(n, -1.0)
        found = vs.acceptance(phi, float(target), mix, floor, out)
        assert found == (want is not None)
        if found:
            assert np.array_equal(out, want)
            assert abs(out.sum() - target) < 1e-6 * n or out.max() == 1.0
