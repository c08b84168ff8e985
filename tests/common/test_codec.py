import struct

import lz4.frame
import numpy as np
import pytest

from igi.common.codec import (BYTES_PER_PIXEL, HEADER_SIZE, MAGIC, VERSION, decode, encode, oct_decode, oct_encode,
                          to_f16)
from igi.common.frame import TileBuffers


def _angle(a, b):
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    # atan2 form: accurate for tiny angles where arccos(dot) is not.
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def _render_like_tile(p=64 * 48, seed=0):
    """Buffers resembling a rendered sub-image: flat walls, smooth light, some noise."""
    rng = np.random.default_rng(seed)
    h, w = 48, p // 48
    ys, xs = np.mgrid[0:h, 0:w]
    wall = (xs * 3 // w) + 3 * (ys * 2 // h)  # six planar patches
    albedo = np.array([[0.7, 0.1, 0.1], [0.1, 0.7, 0.1], [0.7, 0.7, 0.7]] * 2, np.float32)
    normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0], [0, 0, -1]], np.float32)
    light = 1.0 / (1.0 + ((xs - w / 2) ** 2 + (ys - h / 3) ** 2) / 400.0)
    irr = light[..., None] * np.array([1.0, 0.9, 0.8]) * (1 + 0.2 * rng.standard_normal((h, w, 1)))
    unf = np.zeros((h, w, 3), np.float32)
    unf[:4, w // 2 - 3:w // 2 + 3] = 17.0  # an emitter seen directly
    depth = 2.0 + 0.01 * xs + 0.02 * ys
    depth[wall == 5] = np.inf  # a miss region
    flat = lambda a: np.ascontiguousarray(np.asarray(a, np.float32).reshape(p, -1).squeeze())
    return TileBuffers(reflectance=flat(albedo[wall]).reshape(p, 3), irradiance=flat(irr).reshape(p, 3),
                       unfiltered=flat(unf).reshape(p, 3), depth=flat(depth), normal=flat(normals[wall]).reshape(p, 3))


def test_octahedral_round_trip_error_is_tiny_for_random_unit_normals():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(200_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    m = oct_decode(oct_encode(n)).astype(np.float64)
    assert np.allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-6)
    err = _angle(n, m)
    assert err.max() < 1e-4  # measured ~6.4e-5 rad max, ~2.3e-5 mean


def test_octahedral_round_trip_at_poles_axes_and_fold_edges():
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    np.testing.assert_array_equal(oct_decode(oct_encode(axes)), axes.astype(np.float32))
    rng = np.random.default_rng(1)
    special = [
        [1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0],  # equator diagonals: the fold line
        [1, 1, 1], [-1, -1, -1], [1, -1, -1], [0, 1, -1], [1, 0, -1e-12], [1e-9, 1e-9, -1],
        [-0.0, -0.0, -1], [1e-30, 0, 1], [0, -0.0, 1],
    ]
    near_pole = np.column_stack([rng.normal(0, 1e-6, (100, 2)), rng.choice([-1, 1], 100)])
    equator = np.column_stack([rng.normal(size=(100, 2)), rng.normal(0, 1e-7, 100)])
    n = np.concatenate([np.array(special, float), near_pole, equator, axes])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert _angle(n, oct_decode(oct_encode(n)).astype(np.float64)).max() < 1e-4


def test_octahedral_unnormalized_zero_and_nonfinite_normals():
    n = np.array([[0, 0, 5.0], [0, 0, 0], [np.nan, 0, 1], [np.inf, 0, 0], [3, 4, 0]])
    m = oct_decode(oct_encode(n))
    np.testing.assert_allclose(m[0], [0, 0, 1], atol=1e-6)
    np.testing.assert_array_equal(m[1:4], 0.0)  # undefined normals stay zero, not invented
    np.testing.assert_allclose(m[4], [0.6, 0.8, 0], atol=1e-4)
    assert np.all(np.isfinite(m))


def test_float16_relative_error_bound():
    rng = np.random.default_rng(2)
    v = np.exp(rng.uniform(np.log(6.2e-5), np.log(6.5e4), 100_000)).astype(np.float32)
    v *= rng.choice([-1, 1], v.shape)
    rel = np.abs(to_f16(v).astype(np.float64) - v) / np.abs(v)
    assert rel.max() <= 2.0 ** -11  # half-ULP of a 10-bit mantissa (normal range)
    tiny = np.float32([1e-6, 3e-7, 0.0, -0.0])
    assert np.all(np.abs(to_f16(tiny).astype(np.float64) - tiny) <= 2.0 ** -25)  # subnormal step / 2


def test_nan_and_inf_radiance_are_clamped_not_sent():
    p = 6
    bad = np.array([[np.nan, np.inf, -np.inf]] * p, np.float32)
    bad[1] = (1e9, -1e9, 65519.0)
    b = TileBuffers(reflectance=bad.copy(), irradiance=bad.copy(), unfiltered=bad.copy(),
                    depth=np.array([1, np.inf, np.nan, 0, 1e30, 3], np.float32),
                    normal=np.tile(np.float32([0, 0, 1]), (p, 1)))
    out = decode(encode(b), p)
    for name in ("reflectance", "irradiance", "unfiltered"):
        a = getattr(out, name)
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a[0], [0.0, 65504.0, -65504.0])
        np.testing.assert_array_equal(a[1], [65504.0, -65504.0, 65504.0])
    # depth is float32: inf is the miss marker and survives; NaN becomes a miss.
    np.testing.assert_array_equal(out.depth, np.float32([1, np.inf, np.inf, 0, 1e30, 3]))


