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
