"""numpy's ``SeedSequence`` hash (O'Neill's seed_seq design, numpy.random.bit_generator) in one
compiled call: the state words a ``SeedSequence(entropy, spawn_key=keys)`` would hand a bit
generator, bit for bit.

common.sobol_stream.rng builds ~150 seeded generators a frame (a tile's, each set's camera pool,
acceptance and visibility draws, each padded block's shuffle); numpy's own SeedSequence costs
~11 µs to build and ~4 µs more to hash into PCG64's state, cache-cold in a task ~50-130 µs a
generator: 3% of a 320×240 frame. Here the same words cost ~1 µs.
"""
from __future__ import annotations

import numpy as np
from numba import njit

POOL_SIZE = 4  # numpy's DEFAULT_POOL_SIZE (uint32 words)
_INIT_A = np.uint32(0x43B0D7E5)
_MULT_A = np.uint32(0x931E8875)
_INIT_B = np.uint32(0x8B51F9DD)
_MULT_B = np.uint32(0x58F38DED)
_MIX_MULT_L = np.uint32(0xCA01F9DD)
_MIX_MULT_R = np.uint32(0x4973F715)
_XSHIFT = np.uint32(16)


@njit(cache=True, nogil=True, inline="always")
def _hashmix(value, h):
    """(hashed value, next hash constant): numpy's ``hashmix`` (each step kept to 32 bits:
    numba widens integer arithmetic)."""
    value = np.uint32(value ^ h)
    h = np.uint32(h * _MULT_A)
    value = np.uint32(value * h)
    return np.uint32(value ^ (value >> _XSHIFT)), h


@njit(cache=True, nogil=True, inline="always")
def _mix(x, y):
    r = np.uint32(np.uint32(_MIX_MULT_L * x) - np.uint32(_MIX_MULT_R * y))
    return np.uint32(r ^ (r >> _XSHIFT))


@njit(cache=True, nogil=True)
def state_words(entropy, out) -> None:
    """``out`` (uint32) = ``SeedSequence`` of the assembled ``entropy`` words (uint32: the run
    entropy's words, padded with zeros to POOL_SIZE where spawn-key words follow, then those)
    ``.generate_state(len(out), np.uint32)``."""
    n = entropy.shape[0]
    pool = np.empty(POOL_SIZE, np.uint32)
    h = _INIT_A
    for i in range(POOL_SIZE):
        pool[i], h = _hashmix(entropy[i] if i < n else np.uint32(0), h)
    for s in range(POOL_SIZE):
        for d in range(POOL_SIZE):
            if s != d:
                v, h = _hashmix(pool[s], h)
                pool[d] = _mix(pool[d], v)
    for s in range(POOL_SIZE, n):
        for d in range(POOL_SIZE):
            v, h = _hashmix(entropy[s], h)
            pool[d] = _mix(pool[d], v)
    hb = _INIT_B
    for i in range(out.shape[0]):
        v = np.uint32(pool[i % POOL_SIZE] ^ hb)
        hb = np.uint32(hb * _MULT_B)
        v = np.uint32(v * hb)
        out[i] = np.uint32(v ^ (v >> _XSHIFT))
