"""Frame assembly (tiles -> full frame -> filtered image) and accumulation."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.frame import TileBuffers
from igi.common.params import make_params, params_to_dict
from igi.master.accumulation import Accumulator, accumulation_key, jitter_for, sequence_spec
from igi.master.frame_assembly import (LARGEST_TASK_PIXELS, SMALLEST_TASK_PIXELS, TASKS_PER_THREAD, FrameAssembler,
                                       filter_weight, task_pixels_for, task_tiles, tile_pixel_count)


@pytest.mark.parametrize("w,h,n,px", [(64, 48, 3, 4096), (65, 47, 3, 50), (7, 5, 4, 3), (2, 2, 3, 10), (640, 480, 3, 4096)])
def test_tiles_cover_every_pixel_once(w, h, n, px):
    seen = np.zeros((h, w), int)
    for t in task_tiles(w, h, n, px):
        xs, ys = t.pixels(n, w, h)
        assert len(xs) == tile_pixel_count(t, n, w, h) > 0
        seen[ys, xs] += 1
    assert (seen == 1).all()


@pytest.mark.parametrize("w,h", [(640, 480), (1920, 1080), (320, 240)])
def test_task_size_is_the_largest_that_keeps_every_thread_supplied(w, h):
    """Few threads: the largest tasks (fewest per-bounce overheads); many: smaller, so the frames
    in flight still hold TASKS_PER_THREAD tasks per thread; never below the smallest size."""
    sizes = [task_pixels_for(w * h, t, 3) for t in range(1, 1000)]
    assert sizes[0] == LARGEST_TASK_PIXELS and sizes[-1] == SMALLEST_TASK_PIXELS
    assert all(b <= a for a, b in zip(sizes, sizes[1:]))  # more threads: never larger tasks
    for threads, px in enumerate(sizes, 1):
        tasks = len(task_tiles(w, h, 5, px))
        if px > SMALLEST_TASK_PIXELS:  # the policy chose it: the open frames supply every thread
            assert 3 * tasks >= TASKS_PER_THREAD * threads * 0.9
    # fewer frames in flight: each frame is cut finer
    assert task_pixels_for(640 * 480, 16, 1) < task_pixels_for(640 * 480, 16, 3)


def test_assembler_scatters_and_completes():
    w, h, n = 17, 11, 3
    asm = FrameAssembler(w, h, n)
    tiles = task_tiles(w, h, n, 12)
    for i, t in enumerate(tiles):
        xs, ys = t.pixels(n, w, h)
        val = np.stack([xs, ys, np.full_like(xs, t.k)], 1).astype(np.float32)
        bufs = TileBuffers(val, val, val, np.ones(len(xs), np.float32), np.tile([0, 0, 1], (len(xs), 1)).astype(np.float32))
        assert asm.add(t, bufs) == (i == len(tiles) - 1)
        assert asm.add(t, bufs) == asm.complete  # a duplicate is ignored
    yy, xx = np.mgrid[0:h, 0:w]
    assert np.array_equal(asm.buffers["reflectance"][..., 0], xx)
    assert np.array_equal(asm.buffers["reflectance"][..., 1], yy)
    assert np.array_equal(asm.buffers["reflectance"][..., 2], (yy % n) * n + xx % n)
    with pytest.raises(ValueError):
        asm.add(tiles[0].__class__(0, 0, 0, 1, 1), TileBuffers(*(np.zeros((5, 3), np.float32),) * 3,
                                                                 np.zeros(5, np.float32), np.zeros((5, 3), np.float32)))


def test_filter_window_one_is_reflectance_times_irradiance_plus_unfiltered():
    w, h, n = 9, 6, 3
    asm = FrameAssembler(w, h, n)
    rng = np.random.default_rng(0)
    for t in task_tiles(w, h, n):
        p = tile_pixel_count(t, n, w, h)
        asm.add(t, TileBuffers(*(rng.random((p, 3), dtype=np.float32) for _ in range(3)),
                               np.ones(p, np.float32), np.tile([0, 0, 1], (p, 1)).astype(np.float32)))
    b = asm.buffers
    img = asm.image(params_to_dict(make_params(filter_window=1)))
    assert np.allclose(img, b["reflectance"] * b["irradiance"] + b["unfiltered"])
    # the default window (interleave size) averages flat irradiance over 3x3 neighbours
    img3 = asm.image(make_params())
    assert not np.allclose(img3, img)


def _lobe_reference(b: dict, window: int, dt: float, nt: float, w: float) -> np.ndarray:
    """The split lobe's rule, written out per pixel: a pixel with a lobe averages its own and its
    continuous neighbours' lobes (only those that have one), blends by w, and adds it (a miss adds
    its own)."""
    from tests.support.oracle_master import continuous_neighbours

    H, W = b["depth"].shape
    out = np.zeros((H, W, 3), np.float64)
    for y in range(H):
        for x in range(W):
            lc = b["lobe"][y, x]
            if lc[0] < 0:
                continue
            if not np.isfinite(b["depth"][y, x]):  # a miss keeps its own
                out[y, x] = lc
                continue
            acc, cnt = lc.astype(np.float64), 1
            for j, i in continuous_neighbours(b, y, x, window, dt, nt):
                if b["lobe"][j, i, 0] >= 0:
                    acc, cnt = acc + b["lobe"][j, i], cnt + 1
            out[y, x] = w * acc / cnt + (1 - w) * lc
    return out


@pytest.mark.parametrize("weight_index", [0, 100])
def test_split_lobes_are_filtered_over_the_neighbours_that_have_one_and_added(weight_index):
    """A lobe is averaged only with continuous neighbours that carry one (a diffuse material beside
    it on the same plane must not dim it, nor get its reflection), then added over the compose;
    the wire path (lobe section on some tiles only) and the float path give the same image."""
    from igi.common.codec import encode

    rng = np.random.default_rng(3)
    w, h, n = 23, 17, 3
    params = params_to_dict(make_params(interleave=n, consistent=True))
    tiles = task_tiles(w, h, n, 12)
    wire, copy, plain = FrameAssembler(w, h, n), FrameAssembler(w, h, n), FrameAssembler(w, h, n)
    for t in tiles:
        p = tile_pixel_count(t, n, w, h)
        f = lambda: rng.random((p, 3), dtype=np.float32)  # noqa: E731
        depth = np.where(rng.random(p) < 0.1, np.inf, 1.0 + 0.02 * rng.random(p)).astype(np.float32)
        normal = np.tile(np.float32([0, 0, 1]), (p, 1))
        normal[rng.random(p) < 0.1] = [1, 0, 0]
        lobe = np.where(rng.random((p, 1)) < 0.6, 5.0 * f(), np.float32(-1.0)).astype(np.float32)
        if t.k == 1:
            lobe[:] = -1.0  # a tile without lobes: its payload has no lobe section
        b = TileBuffers(f(), f(), f(), depth, normal, lobe)
        wire.add_wire(t, encode(b))
        copy.add_wire(t, encode(b))
        plain.add_wire(t, encode(TileBuffers(b.reflectance, b.irradiance, b.unfiltered, depth, normal)))
    bufs = copy.buffers  # as decoded (reading them turns ``copy`` into the float path)
    img, img_plain, img_float = (a.image(params, weight_index) for a in (wire, plain, copy))
    lobe = _lobe_reference(bufs, n, params["depth_threshold"], params["normal_threshold"],
                           filter_weight(params, weight_index))
    assert 0.4 < (bufs["lobe"][..., 0] >= 0).mean() < 0.7 and (lobe > 0).mean() > 0.4
    np.testing.assert_allclose(img - img_plain, lobe, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(img, img_float)


def test_accumulator_mean_halves_and_reset():
    acc = Accumulator()
    assert acc.mean() is None and acc.halves() is None
    for i in range(4):
        acc.add(np.full((2, 2, 3), float(i), np.float32), key="a")
    assert np.allclose(acc.mean(), 1.5) and acc.count == 4
    even, odd = acc.halves()
    assert np.allclose(even, 1.0) and np.allclose(odd, 2.0)
    assert acc.relative_error() > 0
    acc.add(np.full((2, 2, 3), 10.0, np.float32), key="b")  # key change resets
    assert acc.count == 1 and np.allclose(acc.mean(), 10.0)


def test_accumulator_does_not_drift_over_a_million_frames():
    acc = Accumulator()
    x = np.array([[[0.1, 1e-3, 123.456]]], np.float32)
    for _ in range(1000):
        acc.add(x)
    acc._sum *= 1000  # same state as 1e6 additions of x (float64 sums), without the time
    acc.count *= 1000
    assert np.array_equal(acc.mean(), x)
    assert np.max(np.abs(acc._sum / acc.count - x.astype(np.float64)) / x) < 1e-12


def test_sequence_advances_seed_and_jitter_only_when_accumulating():
    p = params_to_dict(make_params(seed=5))
    cam = np.eye(4)
    s0, s1 = (sequence_spec(i, i, cam, 40.0, 8, 6, p) for i in range(2))
    assert (s0.seed, s1.seed) == (5, 6) and s0.jitter == (0.5, 0.5) and s1.jitter == jitter_for(1) != (0.5, 0.5)
    assert accumulation_key(s0) == accumulation_key(s1)
    q = dict(p, accumulate=False)
    a, b = (sequence_spec(i, i, cam, 40.0, 8, 6, q) for i in range(2))
    assert a.seed == b.seed == 5 and a.jitter == b.jitter
    moved = sequence_spec(2, 0, np.diag([1.0, 1, 1, 1]) * 2, 40.0, 8, 6, p)
    assert accumulation_key(moved) != accumulation_key(s0) and moved.seed == s0.seed
    assert all(0 <= c < 1 for i in range(1, 50) for c in jitter_for(i))
