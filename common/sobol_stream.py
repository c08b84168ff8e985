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

Accumulated frames continue the sequence (worker.renderer): frame i after a reset takes the
blocks after frame i-1's, so the frames of an accumulation are jointly stratified. A block
past an instance's ``POINTS`` points continues in a fresh scrambling (a new "lap").
"""
from __future__ import annotations

import copy
import hashlib
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.random.bit_generator import ISpawnableSeedSequence
from scipy.stats import qmc

from igi.common.kernels import seed_sequence, sobol_points

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


def _words(x: int) -> list[int]:
    """The uint32 words of a non-negative int, least significant first ([0] for 0), as numpy's
    SeedSequence splits its entropy and spawn keys."""
    words = [x & 0xFFFFFFFF]
    x >>= 32
    while x:
        words.append(x & 0xFFFFFFFF)
        x >>= 32
    return words


class _State(ISpawnableSeedSequence):
    """PCG64's seed words, already hashed (seed_sequence.state_words): what the ``SeedSequence``
    of the same entropy and spawn key would generate. Anything else asked of it (``spawn``:
    scipy's engines spawn from the generator they are given) goes to that SeedSequence, made
    on first use."""

    __slots__ = ("words", "_entropy", "_keys", "_seq")

    def __init__(self, words: np.ndarray, entropy: int, keys: tuple[int, ...]) -> None:
        self.words, self._entropy, self._keys, self._seq = words, entropy, keys, None

    def generate_state(self, n_words: int, dtype=np.uint32) -> np.ndarray:
        if np.dtype(dtype) != np.uint64 or n_words != len(self.words):
            raise ValueError(f"holds {len(self.words)} uint64 words, asked for {n_words} {np.dtype(dtype)}")
        return self.words

    def _sequence(self) -> np.random.SeedSequence:
        if self._seq is None:
            self._seq = np.random.SeedSequence(self._entropy, spawn_key=self._keys)
        return self._seq

    def spawn(self, n_children: int) -> list[np.random.SeedSequence]:
        return self._sequence().spawn(n_children)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self._sequence(), name)


def rng(seed: int, *keys: int | str | bytes) -> np.random.Generator:
    """An independent PRNG for (seed, *keys), identical in every process: the generator
    ``PCG64(SeedSequence(seed, spawn_key=keys))``, bit for bit, its seed hashed in one compiled
    call (common.kernels.seed_sequence: numpy's SeedSequence cost ~3% of a small frame).

    Different key tuples give statistically independent streams (SeedSequence spawn keys),
    so e.g. ``rng(seed, "photons", k)`` and ``rng(seed, "vpl", k)`` never overlap.
    """
    seed_word, key_words = _key_word(seed), tuple(_key_word(k) for k in keys)
    entropy = _words(seed_word)
    if key_words:
        entropy += [0] * (seed_sequence.POOL_SIZE - len(entropy))  # as numpy: the seed padded to the pool
        for k in key_words:
            entropy += _words(k)
    words = np.empty(8, np.uint32)
    seed_sequence.state_words(np.array(entropy, np.uint32), words)
    return np.random.Generator(np.random.PCG64(_State(words.view(np.uint64), seed_word, key_words)))


def stream_seed(seed: int, *keys: int | str | bytes) -> int:
    """A seed for a SobolStream of its own, derived from (seed, *keys): streams of different
    uses in one frame are independent scramblings."""
    return int(rng(seed, "stream", *keys).integers(0, 1 << 62))


POINTS = 1 << 30  # points of one scrambled instance (scipy's 30-bit direction numbers)


def _sobol(d: int, seed: int, *keys: int) -> qmc.Sobol:
    return qmc.Sobol(d, scramble=True, seed=rng(seed, *keys))


@dataclass(frozen=True)
class _Scrambling:
    """One scrambled Sobol' instance as data: its direction numbers and digital shift (read-only,
    so every thread may draw from it at once)."""

    sv: np.ndarray  # (d, bits) unsigned
    shift: np.ndarray  # (d,) unsigned
    scale: float  # 2^-bits
    engine: qmc.Sobol  # the scipy engine it came from (fallback draws only)


_SCRAMBLINGS: "OrderedDict[tuple, _Scrambling]" = OrderedDict()
_SCRAMBLINGS_MAX = 512  # ~15 instances per frame seed (VPL walks, emitter samples, photons): ~30 frames
_LOCK = threading.Lock()


def _scrambling(d: int, seed: int, *keys: int) -> _Scrambling:
    """The scrambling of (d, seed, keys), built once per process: scipy's scrambled construction
    (~0.3 ms per instance) used to be paid by every set of every frame."""
    key = (d, seed, *keys)
    with _LOCK:
        hit = _SCRAMBLINGS.get(key)
        if hit is not None:
            _SCRAMBLINGS.move_to_end(key)
            return hit
    e = _sobol(d, seed, *keys)
    scr = _Scrambling(e._sv.copy(), e._shift.copy(), float(e._scale), e)
    scr.sv.flags.writeable = scr.shift.flags.writeable = False
    with _LOCK:
        _SCRAMBLINGS[key] = scr
        while len(_SCRAMBLINGS) > _SCRAMBLINGS_MAX:
            _SCRAMBLINGS.popitem(last=False)
    return scr


_DIRECT: list[bool] = []  # [works?] once checked against scipy's own engine


def _engine_draw(engine: qmc.Sobol, start: int, count: int) -> np.ndarray:
    """Points [start, start+count) through scipy's public API (O(start); a private copy of the
    engine, so concurrent draws never share its state)."""
    e = copy.deepcopy(engine)
    e.reset()
    if start:
        e.fast_forward(start)
    with warnings.catch_warnings():
        # scipy warns when count is not a power of two; blocks of any size are intended here.
        warnings.simplefilter("ignore", UserWarning)
        return e.random(count)


def _direct_works() -> bool:
    """Direct evaluation reads scipy's private direction numbers and shift; it is checked
    against scipy's own draws once per process and used only if they agree bit for bit."""
    if not _DIRECT:
        try:
            scr = _scrambling(5, 12345, 1)
            ok = all(np.array_equal(_direct_draw(scr, start, 9), _engine_draw(scr.engine, start, 9))
                     for start in (0, 1, 2, 3, 5, 8, 1000, 4097, 123457))
        except Exception:  # noqa: BLE001 - any scipy internals change: use the public path
            ok = False
        _DIRECT.append(ok)
    return _DIRECT[0]


