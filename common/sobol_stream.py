"""The randomized quasi-Monte Carlo stream of the paper's §4.4.

One scrambled Sobol' sequence per frame seed; interleave set k uses the k-th consecutive
block of points, so the sets of neighbouring pixels are disjoint pieces of one
low-discrepancy sequence and complement each other when the discontinuity buffer joins
them. Every process that builds ``SobolStream(seed)`` gets bitwise the same points: the
scrambling is drawn from a ``SeedSequence`` of the seed, never from global state.

Random walks need more dimensions than one Sobol' instance should carry, so
:meth:`SobolStream.padded` implements padded replications sampling (Kollig & Keller 2001):
independent low-dimensional scrambled Sobol' instances, one per group of dimensions, whose
points are shuffled per group so every group's projection stays low-discrepancy while the
groups are paired at random.
"""
from __future__ import annotations

import hashlib
import warnings

import numpy as np
from scipy.stats import qmc

# Tags that keep the derived PRNGs of different uses independent of each other.
_TAG_MAIN = 0x50B01  # the main Sobol' instance
_TAG_GROUP = 0x9AD  # scrambling of padded group g
_TAG_PERM = 0x9E5  # shuffle of padded group g in block k


def _key_word(key: int | str | bytes) -> int:
    """A non-negative integer for SeedSequence from an int, str or bytes key."""
    if isinstance(key, (bool, np.bool_)):
        return int(key)
    if isinstance(key, (int, np.integer)):
        k = int(key)
        if k < 0:
            raise ValueError(f"rng keys must be non-negative, got {k}")
        return k
    if isinstance(key, str):
        key = key.encode("utf-8")
    if isinstance(key, bytes):
        # A 64-bit hash: str keys are names ("vpl", "photon"), collisions are not a concern.
        return int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little")
    raise TypeError(f"rng key must be int, str or bytes, not {type(key).__name__}")


def rng(seed: int, *keys: int | str | bytes) -> np.random.Generator:
    """An independent PRNG for (seed, *keys), identical in every process.

    Different key tuples give statistically independent streams (SeedSequence spawn keys),
    so e.g. ``rng(seed, "photons", k)`` and ``rng(seed, "vpl", k)`` never overlap.
    """
    ss = np.random.SeedSequence(_key_word(seed), spawn_key=tuple(_key_word(k) for k in keys))
    return np.random.Generator(np.random.PCG64(ss))


def _sobol(d: int, seed: int, *keys: int) -> qmc.Sobol:
    return qmc.Sobol(d, scramble=True, seed=rng(seed, *keys))


_DIRECT_SEEK: list[bool] = []  # [works?] once checked against scipy's own fast_forward


def _seek_state(engine: qmc.Sobol, start: int) -> np.ndarray:
    """The engine's state after ``start`` points, in O(bits): scipy keeps the last point drawn
    (Gray-code order: point j = shift ^ XOR of the direction numbers of the bits of j ^ (j>>1))."""
    j = start - 1
    g = j ^ (j >> 1)
    q = engine._shift.copy()
    b = 0
    while g:
        if g & 1:
            q ^= engine._sv[:, b]
        g >>= 1
        b += 1
    return q


def _direct_seek_works() -> bool:
    """scipy's fast_forward walks every skipped point (O(n): ~0.4 s per photon set of a
    13-light scene at block 116); seeking the state directly relies on private attributes, so
    it is checked against fast_forward once and used only if it agrees."""
    if not _DIRECT_SEEK:
        try:
            ok = True
            for start in (1, 2, 3, 5, 8, 1000, 4097, 123457):
                e = _sobol(5, 12345, 1)
                e.reset()
                e.fast_forward(start)
                ok &= bool(np.array_equal(_seek_state(e, start), e._quasi))
        except Exception:  # noqa: BLE001 - any scipy internals change: use the public path
            ok = False
        _DIRECT_SEEK.append(ok)
    return _DIRECT_SEEK[0]


def _draw(engine: qmc.Sobol, start: int, count: int) -> np.ndarray:
    """Points [start, start+count) of the engine's sequence."""
    engine.reset()
    if start and _direct_seek_works():
        engine._quasi = _seek_state(engine, start)
        engine.num_generated = start
    elif start:
        engine.fast_forward(start)
    with warnings.catch_warnings():
        # scipy warns when count is not a power of two; blocks of any size are intended here.
        warnings.simplefilter("ignore", UserWarning)
        return engine.random(count)


class SobolStream:
    """A scrambled Sobol' sequence of ``dims`` dimensions, fixed by ``seed``.

    Draws reuse one engine (reset + fast_forward), so one instance must not be shared by
    threads drawing concurrently; build one per thread (construction takes ~2 ms).
    """

    def __init__(self, seed: int, dims: int = 32) -> None:
        if dims < 1:
            raise ValueError(f"dims must be >= 1, got {dims}")
        self.seed = int(seed)
        self.dims = int(dims)
        self._engine = _sobol(self.dims, self.seed, _TAG_MAIN)
        self._groups: dict[tuple[int, int], qmc.Sobol] = {}

    def points(self, start: int, count: int) -> np.ndarray:
        """Points [start, start+count) of the stream: (count, dims) float64 in [0, 1)."""
        if start < 0 or count < 0:
            raise ValueError(f"start and count must be >= 0, got {start}, {count}")
        return _draw(self._engine, start, count)

    def block(self, k: int, count: int, block_size: int) -> np.ndarray:
        """The first ``count`` points of block k: rows [k*block_size, k*block_size+count).

        Interleave set k uses block k, so sets are consecutive pieces of one sequence.
        """
        _check_block(k, count, block_size)
        return self.points(k * block_size, count)

    def _group_engine(self, g: int, d: int) -> qmc.Sobol:
        engine = self._groups.get((g, d))
        if engine is None:
            engine = self._groups[(g, d)] = _sobol(d, self.seed, _TAG_GROUP, g)
        return engine

    def padded(self, k: int, count: int, block_size: int, total_dims: int,
               group_dims: int = 4) -> np.ndarray:
        """Padded replications sampling: (count, total_dims) float64 in [0, 1).

        Dimensions are cut into groups of ``group_dims``; group g is an independent
        scrambled Sobol' instance of its own, drawn over the same rows as :meth:`block`.
        The rows of every group but the first are shuffled (a permutation seeded by
        (seed, g, k, count)), which pairs the groups at random: each group's projection
        keeps the stratification of a Sobol' prefix, while the whole point set is a
        valid randomized sample of the high-dimensional cube.
        """
        _check_block(k, count, block_size)
        if total_dims < 1 or group_dims < 1:
            raise ValueError(f"total_dims and group_dims must be >= 1, got {total_dims}, {group_dims}")
        out = np.empty((count, total_dims), dtype=np.float64)
        for g, d0 in enumerate(range(0, total_dims, group_dims)):
            d = min(group_dims, total_dims - d0)
            pts = _draw(self._group_engine(g, d), k * block_size, count)
            if g:
                pts = pts[rng(self.seed, _TAG_PERM, g, k, count).permutation(count)]
            out[:, d0:d0 + d] = pts
        return out


def _check_block(k: int, count: int, block_size: int) -> None:
    if k < 0 or count < 0 or block_size < 1:
        raise ValueError(f"need k >= 0, count >= 0, block_size >= 1; got {k}, {count}, {block_size}")
    if count > block_size:
        raise ValueError(f"count {count} exceeds block_size {block_size}: blocks would overlap")
