"""The master's compiled path (common.kernels.wire_decode, master.kernels) equals the numpy
path it replaced (tests/support/oracle_master.py) bit for bit: frame assembly from wire bytes
(arbitrary payload bytes: NaN/Inf everywhere, incomplete frames, frames smaller than the
interleave), the discontinuity buffer at every window and threshold setting, the fading
blend of consistent accumulation, any thread count, and the accumulation sums."""
from __future__ import annotations

import lz4.frame
import numpy as np
import pytest

from igi.common import codec
from igi.common.codec import encode
from igi.common.interleave import extract
from igi.common.params import make_params, params_to_dict
from igi.master import parallel
from igi.master.accumulation import Accumulator
from igi.master.discontinuity_buffer import filter_irradiance
from igi.master.frame_assembly import FrameAssembler, task_tiles, tile_pixel_count
from tests.support import oracle_master as om

# the numpy oracle warns on NaN/Inf arithmetic (the inputs are hostile on purpose)
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


@pytest.fixture(autouse=True)
def _restore_threads():
    prev = parallel.set_threads(None)
    yield
    parallel.set_threads(prev)


def _wire(p: int, raw: np.ndarray) -> bytes:
    """Wire bytes around an arbitrary payload (what a hostile or buggy worker could send)."""
    body = lz4.frame.compress(raw.tobytes(), content_checksum=True, store_size=True)
    return codec._HEADER.pack(codec.MAGIC, codec.VERSION, 0, 0, p) + body


def _frame(w, h, seed):
    """Render-like full-frame buffers with NaN/Inf/-0/subnormal values sprinkled in."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    wall = (xx * 3 // max(w, 1)) + 3 * (yy * 2 // max(h, 1))
    normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0], [0, 0, -1]], np.float32)
    nrm = (normals[wall] + 0.2 * rng.standard_normal((h, w, 3))).astype(np.float32)
    irr = ((1 + 0.3 * rng.standard_normal((h, w, 3))) * (wall[..., None] + 1)).astype(np.float32)
    depth = (2 + 0.01 * xx + 0.05 * wall + 0.02 * rng.standard_normal((h, w))).astype(np.float32)
    for a, vals in ((irr, [np.nan, np.inf, -np.inf, -0.0, 3e-6, 1e5]), (depth, [np.nan, np.inf, -np.inf, 0.0, -1.0]),
                    (nrm, [np.nan, 0.0])):
        for v in vals:
            a[rng.random(a.shape) < 0.01] = v
    refl = rng.random((h, w, 3), dtype=np.float32)
    unf = np.where(rng.random((h, w, 3)) < 0.05, np.float32(17.0), np.float32(0.0))
    return {"reflectance": refl, "irradiance": irr, "unfiltered": unf, "depth": depth, "normal": nrm}


def assert_same(a, b, msg=None):
    """Bit for bit, except which NaN: when two NaNs meet, x86 returns one operand's payload,
    and which one a compiler puts first is not part of anyone's semantics."""
    assert a.shape == b.shape and a.dtype == b.dtype, msg
    na, nb = np.isnan(a), np.isnan(b)
    assert np.array_equal(na, nb), msg
    assert a[~na].tobytes() == b[~nb].tobytes(), msg


def _params(n, **kw):
    """Parameter dict (image() reads a dict; settings outside the CLI's ranges on purpose)."""
    return dict(params_to_dict(make_params(interleave=n)), **kw)


SETTINGS = [  # (filter_window, depth_threshold, normal_threshold, consistent fading index)
    (-1, 0.05, 0.9, 0), (1, 0.05, 0.9, 0), (2, 0.1, 0.5, 0), (3, 0.0, 1.0, 0), (4, 0.05, -1.0, 0),
    (5, 1.0, 0.0, 0), (7, 0.2, 0.99, 0), (-1, 0.05, 0.9, 5), (3, 2.0, 0.3, 9),
    # the widest window the parameters allow (the planes' border), and one wider (planes re-bordered)
    (15, 0.3, 0.2, 0), (17, 0.3, 0.2, 0),
]


def _images(ref, new, n):
    for window, dt, nt, index in SETTINGS:
        kw = dict(filter_window=window, depth_threshold=dt, normal_threshold=nt)
        if index:
            kw.update(consistent=True, filter_frames=2, accumulate=True)
        p = _params(n, **kw)
        assert_same(ref.image(p, index), new.image(p, index), (window, dt, nt, index))


@pytest.mark.parametrize("w,h,n,task_pixels", [(97, 61, 3, 200), (64, 48, 4, 97), (33, 20, 2, 5000), (53, 37, 5, 150),
                                               (5, 4, 3, 4), (2, 1, 3, 1), (1, 1, 1, 1)])
