"""The compiled wire decode (common.kernels.wire_decode via common.codec) equals the numpy
decode it replaced (tests/support/oracle_codec.py) bit for bit: on every float16 code
(subnormals, inf, NaN payloads), arbitrary payload bytes, every octahedral edge code, empty
tiles, and when it writes a tile into a larger frame with a step (the master's layout)."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.codec import (BYTES_PER_PIXEL, _F16_TO_F32, decode, decode_into, decode_raw, decompress,
                          encode, oct_decode, payload_bytes, section_offsets)
from igi.common.frame import TileBuffers
from igi.common.kernels.wire_decode import f16_to_f32
from tests.support import oracle_codec as oc


def _same(a, b):
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.tobytes() == b.tobytes()


def test_every_float16_code_converts_like_numpy():
    codes = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16)
    out = np.empty(len(codes), np.float32)
    lo = (codes & 0xFF).astype(np.uint8)
    hi = (codes >> 8).astype(np.uint8)
    f16_to_f32(lo, hi, out)
    _same(out, codes.view(np.float16).astype(np.float32))
    _same(out, _F16_TO_F32)


@pytest.mark.parametrize("lobe", [False, True])
@pytest.mark.parametrize("p", [0, 1, 7, 4096])
def test_arbitrary_payload_bytes_decode_like_numpy(p, lobe):
    rng = np.random.default_rng(p)
    raw = rng.integers(0, 256, payload_bytes(p, lobe)).astype(np.uint8)
    a, b = decode_raw(p, raw), oc.decode_raw(p, raw)
    for name in ("reflectance", "irradiance", "unfiltered", "lobe", "depth", "normal"):
        _same(getattr(a, name), getattr(b, name))


def test_hostile_tile_buffers_round_trip_like_numpy():
    rng = np.random.default_rng(1)
    p = 3000

    def rnd(shape):
        a = rng.standard_normal(shape) * rng.choice([1e-9, 1e-6, 1.0, 1e4, 1e6], shape)
        for v, frac in ((np.nan, 0.02), (np.inf, 0.02), (-np.inf, 0.02), (0.0, 0.05), (-0.0, 0.05)):
            a[rng.random(shape) < frac] = v
        return a.astype(np.float32)

    nrm = rnd((p, 3))
    nrm[::40] = 0.0
    for lobe in (None, rnd((p, 3))):
        b = TileBuffers(rnd((p, 3)), rnd((p, 3)), rnd((p, 3)), rnd(p), nrm, lobe)
        d = encode(b)
        x, y = decode(d, p), oc.decode_raw(*decompress(d))
        for name in ("reflectance", "irradiance", "unfiltered", "lobe", "depth", "normal"):
            _same(getattr(x, name), getattr(y, name))


def test_octahedral_decode_on_random_and_edge_codes():
    rng = np.random.default_rng(5)
    q = rng.integers(-32768, 32768, (100_000, 2)).astype(np.int16)
    edge = np.arange(-32768, 32768, 97, dtype=np.int32)
    q = np.concatenate([q, np.stack([edge, 32767 - np.abs(edge)], 1).clip(-32768, 32767).astype(np.int16),
                        np.stack([edge, -edge], 1).clip(-32768, 32767).astype(np.int16),
                        np.array([[-32768, -32768], [0, 0], [32767, 0], [0, -32768], [-32768, 0],
                                  [-32767, -32767], [32767, 32767]], np.int16)])
    _same(oct_decode(q), oc.oct_decode(q))
    _same(oct_decode(q[:0]), oc.oct_decode(q[:0]))


@pytest.mark.parametrize("lobe", [False, True])
@pytest.mark.parametrize("n", [1, 3, 4])
def test_decode_into_a_frame_with_a_step_places_every_pixel(n, lobe):
    rng = np.random.default_rng(n)
    h, w = 5, 7
    p = h * w
    raw = rng.integers(0, 256, payload_bytes(p, lobe)).astype(np.uint8)
    H, W = 2 + h * n, 3 + w * n
    vals = np.full((12, H, W), 7.0, np.float32)
    nrm = np.full((3, H, W), 7.0, np.float32)
    depth = np.full((H, W), 7.0, np.float32)
    assert decode_into(raw, p, h, w, n, 1, 2, vals, nrm, depth) == lobe
    ref = oc.decode_raw(p, raw)
    at = (slice(1, 1 + (h - 1) * n + 1, n), slice(2, 2 + (w - 1) * n + 1, n))
    for s, name in enumerate(("reflectance", "irradiance", "unfiltered", "lobe")):  # no lobe: all NO_LOBE
        _same(np.ascontiguousarray(vals[3 * s:3 * s + 3][(slice(None),) + at].transpose(1, 2, 0)),
              getattr(ref, name).reshape(h, w, 3))
    _same(np.ascontiguousarray(nrm[(slice(None),) + at].transpose(1, 2, 0)), ref.normal.reshape(h, w, 3))
    _same(np.ascontiguousarray(depth[at]), ref.depth.reshape(h, w))
    untouched = np.ones((H, W), bool)
    untouched[at] = False
    assert (depth[untouched] == 7.0).all() and (vals[:, untouched] == 7.0).all()
    with pytest.raises(ValueError):  # a tile that would not fit is refused, nothing written
        decode_into(raw, p, h, w, n, H - 1, 0, vals, nrm, depth)


def test_section_offsets_are_the_codec_layout():
    o = section_offsets(10)
    assert o == {"reflectance": 0, "irradiance": 60, "unfiltered": 120, "depth": 180, "normal": 220}
    assert 220 + 40 == 10 * BYTES_PER_PIXEL == payload_bytes(10, False)
    o = section_offsets(10, lobe=True)
    assert o == {"reflectance": 0, "irradiance": 60, "unfiltered": 120, "lobe": 180, "depth": 240, "normal": 280}
    assert 280 + 40 == payload_bytes(10, True)
