import numpy as np
import pytest

from igi.common.frame import Tile, TileBuffers
from igi.common.interleave import (extract, make_tiles, scatter, set_index, sub_image_size,
                               task_tile_size, tile_slices)

SIZES = [(64, 48, 3, 5, 4), (67, 50, 3, 7, 3), (10, 7, 4, 2, 2), (5, 3, 8, 3, 3), (1, 1, 1, 1, 1),
         (33, 17, 2, 100, 100), (2, 2, 3, 1, 1)]


def _full(H, W):
    return {"reflectance": np.zeros((H, W, 3), np.float32), "irradiance": np.zeros((H, W, 3), np.float32),
            "unfiltered": np.zeros((H, W, 3), np.float32), "depth": np.zeros((H, W), np.float32),
            "normal": np.zeros((H, W, 3), np.float32), "lobe": np.zeros((H, W, 3), np.float32)}


def _buffers_for(xs, ys):
    P = len(xs)
    pid = (ys * 1000 + xs).astype(np.float32)
    return TileBuffers(reflectance=np.stack([pid, pid + 0.25, pid + 0.5], 1),
                       irradiance=np.stack([xs, ys, pid], 1).astype(np.float32),
                       unfiltered=np.full((P, 3), 1, np.float32), depth=pid,
                       normal=np.stack([ys, xs, pid], 1).astype(np.float32),
                       lobe=np.where((xs % 2)[:, None] == 1, np.stack([pid + 0.75, pid, xs], 1),
                                     -1.0).astype(np.float32))


def test_set_index_matches_tile_convention():
    n = 3
    for k in range(9):
        xs, ys = Tile(k, 0, 0, 5, 5).pixels(n, 100, 100)
        assert np.all(set_index(xs, ys, n) == k)
    assert set_index(4, 7, 3) == 1 * 3 + 1


@pytest.mark.parametrize("W,H,n,tw,th", SIZES)
def test_sub_image_sizes_add_up_to_the_image(W, H, n, tw, th):
    total = 0
    for k in range(n * n):
        sw, sh = sub_image_size(W, H, n, k)
        xs, ys = Tile(k, 0, 0, sw, sh).pixels(n, W, H)
        assert len(xs) == sw * sh  # no pixel of the sub-image falls outside the image
        total += sw * sh
    assert total == W * H


@pytest.mark.parametrize("W,H,n,tw,th", SIZES)
def test_make_tiles_covers_every_pixel_exactly_once(W, H, n, tw, th):
    count = np.zeros((H, W), int)
    for t in make_tiles(W, H, n, tw, th):
        xs, ys = t.pixels(n, W, H)
        assert len(xs) > 0  # no empty tasks
        assert np.all(set_index(xs, ys, n) == t.k)
        np.add.at(count, (ys, xs), 1)
    assert np.all(count == 1)


def test_make_tiles_groups_tasks_by_set():
    ks = [t.k for t in make_tiles(64, 48, 3, 4, 4)]
    assert ks == sorted(ks)


@pytest.mark.parametrize("W,H,n,tw,th", SIZES)
def test_scatter_places_each_pixel_where_tile_pixels_says(W, H, n, tw, th):
    out = _full(H, W)
    for t in make_tiles(W, H, n, tw, th):
        xs, ys = t.pixels(n, W, H)
        scatter(t, n, _buffers_for(xs, ys), out)
    ys, xs = np.mgrid[0:H, 0:W]
    pid = (ys * 1000 + xs).astype(np.float32)
    np.testing.assert_array_equal(out["depth"], pid)
    np.testing.assert_array_equal(out["irradiance"][..., 0], xs)
    np.testing.assert_array_equal(out["normal"][..., 0], ys)
    np.testing.assert_array_equal(out["reflectance"][..., 2], pid + 0.5)


def test_scatter_into_tilebuffers_of_frames_and_extract_round_trip():
    W, H, n = 20, 13, 3
    full = TileBuffers(**_full(H, W))
    tiles = make_tiles(W, H, n, 3, 2)
    for t in tiles:
        xs, ys = t.pixels(n, W, H)
        scatter(t, n, _buffers_for(xs, ys), full)
    for t in tiles:
        xs, ys = t.pixels(n, W, H)
        back = extract(t, n, full)
        ref = _buffers_for(xs, ys)
        for name in ("reflectance", "irradiance", "unfiltered", "lobe", "depth", "normal"):
            np.testing.assert_array_equal(getattr(back, name), getattr(ref, name))


def test_scatter_refuses_to_drop_split_lobes():
    """Frame arrays without a lobe take tiles without one; a tile with lobes is refused, not cut."""
    out = _full(10, 10)
    del out["lobe"]
    t = Tile(0, 0, 0, 2, 2)
    xs, ys = t.pixels(3, 10, 10)
    b = _buffers_for(xs, ys)
    with pytest.raises(ValueError, match="lobes"):
        scatter(t, 3, b, out)
    b.lobe[:] = -1.0
    scatter(t, 3, b, out)


def test_scatter_rejects_wrong_pixel_count():
    out = _full(10, 10)
    t = Tile(0, 0, 0, 2, 2)
    xs, ys = np.arange(3), np.zeros(3, int)
    with pytest.raises(ValueError):
        scatter(t, 3, _buffers_for(xs, ys), out)


def test_tile_slices_for_clipped_tile():
    rows, cols, h, w = tile_slices(Tile(4, 2, 1, 10, 10), 3, 10, 8)
    # Sub-image 4 of a 10x8 image is 3x3 (x = 1,4,7; y = 1,4,7); the tile starting at
    # (2, 1) is clipped to x = 7, y = 4,7.
    assert (h, w) == (2, 1)
    img = np.arange(80).reshape(8, 10)
    assert img[rows, cols].tolist() == [[47], [77]]
    xs, ys = Tile(4, 2, 1, 10, 10).pixels(3, 10, 8)
    assert (ys * 10 + xs).tolist() == [47, 77]


@pytest.mark.parametrize("W,H,n,target", [(640, 480, 3, 1024), (640, 480, 1, 4096), (64, 8, 4, 256),
                                          (1920, 1080, 5, 2000), (7, 5, 3, 1), (100, 100, 2, 10**9)])
def test_task_tile_size_hits_target_and_splits_evenly(W, H, n, target):
    tw, th = task_tile_size(W, H, n, target)
    sw, sh = -(-W // n), -(-H // n)
    assert 1 <= tw <= sw and 1 <= th <= sh
    if target <= sw * sh:
        assert 0.4 * target <= tw * th <= 2.5 * target
    else:
        assert (tw, th) == (sw, sh)  # one tile per sub-image
    # No thin remainder: the last tile of a row/column is at least half as large as the rest.
    assert sw % tw == 0 or sw % tw >= tw / 2
    assert sh % th == 0 or sh % th >= th / 2