def _direct_draw(scr: _Scrambling, start: int, count: int) -> np.ndarray:
    out = np.empty((count, scr.sv.shape[0]), np.float64)
    sobol_points.draw(scr.sv, scr.shift, start, count, scr.scale, out)
    return out


def _draw(scr: _Scrambling, start: int, count: int) -> np.ndarray:
    """Points [start, start+count) of the instance's sequence."""
    if _direct_works():
        return _direct_draw(scr, start, count)
    return _engine_draw(scr.engine, start, count)


class SobolStream:
    """A scrambled Sobol' sequence of ``dims`` dimensions, fixed by ``seed``.

    Points are evaluated directly from process-wide scramblings (any start in O(bits), no
    engine state), so instances are cheap and threads may share one.
    """

    def __init__(self, seed: int, dims: int = 32) -> None:
        if dims < 1:
            raise ValueError(f"dims must be >= 1, got {dims}")
        self.seed = int(seed)
        self.dims = int(dims)
        self._main = _scrambling(self.dims, self.seed, _TAG_MAIN)

    def points(self, start: int, count: int) -> np.ndarray:
        """Points [start, start+count) of the stream: (count, dims) float64 in [0, 1)."""
        if start < 0 or count < 0 or start + count > POINTS:
            raise ValueError(f"need 0 <= start, 0 <= count, start + count <= 2^30; got {start}, {count}")
        return _draw(self._main, start, count)

    def _lap(self, k: int, block_size: int) -> tuple[int, int]:
        """(scrambling seed, first row) of block k: blocks that would pass the instance's
        POINTS continue from row 0 of a derived scrambling."""
        lap, j = divmod(k, POINTS // block_size)
        return (self.seed if lap == 0 else stream_seed(self.seed, "lap", lap)), j * block_size

    def block(self, k: int, count: int, block_size: int) -> np.ndarray:
        """The first ``count`` points of block k: rows [k*block_size, k*block_size+count).

        Interleave set k uses block k, so sets are consecutive pieces of one sequence.
        """
        _check_block(k, count, block_size)
        seed, start = self._lap(k, block_size)
        return _draw(self._main if seed == self.seed else _scrambling(self.dims, seed, _TAG_MAIN), start, count)

    def padded(self, k: int, count: int, block_size: int, total_dims: int,
               group_dims: int = 4) -> np.ndarray:
        """Padded replications sampling: (count, total_dims) float64 in [0, 1).

        Dimensions are cut into groups of ``group_dims``; group g is an independent
        scrambled Sobol' instance of its own, drawn over the same rows as :meth:`block`.
        The rows of every group but the first are shuffled (successive permutations of one
        generator seeded by (seed, k, count)), which pairs the groups at random: each group's projection
        keeps the stratification of a Sobol' prefix, while the whole point set is a
        valid randomized sample of the high-dimensional cube.
        """
        _check_block(k, count, block_size)
        if total_dims < 1 or group_dims < 1:
            raise ValueError(f"total_dims and group_dims must be >= 1, got {total_dims}, {group_dims}")
        seed, start = self._lap(k, block_size)
        groups = [(g, d0, min(group_dims, total_dims - d0)) for g, d0 in enumerate(range(0, total_dims, group_dims))]
        # One generator per block for all its groups' shuffles (they are cheap to draw, not to seed).
        shuffle = rng(self.seed, _TAG_PERM, k, count) if len(groups) > 1 else None
        if _direct_works():
            padding = _padding(seed, total_dims, group_dims)
            perms = np.zeros((len(groups), count), np.int64)
            for g in range(1, len(groups)):
                perms[g] = shuffle.permutation(count)
            out = np.empty((count, total_dims), dtype=np.float64)
            sobol_points.draw_padded(padding.sv, padding.shift, padding.dims, padding.scale, start, count, perms, out)
            return out
        out = np.empty((count, total_dims), dtype=np.float64)
        for g, d0, d in groups:
            pts = _engine_draw(_scrambling(d, seed, _TAG_GROUP, g).engine, start, count)
            if g:
                pts = pts[shuffle.permutation(count)]
            out[:, d0:d0 + d] = pts
        return out


@dataclass(frozen=True)
class _Padding:
    """The scramblings of a padded draw's groups stacked for sobol_points.draw_padded: group g's
    direction numbers sv[g, :dims[g]] and shift[g, :dims[g]] (read-only)."""

    sv: np.ndarray  # (groups, group_dims, bits)
    shift: np.ndarray  # (groups, group_dims)
    dims: np.ndarray  # (groups,)
    scale: float


_PADDINGS: "OrderedDict[tuple, _Padding]" = OrderedDict()


def _padding(seed: int, total_dims: int, group_dims: int) -> _Padding:
    """The stacked group scramblings of (seed, total_dims, group_dims), built once per process."""
    key = (seed, total_dims, group_dims)
    with _LOCK:
        hit = _PADDINGS.get(key)
        if hit is not None:
            _PADDINGS.move_to_end(key)
            return hit
    scrs = [_scrambling(min(group_dims, total_dims - d0), seed, _TAG_GROUP, g)
            for g, d0 in enumerate(range(0, total_dims, group_dims))]
    bits = scrs[0].sv.shape[1]
    sv = np.zeros((len(scrs), group_dims, bits), scrs[0].sv.dtype)
    shift = np.zeros((len(scrs), group_dims), scrs[0].shift.dtype)
    for g, scr in enumerate(scrs):
        sv[g, :len(scr.shift)] = scr.sv
        shift[g, :len(scr.shift)] = scr.shift
    dims = np.array([len(scr.shift) for scr in scrs], np.int64)
    for a in (sv, shift, dims):
        a.flags.writeable = False
    out = _Padding(sv, shift, dims, scrs[0].scale)
    with _LOCK:
        _PADDINGS[key] = out
        while len(_PADDINGS) > _SCRAMBLINGS_MAX // 4:
            _PADDINGS.popitem(last=False)
    return out


def _check_block(k: int, count: int, block_size: int) -> None:
    if k < 0 or count < 0 or block_size < 1:
        raise ValueError(f"need k >= 0, count >= 0, block_size >= 1; got {k}, {count}, {block_size}")
    if count > block_size:
        raise ValueError(f"count {count} exceeds block_size {block_size}: blocks would overlap")
    if block_size > POINTS:
        raise ValueError(f"block_size {block_size} exceeds the {POINTS} points of one instance")
