"""worker.kernels.vpl_scoring against its numpy original (tests/support/oracle_vpl_scoring.py)
on random pair lists: empty columns, zero and non-finite weights, single-pair columns."""
from __future__ import annotations

import numpy as np
import pytest

from igi.worker.kernels import vpl_scoring as vs
from tests.support import oracle_vpl_scoring as oracle


def _draw(pj, weight, m: int, samples: int, u):
    """The kernel's draws and shares, trimmed to what it wrote."""
    draw = np.empty(m * samples, np.int64)
    share = np.empty(m * samples)
    n = vs.systematic_pairs(pj, weight, m, samples, u, draw, share)
    return draw[:n], share[:n]


def _pairs(seed: int, n_pairs: int, m: int):
    g = np.random.default_rng(seed)
    pj = np.sort(g.integers(0, m, n_pairs)) if seed % 2 else g.integers(0, m, n_pairs)
    weight = g.lognormal(0, 2, n_pairs) * (g.random(n_pairs) > 0.3)  # many zero weights
    return pj.astype(np.int64), weight, g.random(m)


@pytest.mark.parametrize("seed,n_pairs,m", [(0, 5000, 40), (1, 5000, 40), (2, 7, 30), (3, 1, 1), (4, 0, 5)])
def test_systematic_pairs_draw_what_the_numpy_original_draws(seed, n_pairs, m):
    pj, weight, u = _pairs(seed, n_pairs, m)
    draw, share = _draw(pj, weight, m, 8, u)
    n = len(draw)
    want_draw, want_share = oracle.systematic_pairs(pj, weight, m, 8, u)
    assert n == len(want_draw)
    # the numpy original cumulates across columns: a draw landing on a boundary within
    # rounding may pick the neighbouring pair; the pairs' weights must then agree
    same = draw[:n] == want_draw
    assert n == 0 or same.mean() > 0.999 or n < 1000 and same.all()
    np.testing.assert_allclose(share[:n], want_share, rtol=1e-12)
    assert np.all(pj[draw[:n]] == pj[want_draw])  # every draw stays in its column
    assert np.all(weight[draw[:n]] > 0)  # never a pair that carries nothing


@pytest.mark.parametrize("seed,n_pairs,m", [(0, 5000, 40), (1, 5000, 40), (2, 7, 30), (3, 1, 1), (4, 0, 5),
                                             (6, 3000, 200)])
def test_systematic_pairs_draw_bit_for_bit_what_a_walk_along_each_sorted_column_draws(seed, n_pairs, m):
    """Two passes in pair order draw exactly the pairs, in the same order, that a stable sort
    by column and a walk along each column draw (the same running sums in the same order)."""
    pj, weight, u = _pairs(seed, n_pairs, m)
    if n_pairs > 10:
        weight[::97] = np.nan  # a column with a non-finite weight draws nothing
        weight[1::89] = 0.0
    draw, share = _draw(pj, weight, m, 8, u)
    want_draw, want_share = oracle.systematic_pairs_sorted(pj, weight, m, 8, u)
    assert np.array_equal(draw, want_draw) and np.array_equal(share, want_share)


def test_unique_runs_equal_numpys_unique_on_draws():
    pj, weight, u = _pairs(1, 4000, 60)
    d, _ = _draw(pj, weight, 60, 16, u)
    n = len(d)
    uniq = np.empty(n, np.int64)
    inv = np.empty(n, np.int64)
    k = vs.unique_runs(d, uniq, inv)
    assert k < n  # heavy pairs drawn more than once
    assert np.array_equal(np.sort(uniq[:k]), np.unique(d)) and np.array_equal(uniq[:k][inv], d)
    assert vs.unique_runs(np.zeros(0, np.int64), uniq, inv) == 0


def test_systematic_pairs_estimate_each_columns_sum_without_bias():
    """Σ over a column's draws of share · g/weight estimates Σ g over its pairs that carry
    weight, for g = weight × a visibility in [0, 1] (the scoring's shadowed light from a few
    shadow rays per VPL)."""
    pj, weight, _ = _pairs(5, 3000, 12)
    g = weight * (np.random.default_rng(6).random(len(pj)) > 0.4)
    want = np.bincount(pj, weights=np.where(weight > 0, g, 0.0), minlength=12)
    est = np.zeros(12)
    trials = 2000
    for t in range(trials):
        u = np.random.default_rng(100 + t).random(12)
        draw = np.empty(12 * 4, np.int64)
        share = np.empty(12 * 4)
        n = vs.systematic_pairs(pj, weight, 12, 4, u, draw, share)
        d = draw[:n]
        np.add.at(est, pj[d], share[:n] * g[d] / weight[d])
    np.testing.assert_allclose(est / trials, want, rtol=0.03)


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
