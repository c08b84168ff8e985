import os
import subprocess
import sys

import numpy as np
import pytest

from igi.common.sobol_stream import SobolStream, rng

from tests.support.paths import ROOT as REPO


_CHILD = """
import sys
from igi.common.sobol_stream import SobolStream, rng
s = SobolStream(int(sys.argv[1]), dims=12)
sys.stdout.buffer.write(s.block(3, 100, 128).tobytes())
sys.stdout.buffer.write(s.padded(2, 64, 64, 11).tobytes())
sys.stdout.buffer.write(rng(int(sys.argv[1]), "photons", 5).random(8).tobytes())
"""


def _child_bytes(seed: int) -> bytes:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               PYTHONHASHSEED=str(seed + 17))  # a different hash seed must not matter
    out = subprocess.run([sys.executable, "-c", _CHILD, str(seed)], cwd=REPO, env=env,
                         capture_output=True, check=True)
    return out.stdout


def test_same_seed_is_bitwise_identical_in_separate_processes():
    a, b = _child_bytes(1234), _child_bytes(1234)
    assert len(a) == (100 * 12 + 64 * 11 + 8) * 8
    assert a == b
    s = SobolStream(1234, dims=12)
    here = (s.block(3, 100, 128).tobytes() + s.padded(2, 64, 64, 11).tobytes()
            + rng(1234, "photons", 5).random(8).tobytes())
    assert here == a


def test_block_k_equals_rows_of_one_long_draw():
    s = SobolStream(7, dims=5)
    long = SobolStream(7, dims=5).points(0, 10 * 64)
    for k in (0, 1, 4, 9):
        for count in (1, 17, 64):
            np.testing.assert_array_equal(s.block(k, count, 64), long[k * 64:k * 64 + count])


def test_blocks_in_any_call_order_are_the_same():
    s = SobolStream(3)
    first = [s.block(k, 32, 32) for k in range(4)]
    again = [s.block(k, 32, 32) for k in (3, 1, 0, 2)]
    for k, a in zip((3, 1, 0, 2), again):
        np.testing.assert_array_equal(a, first[k])


def test_different_seeds_give_different_points():
    a = SobolStream(1).block(0, 64, 64)
    b = SobolStream(2).block(0, 64, 64)
    assert not np.any(a == b)
    pa = SobolStream(1).padded(0, 64, 64, 12)
    pb = SobolStream(2).padded(0, 64, 64, 12)
    assert not np.array_equal(pa, pb)


def test_points_lie_in_half_open_unit_cube():
    s = SobolStream(99, dims=32)
    p = s.block(5, 4096, 4096)
    assert p.shape == (4096, 32) and p.dtype == np.float64
    assert p.min() >= 0.0 and p.max() < 1.0
    q = s.padded(5, 1000, 4096, 37)
    assert q.shape == (1000, 37)
    assert q.min() >= 0.0 and q.max() < 1.0


@pytest.mark.parametrize("m", [4, 7])
def test_block_one_dimensional_projections_are_stratified(m):
    B = 2 ** m
    s = SobolStream(11, dims=8)
    for k in (0, 3):
        cells = np.floor(s.block(k, B, B) * B).astype(int)
        for j in range(8):
            assert np.array_equal(np.sort(cells[:, j]), np.arange(B))


@pytest.mark.parametrize("m", [3, 6])
def test_padded_blocks_have_every_group_projection_stratified(m):
    B = 2 ** m
    total = 4 * 5 + 2  # a short last group too
    s = SobolStream(21)
    for k in (0, 1, 5):
        p = s.padded(k, B, B, total)
        cells = np.floor(p * B).astype(int)
        for j in range(total):
            assert np.array_equal(np.sort(cells[:, j]), np.arange(B)), (k, j)
        # 2-D projections inside a group are (0, m, 2)-nets of Sobol': every 2^a x 2^(m-a)
        # elementary box holds exactly one point (checked for the square-ish split).
        a = m // 2
        for g0 in range(0, total - 1, 4):
            bx = np.floor(p[:, g0] * 2 ** a).astype(int)
            by = np.floor(p[:, g0 + 1] * 2 ** (m - a)).astype(int)
            assert len(set(zip(bx.tolist(), by.tolist()))) == B


def test_padded_groups_are_independent_instances_paired_at_random():
    s = SobolStream(5)
    p = s.padded(0, 256, 256, 8)
    # Same Sobol' generator matrices in every group: without scrambling + shuffling the
    # groups would be copies of each other. Their correlation must look like chance.
    for j in range(4):
        r = np.corrcoef(p[:, j], p[:, 4 + j])[0, 1]
        assert abs(r) < 0.25
        assert not np.allclose(np.sort(p[:, j]), np.sort(p[:, 4 + j]))