def test_wire_frames_match_the_numpy_master(w, h, n, task_pixels):
    full = _frame(w, h, w + h)
    tiles = task_tiles(w, h, n, task_pixels)
    ref, new = om.OracleFrameAssembler(w, h, n), FrameAssembler(w, h, n)
    for t in reversed(tiles):
        d = encode(extract(t, n, full))
        ref.add_wire(t, d)
        new.add_wire(t, d)
    assert new.complete
    _images(ref, new, n)
    for name, arr in ref.buffers.items():
        assert arr.tobytes() == new.buffers[name].tobytes(), name
    _images(ref, new, n)  # after .buffers: the float path


@pytest.mark.parametrize("seed", [0, 1])
def test_arbitrary_payload_bytes_and_incomplete_frames_match(seed):
    w, h, n = 41, 29, 3
    rng = np.random.default_rng(seed)
    tiles = task_tiles(w, h, n, 60)
    ref, new = om.OracleFrameAssembler(w, h, n), FrameAssembler(w, h, n)
    _images(ref, new, n)  # no tile yet
    for t in tiles[::2]:
        p = tile_pixel_count(t, n, w, h)
        d = _wire(p, rng.integers(0, 256, p * codec.BYTES_PER_PIXEL).astype(np.uint8))
        ref.add_wire(t, d)
        new.add_wire(t, d)
    assert not new.complete
    _images(ref, new, n)


@pytest.mark.parametrize("threads", [1, 3])
def test_float_path_and_thread_count_match(threads):
    parallel.set_threads(threads)
    w, h, n = 70, 45, 3
    full = _frame(w, h, 7)
    ref, new = om.OracleFrameAssembler(w, h, n), FrameAssembler(w, h, n)
    from igi.common.codec import decode
    for t in task_tiles(w, h, n, 300):
        b = decode(encode(extract(t, n, full)))
        ref.add(t, b)
        new.add(t, b)
    _images(ref, new, n)


@pytest.mark.parametrize("window", [1, 2, 3, 4, 5, 6, 9])
@pytest.mark.parametrize("dt,nt", [(0.05, 0.9), (0.0, 1.0), (1.5, -1.0), (np.inf, 0.5)])
def test_filter_irradiance_matches_numpy_with_nonfinite_inputs(window, dt, nt):
    full = _frame(37, 23, window)
    args = (full["irradiance"], full["depth"], full["normal"], window, dt, nt)
    assert_same(om.filter_irradiance(*args), filter_irradiance(*args))


def test_filter_keeps_minus_zero_exactly_where_numpy_did():
    # a -0 centre stays -0 only while every term added to it is -0 (rejected negative
    # neighbours); a rejected non-negative or an outside neighbour adds +0
    irr = np.full((4, 5, 3), -0.0, np.float32)
    irr[0, 0] = -1.0
    irr[2, 3] = 2.0
    depth = np.ones((4, 5), np.float32)
    depth[1:3, 1:4] = 50.0  # rejected by depth
    nrm = np.tile(np.float32([0, 0, 1]), (4, 5, 1))
    for window in (2, 3):
        a = om.filter_irradiance(irr, depth, nrm, window, 0.05, 0.9)
        b = filter_irradiance(irr, depth, nrm, window, 0.05, 0.9)
        assert a.tobytes() == b.tobytes()
        assert np.signbit(b).any() and not np.signbit(b).all()  # the case is exercised


def test_empty_and_degenerate_frames():
    for H, W in ((0, 5), (5, 0), (1, 1)):
        z = np.zeros((H, W, 3), np.float32)
        out = filter_irradiance(z, np.ones((H, W), np.float32), z, 3, 0.05, 0.9)
        assert out.shape == (H, W, 3)


def test_accumulator_sums_and_mean_match_numpy():
    rng = np.random.default_rng(3)
    acc = Accumulator()
    total, halves = np.zeros((6, 5, 3)), [np.zeros((6, 5, 3)), np.zeros((6, 5, 3))]
    for i in range(7):
        img = (rng.standard_normal((6, 5, 3)) * 10.0 ** rng.integers(-8, 8, (6, 5, 3))).astype(np.float32)
        img[0, 0, 0] = np.nan if i == 3 else img[0, 0, 0]
        acc.add(img, "k")
        om.accumulate_numpy(total, halves[i % 2], img)
        assert acc._sum.tobytes() == total.tobytes()
        assert acc.mean().tobytes() == om.mean_numpy(total, i + 1).tobytes()
    for a, b in zip(acc._halves, halves):
        assert a.tobytes() == b.tobytes()
    acc.add(np.ones((6, 5, 3)), "k")  # float64 frames take numpy's path, same sums
    assert acc.count == 8
