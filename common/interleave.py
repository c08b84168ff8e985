"""Interleaved sampling bookkeeping (paper §4.2).

An n x n interleave gives image pixel (x, y) the set k = (y % n) * n + x % n. Sub-image k
holds the pixels of set k; tasks are rectangles (:class:`Tile`) of one sub-image, so a
worker that renders tiles of equal k reuses its cached VPLs and photons. Sub-image pixel
(sx, sy) is image pixel (sx*n + k%n, sy*n + k//n): a tile is a strided slice of the image.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, MutableMapping

import numpy as np

from igi.common.frame import BUFFER_NAMES, Tile, TileBuffers


def set_index(x, y, n: int):
    """Interleave set of image pixel (x, y); works on ints and numpy arrays alike."""
    return (y % n) * n + x % n


def sub_image_size(width: int, height: int, n: int, k: int) -> tuple[int, int]:
    """(sw, sh): pixels per row and rows of sub-image k (0 where the image is smaller than n)."""
    if not 0 <= k < n * n:
        raise ValueError(f"set index {k} outside 0..{n * n - 1}")
    kx, ky = k % n, k // n
    # Count of x in [0, width) with x % n == kx.
    return max(0, (width - kx + n - 1) // n), max(0, (height - ky + n - 1) // n)


def make_tiles(width: int, height: int, n: int, tile_w: int, tile_h: int) -> list[Tile]:
    """Tiles of tile_w x tile_h sub-image pixels covering every image pixel exactly once.

    Ordered by set k, then row-major inside the sub-image, so consecutive tasks share k.
    Edge tiles are clipped to the sub-image; empty sub-images (image smaller than n) get none.
    """
    if n < 1 or tile_w < 1 or tile_h < 1:
        raise ValueError(f"need n, tile_w, tile_h >= 1; got {n}, {tile_w}, {tile_h}")
    tiles = []
    for k in range(n * n):
        sw, sh = sub_image_size(width, height, n, k)
        for sy0 in range(0, sh, tile_h):
            for sx0 in range(0, sw, tile_w):
                tiles.append(Tile(k, sx0, sy0, min(sx0 + tile_w, sw), min(sy0 + tile_h, sh)))
    return tiles


def tile_slices(tile: Tile, n: int, width: int, height: int) -> tuple[slice, slice, int, int]:
    """(rows, cols, h, w): the image slices holding the tile's pixels (clipped to the image),
    and the tile's pixel rows and columns, so ``image[rows, cols]`` is the tile, shaped
    (h, w, ...) in the row-major order of :meth:`Tile.pixels`."""
    sw, sh = sub_image_size(width, height, n, tile.k)
    sx1, sy1 = min(tile.sx1, sw), min(tile.sy1, sh)
    w, h = max(0, sx1 - tile.sx0), max(0, sy1 - tile.sy0)
    kx, ky = tile.k % n, tile.k // n
    x0, y0 = tile.sx0 * n + kx, tile.sy0 * n + ky
    return slice(y0, y0 + (h - 1) * n + 1 if h else y0, n), slice(x0, x0 + (w - 1) * n + 1 if w else x0, n), h, w


def _get(out_arrays, name: str) -> np.ndarray | None:
    """``out_arrays``'s buffer ``name``; None for the lobe where arrays keep none (it is optional)."""
    if isinstance(out_arrays, Mapping):
        return out_arrays.get(name) if name == "lobe" else out_arrays[name]
    return getattr(out_arrays, name, None) if name == "lobe" else getattr(out_arrays, name)


def scatter(tile: Tile, n: int, buffers: TileBuffers,
            out_arrays: MutableMapping[str, np.ndarray] | TileBuffers) -> None:
    """Write a task's per-pixel buffers into full-frame arrays.

    out_arrays maps each of BUFFER_NAMES to an (H, W, ...) array (a dict, or any object with
    those attributes, e.g. a TileBuffers of full-frame arrays). Vectorized: one strided
    slice assignment per buffer.
    """
    H, W = _get(out_arrays, "depth").shape[:2]
    rows, cols, h, w = tile_slices(tile, n, W, H)
    if len(buffers) != h * w:
        raise ValueError(f"tile {tile} has {h * w} pixels in a {W}x{H} image, buffers have {len(buffers)}")
    for name in BUFFER_NAMES:
        dst = _get(out_arrays, name)
        if dst is None:
            if buffers.has_lobe:
                raise ValueError("the tile has split lobes and the frame's arrays keep none")
            continue
        src = np.asarray(getattr(buffers, name))
        dst[rows, cols] = src.reshape((h, w) + src.shape[1:])


def extract(tile: Tile, n: int, arrays: Mapping[str, np.ndarray] | TileBuffers) -> TileBuffers:
    """The inverse of :func:`scatter`: a tile's pixels of full-frame arrays, as TileBuffers."""
    H, W = _get(arrays, "depth").shape[:2]
    rows, cols, h, w = tile_slices(tile, n, W, H)
    parts = {}
    for name in BUFFER_NAMES:
        a = _get(arrays, name)
        if a is None:
            continue
        a = a[rows, cols]
        parts[name] = np.ascontiguousarray(a.reshape((h * w,) + a.shape[2:]))
    return TileBuffers(**parts)


def task_tile_size(width: int, height: int, n: int, target_pixels: int) -> tuple[int, int]:
    """(tile_w, tile_h) in sub-image pixels for tasks of about ``target_pixels`` pixels.

    Roughly square tiles (coherent eye rays), then evened out so a sub-image splits into
    equal tiles instead of leaving a thin remainder strip.
    """
    if target_pixels < 1 or n < 1:
        raise ValueError(f"need target_pixels >= 1 and n >= 1; got {target_pixels}, {n}")
    sw, sh = max(1, math.ceil(width / n)), max(1, math.ceil(height / n))
    tw = min(sw, max(1, round(math.sqrt(target_pixels))))
    th = min(sh, max(1, round(target_pixels / tw)))
    if th == sh:  # sub-image too short for a square: widen to keep the pixel budget
        tw = min(sw, max(1, round(target_pixels / th)))
    tw = math.ceil(sw / math.ceil(sw / tw))
    th = math.ceil(sh / math.ceil(sh / th))
    return tw, th