def test_padded_first_group_is_a_plain_prefix_and_blocks_differ():
    s = SobolStream(8)
    p0 = s.padded(0, 64, 64, 8)
    p1 = s.padded(1, 64, 64, 8)
    assert not np.any(p0[:, 0] == p1[:, 0])
    # The first group keeps sequence order: a prefix of a block is a prefix of the group.
    np.testing.assert_array_equal(s.padded(1, 16, 64, 4), p1[:16, :4])


def test_blocks_past_one_instance_continue_in_a_fresh_scrambling():
    # 2^30 points per instance: block k of size 2^28 wraps to row 0 every 4 blocks, in a new
    # scrambling (never the silently repeated points a 30-bit engine would give).
    from igi.common.sobol_stream import POINTS

    s = SobolStream(3)
    size = POINTS // 4
    first = s.block(0, 16, size)
    lapped = s.block(4, 16, size)
    assert not np.array_equal(first, lapped)
    np.testing.assert_array_equal(s.block(3, 16, size), s.points(3 * size, 16))  # the last of lap 0
    assert np.array_equal(np.sort(np.floor(lapped[:, 0] * 16)), np.arange(16))  # still a Sobol prefix
    pf, pl = s.padded(0, 16, size, 6), s.padded(4, 16, size, 6)
    assert not np.array_equal(pf, pl)
    with pytest.raises(ValueError):
        s.points(POINTS - 4, 8)


def test_rng_is_deterministic_and_keys_are_independent():
    a = rng(5, "vpl", 3).random(16)
    np.testing.assert_array_equal(a, rng(5, "vpl", 3).random(16))
    for other in (rng(5, "vpl", 4), rng(5, "photons", 3), rng(6, "vpl", 3), rng(5, 3, "vpl")):
        assert not np.array_equal(a, other.random(16))


def test_invalid_block_arguments_raise():
    s = SobolStream(0)
    with pytest.raises(ValueError):
        s.block(0, 65, 64)
    with pytest.raises(ValueError):
        s.block(-1, 4, 64)
    with pytest.raises(ValueError):
        rng(1, -3)


@pytest.mark.parametrize("start", [0, 1, 2, 3, 4, 5, 63, 64, 65, 4096, 4097, 123457, 475136])
def test_direct_evaluation_draws_what_scipys_engine_draws(start):
    """Points are evaluated directly from the scrambled direction numbers (any block in O(bits),
    no engine state); they must be exactly what scipy's engine draws after fast_forward."""
    import warnings

    from scipy.stats import qmc

    from igi.common import sobol_stream as ss

    assert ss._direct_works()
    a = ss._draw(ss._scrambling(7, 99, 4), start, 33)
    e = qmc.Sobol(7, scramble=True, seed=rng(99, 4))
    if start:  # scipy's fast_forward(0) raises
        e.fast_forward(start)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        b = e.random(33)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("k,count,total_dims,group_dims", [(0, 500, 29, 4), (3, 240, 14, 4), (7, 5, 5, 4),
                                                          (2, 1, 3, 4), (4, 0, 9, 4), (1, 100, 8, 3)])
def test_padded_in_one_call_equals_scipys_engines_group_by_group(k, count, total_dims, group_dims):
    """padded() draws every group in one compiled call (sobol_points.draw_padded): the same
    values as each group's own scipy engine over the block's rows, shuffled by the block's
    successive permutations (the engine path it replaced, kept as the fallback)."""
    from igi.common import sobol_stream as ss

    s = SobolStream(4242)
    got = s.padded(k, count, 512, total_dims, group_dims)
    shuffle = rng(4242, ss._TAG_PERM, k, count)
    for g, d0 in enumerate(range(0, total_dims, group_dims)):
        d = min(group_dims, total_dims - d0)
        want = ss._engine_draw(ss._scrambling(d, 4242, ss._TAG_GROUP, g).engine, k * 512, count)
        if g:
            want = want[shuffle.permutation(count)]
        np.testing.assert_array_equal(got[:, d0:d0 + d], want)


def test_threads_drawing_from_one_stream_get_the_serial_points():
    """One stream shared by threads (a worker's render threads) draws what a serial caller does."""
    from concurrent.futures import ThreadPoolExecutor

    s = SobolStream(4242, dims=9)
    want = {k: (s.block(k, 50, 64), s.padded(k, 50, 64, 13)) for k in range(24)}
    fresh = SobolStream(4242, dims=9)
    with ThreadPoolExecutor(4) as pool:
        got = dict(pool.map(lambda k: (k, (fresh.block(k, 50, 64), fresh.padded(k, 50, 64, 13))),
                            list(range(24)) * 3))
    for k, (b, p) in want.items():
        np.testing.assert_array_equal(got[k][0], b)
        np.testing.assert_array_equal(got[k][1], p)
