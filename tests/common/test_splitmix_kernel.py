"""common.kernels.splitmix: the counter-based hashes and their uniforms."""
from __future__ import annotations

import numpy as np
from numba import njit

from igi.common.kernels import splitmix

_MASK = 0xFFFFFFFF


def _lowbias32(z: int) -> int:
    """Wellons' lowbias32 in Python integers, every step cut to 32 bits (the reference)."""
    z ^= z >> 16
    z = (z * 0x7FEB352D) & _MASK
    z ^= z >> 15
    z = (z * 0x846CA68B) & _MASK
    return z ^ (z >> 16)


@njit(cache=False)
def _many(z):
    """mix32 and unit32 of each uint32 of ``z`` (compiled, as the kernels call them)."""
    mixed = np.empty(z.shape[0], np.uint32)
    units = np.empty(z.shape[0], np.float32)
    for i in range(z.shape[0]):
        mixed[i] = splitmix.mix32(z[i])
        units[i] = splitmix.unit32(z[i])
    return mixed, units


def test_mix32_stays_in_32_bits_and_equals_the_reference():
    """numba widens integer arithmetic to 64 bits: the compiled mix32 must still cut every
    product to 32 (else its high bits leak into the shifts), equal to the Python reference on
    edge and random inputs."""
    g = np.random.default_rng(3)
    z = np.concatenate([np.array([0, 1, 2, 0x7FFFFFFF, 0x80000000, _MASK], np.uint32),
                        g.integers(0, 1 << 32, 2000, dtype=np.uint64).astype(np.uint32)])
    got = _many(z)[0]
    assert got.dtype == np.uint32
    np.testing.assert_array_equal(got, np.array([_lowbias32(int(v)) for v in z], np.uint32))


def test_unit32_lies_in_the_unit_interval_and_takes_the_top_24_bits():
    """unit32 maps 0 to 0 and the largest uint32 below 1 (24 bits: exact in float32)."""
    z = np.array([0, 255, 256, _MASK, 0x80000000], np.uint32)
    u = _many(z)[1]
    assert u.dtype == np.float32
    np.testing.assert_array_equal(u, np.array([0.0, 0.0, 2 ** -24, 1 - 2 ** -24, 0.5], np.float32))


def test_pair_uniforms_are_uniform_and_uncorrelated_between_neighbours():
    """The shadow roulette's draws (vpl_gather.pair_uniform: a row key, a column key, mix32):
    uniform over a 200 × 200 grid of pairs (every tenth of [0, 1) within 3% of its share) and
    uncorrelated between neighbouring rows and columns (|r| < 0.02), under two seeds."""
    from igi.worker.kernels import vpl_gather as vg

    for seed in (0, 123456789):
        u = np.array([[vg.pair_uniform(seed, i, j) for j in range(200)] for i in range(200)], np.float64)
        assert u.min() >= 0.0 and u.max() < 1.0
        share = np.bincount((u * 10).astype(np.int64).ravel(), minlength=10) / u.size
        assert np.all(np.abs(share - 0.1) < 0.003)
        for a, b in ((u[:, :-1], u[:, 1:]), (u[:-1], u[1:])):
            assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.02
