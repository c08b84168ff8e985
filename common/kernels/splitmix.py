"""SplitMix64 (Steele, Lea, Flood 2014): the finalizer that turns a 64-bit counter into
well-mixed bits, the counter-based numbers' one source (the gather's pair roulette, the
walks' and photons' bounces past their quasi-random ones, the sets' keys)."""
from __future__ import annotations

import numpy as np
from numba import njit

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, nogil=True, inline="always")
def mix64(z):
    """SplitMix64's finalizer of the uint64 ``z``."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True, inline="always")
def unit(z) -> float:
    """The top 53 bits of the uint64 ``z`` as a uniform in [0, 1)."""
    return np.float64(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


_L1 = np.uint32(0x7FEB352D)
_L2 = np.uint32(0x846CA68B)


@njit(cache=True, nogil=True, inline="always")
def mix32(z):
    """A 32-bit finalizer of the uint32 ``z`` (Wellons' "lowbias32", the 32-bit counterpart of
    :func:`mix64`): where a loop hashes per element, 32-bit lanes run twice as many at once as
    64-bit ones (AVX2 multiplies 8 uint32 in one instruction, 4 uint64 in three). Each step
    truncated to 32 bits: numba widens integer arithmetic to 64."""
    z = np.uint32(np.uint32(z ^ (z >> np.uint32(16))) * _L1)
    z = np.uint32(np.uint32(z ^ (z >> np.uint32(15))) * _L2)
    return np.uint32(z ^ (z >> np.uint32(16)))


@njit(cache=True, nogil=True, inline="always")
def unit32(z):
    """The top 24 bits of the uint32 ``z`` as a float32 uniform in [0, 1)."""
    return np.float32(np.uint32(z >> np.uint32(8))) * np.float32(1.0 / 16777216.0)