def test_round_trip_of_a_render_like_tile():
    b = _render_like_tile()
    data = encode(b)
    out = decode(data, len(b))
    assert len(out) == len(b)
    for name in ("reflectance", "irradiance", "unfiltered"):
        a, ref = getattr(out, name), getattr(b, name)
        assert a.dtype == np.float32 and a.shape == ref.shape
        np.testing.assert_allclose(a, ref, rtol=2.0 ** -11, atol=2.0 ** -25)
    np.testing.assert_array_equal(out.depth, b.depth)  # float32 is sent as is
    assert _angle(out.normal.astype(np.float64), b.normal.astype(np.float64)).max() < 1e-4


def test_split_lobes_round_trip_and_a_tile_without_sends_no_lobe_section():
    """The lobe section travels only when a pixel has a lobe (flag FLAG_LOBE, 6 more bytes a
    pixel before compression); lobes come back like the other colours, pixels without one (a red
    below 0, NaN included: the wire would make NaN a lobe of 0) as NO_LOBE."""
    import lz4.frame

    from igi.common.codec import FLAG_LOBE, payload_bytes
    from igi.common.frame import NO_LOBE

    b = _render_like_tile()
    p = len(b)
    plain = encode(b)
    assert plain[5] == 0 and len(lz4.frame.decompress(plain[HEADER_SIZE:])) == payload_bytes(p, False)
    assert np.all(decode(plain, p).lobe == NO_LOBE)
    rng = np.random.default_rng(2)
    lobe = np.where(rng.random((p, 1)) < 0.5, rng.random((p, 3)) * 3, NO_LOBE).astype(np.float32)
    lobe[0] = [np.nan, 1.0, 1.0]
    b.lobe = lobe
    data = encode(b)
    assert data[5] == FLAG_LOBE and len(lz4.frame.decompress(data[HEADER_SIZE:])) == payload_bytes(p, True)
    out = decode(data, p)
    has = lobe[:, 0] >= 0
    np.testing.assert_allclose(out.lobe[has], lobe[has], rtol=2.0 ** -11)
    assert np.all(out.lobe[~has] == NO_LOBE)
    for name in ("reflectance", "irradiance", "unfiltered", "depth"):
        np.testing.assert_array_equal(getattr(out, name), getattr(decode(plain, p), name))
    # the flag must match the payload: set on a plain one, cleared on a lobe one
    with pytest.raises(ValueError, match="truncated"):
        decode(plain[:5] + bytes([FLAG_LOBE]) + plain[6:], p)
    with pytest.raises(ValueError, match="more than"):
        decode(data[:5] + b"\x00" + data[6:], p)


def test_compression_ratio_is_reported_and_beats_raw(capsys):
    b = _render_like_tile(p=96 * 48)
    data = encode(b)
    raw = len(b) * BYTES_PER_PIXEL
    per_pixel = len(data) / len(b)
    with capsys.disabled():
        print(f"\n[codec] render-like tile: {per_pixel:.2f} bytes/pixel "
              f"(raw {BYTES_PER_PIXEL}, float32 buffers 52), ratio {raw / len(data):.2f}x")
    assert len(data) < raw


def test_empty_tile_round_trips():
    e3 = np.empty((0, 3), np.float32)
    b = TileBuffers(e3, e3, e3, np.empty(0, np.float32), e3)
    out = decode(encode(b), 0)
    assert len(out) == 0 and out.normal.shape == (0, 3)


def test_encode_rejects_inconsistent_buffers():
    b = _render_like_tile()
    b.irradiance = b.irradiance[:-1]
    with pytest.raises(ValueError, match="irradiance"):
        encode(b)


def _header(p, magic=MAGIC, version=VERSION, flags=0):
    return struct.pack("<4sBBHI", magic, version, flags, 0, p)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: b"", "too short"),
    (lambda d: d[:7], "too short"),
    (lambda d: b"XXXX" + d[4:], "magic"),
    (lambda d: d[:4] + b"\x09" + d[5:], "version"),
    (lambda d: d[:5] + b"\x02" + d[6:], "flags"),
    (lambda d: d[:HEADER_SIZE], "truncated"),
    (lambda d: d[:-40], "truncated"),
    (lambda d: d[:-1], "truncated"),
    (lambda d: d[:HEADER_SIZE] + bytes(range(256)) * 4, "corrupt"),
    (lambda d: d + b"extra", "trailing"),
    (lambda d: _header(1 << 30) + d[HEADER_SIZE:], "pixels"),
])
def test_garbage_and_truncated_input_raise_value_error(mutate, message):
    b = _render_like_tile()
    data = encode(b)
    with pytest.raises(ValueError, match=message):
        decode(mutate(data), None)


def test_a_flipped_bit_anywhere_in_the_payload_raises_value_error():
    """Every byte of the lz4 frame (its header, block sizes, blocks, end mark), one bit each:
    the block checksums and the frame's structure catch them all."""
    data = encode(_render_like_tile())
    for i in range(HEADER_SIZE, len(data)):
        d = bytearray(data)
        d[i] ^= 1 << (i % 8)
        with pytest.raises(ValueError):
            decode(bytes(d), 64 * 48)


def test_pixel_count_must_match_the_header():
    b = _render_like_tile()
    with pytest.raises(ValueError, match="expected 100"):
        decode(encode(b), 100)


def test_payload_larger_than_header_announces_is_refused():
    # A valid lz4 frame of 10x the announced size: decode stops at the limit and refuses.
    p = 100
    body = lz4.frame.compress(bytes(p * BYTES_PER_PIXEL * 10))
    with pytest.raises(ValueError, match="more than"):
        decode(_header(p) + body, p)
    short = lz4.frame.compress(bytes(p * BYTES_PER_PIXEL - 1))
    with pytest.raises(ValueError, match="truncated"):
        decode(_header(p) + short, p)
