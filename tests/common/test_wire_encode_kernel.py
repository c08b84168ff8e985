"""The compiled encode side of the codec (common.kernels.wire_encode: the octahedral normals
via common.codec.oct_encode, and the whole payload via common.codec.encode) equals the numpy
encoder it replaced (tests/support/oracle_codec.py) bit for bit: random and lower-hemisphere
normals, axes and diamond edges, ±0, tiny and huge lengths, NaN/±Inf, float16 edge values,
empty tiles."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.codec import oct_decode, oct_encode
from tests.support import oracle_codec as oc


def _hostile() -> np.ndarray:
    rng = np.random.default_rng(11)
    parts = [rng.normal(size=(20000, 3)),
             rng.normal(size=(2000, 3)) * np.array([1, 1, -1]),  # lower hemisphere
             np.eye(3), -np.eye(3),
             np.array([[0.5, 0.5, 0.0], [-0.5, 0.5, -0.0], [0.0, -0.0, -1.0], [-0.0, 0.0, 0.0]]),
             rng.normal(size=(500, 3)) * 1e-30, rng.normal(size=(500, 3)) * 1e30,
             np.array([[np.nan, 0, 1], [0, np.inf, 1], [-np.inf, 0, 0], [1, 1, np.nan], [0, 0, 0]])]
    # exactly on the fold's edges and at the rounding midpoints of the snorm16 grid
    t = (np.arange(-200, 201) + 0.5) / 32767
    parts.append(np.stack([t, 1 - np.abs(t), -np.full_like(t, 1e-3)], axis=1))
    return np.concatenate(parts).astype(np.float32)


def test_the_compiled_encode_equals_the_numpy_encoder_bit_for_bit():
    n = _hostile()
    q = oct_encode(n)
    assert q.dtype == np.int16 and q.shape == (len(n), 2)
    np.testing.assert_array_equal(q, oc.oct_encode(n))
    assert np.sum(q[:, 0] == -32768) >= 5  # the reserved code was exercised
    # float64 input is cast to float32 first, as the numpy encoder did
    np.testing.assert_array_equal(oct_encode(n.astype(np.float64)), q)
    # the reserved code decodes to zero
    assert not np.any(oct_decode(q[~np.isfinite(n).all(axis=1)]))


def test_the_encode_of_no_normals_is_empty():
    assert oct_encode(np.zeros((0, 3))).shape == (0, 2)


@pytest.mark.parametrize("lobe", [False, True])
@pytest.mark.parametrize("p", [0, 1, 7, 12288])
def test_compiled_payload_encodes_the_same_bytes_as_numpy(p, lobe):
    """codec.encode's one-pass payload (wire_encode.payload_into) gives the numpy encoder's
    bytes exactly (tests/support/oracle_codec.encode_numpy): float16 normals and subnormals,
    overflow, ±inf, NaN colours, NaN and infinite depths, zero and NaN normals. (Every one of
    the 2^32 float32 values was checked once against codec.to_f16 by f16_bits.)"""
    from igi.common.codec import encode
    from igi.common.frame import TileBuffers
    from tests.support.oracle_codec import encode_numpy

    g = np.random.default_rng(p)
    special = np.array([np.nan, np.inf, -np.inf, 65504.0, 65519.0, 65520.0, 1e6, -1e6, 2.0 ** -14, 2.0 ** -15,
                        2.0 ** -24, 2.0 ** -25, 3e-8, -0.0, 0.0, 1e-45], np.float32)

    def colours():
        c = (g.standard_normal((p, 3)) * np.exp(g.uniform(-25, 12, (p, 3)))).astype(np.float32)
        if p:
            c.reshape(-1)[g.integers(0, 3 * p, min(3 * p, 40))] = g.choice(special, min(3 * p, 40))
        return c

    depth = (g.random(p) * 10).astype(np.float32)
    normal = g.normal(size=(p, 3)).astype(np.float32)
    if p > 3:
        depth[:3] = [np.nan, np.inf, 0.0]
        normal[:2] = [[0, 0, 0], [np.nan, 0, 1]]
    b = TileBuffers(colours(), colours(), colours(), depth, normal, colours() if lobe else None)
    assert encode(b) == encode_numpy(b)
