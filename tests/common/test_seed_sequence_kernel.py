"""common.kernels.seed_sequence and sobol_stream.rng against numpy's own SeedSequence: the same
generators bit for bit, so every stream, set and image is what it was."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.kernels import seed_sequence
from igi.common.sobol_stream import _key_word, rng


def _numpy_rng(seed, *keys) -> np.random.Generator:
    ss = np.random.SeedSequence(_key_word(seed), spawn_key=tuple(_key_word(k) for k in keys))
    return np.random.Generator(np.random.PCG64(ss))


def _cases(n: int):
    r = np.random.default_rng(20261127)
    edge = [(0,), (1,), (0, 0), (2**32 - 1,), (2**32,), (2**64 - 1, 0, 2**64 - 1), (7, "vpl", 3),
            (2**130 + 5, 1), (12345, 0, 0, 0, 0, 0, 0, 0, 9), (5, b"bytes"), (0, "camera pool", 24)]
    yield from edge
    for _ in range(n):
        bits = int(r.integers(1, 64))
        seed = int(r.integers(0, 1 << bits, dtype=np.uint64))
        keys = tuple(int(r.integers(0, 1 << int(r.integers(1, 64)), dtype=np.uint64))
                     for _ in range(int(r.integers(0, 6))))
        yield (seed, *keys)


def test_rng_is_numpys_seed_sequence_generator_bit_for_bit():
    for case in _cases(2000):
        a, b = rng(*case), _numpy_rng(*case)
        assert a.bit_generator.state == b.bit_generator.state, case
        assert np.array_equal(a.random(4), b.random(4)), case


@pytest.mark.parametrize("n_words", [1, 3, 4, 8, 9])
def test_state_words_equal_generate_state_for_any_length(n_words):
    r = np.random.default_rng(3)
    for _ in range(200):
        entropy = r.integers(0, 2**32, int(r.integers(1, 12)), dtype=np.uint64).astype(np.uint32)
        entropy[r.random(len(entropy)) < 0.25] = 0  # zero words (a seed padded to the pool) too
        out = np.empty(n_words, np.uint32)
        seed_sequence.state_words(entropy, out)
        # the assembled entropy is what SeedSequence mixes: a list of words is taken word by
        # word (a zero word included), as the kernel takes them
        want = np.random.SeedSequence([int(w) for w in entropy]).generate_state(n_words, np.uint32)
        assert np.array_equal(out, want), entropy


def test_a_state_asked_for_another_size_is_refused():
    g = rng(1, 2)
    with pytest.raises(ValueError, match="uint64 words"):
        g.bit_generator.seed_seq.generate_state(2, np.uint64)


def test_a_generator_spawns_the_children_numpy_would():
    # scipy's scrambled Sobol' engines spawn from the generator they are given
    for case in [(9, 1, 2), (2**40, "lap", 3), (0,)]:
        a, b = rng(*case), _numpy_rng(*case)
        for _ in range(2):  # a second spawn continues where the first left off
            for ca, cb in zip(a.spawn(3), b.spawn(3)):
                assert ca.bit_generator.state == cb.bit_generator.state
        assert a.bit_generator.seed_seq.spawn_key == b.bit_generator.seed_seq.spawn_key


def test_a_generator_survives_pickling_and_deep_copies():
    import copy
    import pickle

    g = rng(5, "photons", 3)
    g.random(3)
    copies = [copy.deepcopy(g), pickle.loads(pickle.dumps(g))]
    want = g.random(4)
    for c in copies:
        assert np.array_equal(c.random(4), want)
