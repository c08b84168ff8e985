"""Assembling a frame on the master: tiles in, full-frame buffers and the filtered image out.

:class:`FrameAssembler` receives (tile, TileBuffers) pairs in any order, scatters them into
full-frame buffers (sub-image pixel (sx, sy) of set k lands on image pixel
(sx·n + k mod n, sy·n + k div n)), knows when every pixel has arrived, and produces the image:
discontinuity buffer over the irradiance (window ``filter_window``, -1 → n), multiplied by the
pixel's own reflectance, plus the unfiltered part (DESIGN.md §1, paper §4.3).

:func:`task_tiles` is THE task decomposition of a frame; the broker and ``render_local`` both
use it, so both paths render exactly the same tiles.
"""
from __future__ import annotations

import numpy as np

from common.frame import Tile, TileBuffers
from common.interleave import make_tiles, scatter, task_tile_size, tile_slices

DEFAULT_TASK_PIXELS = 4096  # ~20-50 ms of worker time at 22 VPLs on this machine's cores


def task_tiles(width: int, height: int, n: int, task_pixels: int = DEFAULT_TASK_PIXELS) -> list[Tile]:
    """The tasks of a frame: every sub-image k (k-major order) cut into tiles of about
    ``task_pixels`` pixels (``interleave.task_tile_size``), empty sub-images skipped."""
    tile_w, tile_h = task_tile_size(width, height, n, task_pixels)
    return make_tiles(width, height, n, tile_w, tile_h)


def tile_pixel_count(tile: Tile, n: int, width: int, height: int) -> int:
    """Pixels of ``tile`` inside a width x height image."""
    _, _, h, w = tile_slices(tile, n, width, height)
    return h * w


class FrameAssembler:
    """Full-frame buffers of one frame, filled tile by tile."""

    def __init__(self, width: int, height: int, n: int):
        if width < 1 or height < 1 or n < 1:
            raise ValueError(f"bad frame {width}x{height}, interleave {n}")
        self.width, self.height, self.n = width, height, n
        self.buffers: dict[str, np.ndarray] = {
            "reflectance": np.zeros((height, width, 3), np.float32),
            "irradiance": np.zeros((height, width, 3), np.float32),
            "unfiltered": np.zeros((height, width, 3), np.float32),
            "depth": np.full((height, width), np.inf, np.float32),
            "normal": np.zeros((height, width, 3), np.float32),
        }
        self.expected = width * height
        self.received = 0
        self._tiles: set[Tile] = set()

    @property
    def complete(self) -> bool:
        return self.received >= self.expected

    def add(self, tile: Tile, buffers: TileBuffers) -> bool:
        """Scatter one tile; returns True when the frame is complete. A tile already added is
        ignored (duplicate); a tile whose pixel count does not match raises ValueError."""
        if tile in self._tiles:
            return self.complete
        count = tile_pixel_count(tile, self.n, self.width, self.height)
        if not 0 <= tile.k < self.n * self.n or len(buffers) != count:
            raise ValueError(f"tile {tile} holds {count} pixels, buffers have {len(buffers)}")
        scatter(tile, self.n, buffers, self.buffers)
        self._tiles.add(tile)
        self.received += count
        return self.complete

    def image(self, params, index: int = 0) -> np.ndarray:
        """The filtered image (H, W, 3) float32, linear radiance, of accumulation frame ``index``.

        With ``consistent`` accumulation the discontinuity buffer's share fades after
        ``filter_frames`` frames: frame i uses w·filtered + (1-w)·raw irradiance with
        w = min(1, T/(i+1)), so the filter's blur (a bias no averaging removes) vanishes from
        the running mean like T·ln(N/T)/N, while the first frames stay smooth.
        """
        from master.discontinuity_buffer import compose, filter_irradiance, resolve_window

        p = params if isinstance(params, dict) else _asdict(params)
        window = resolve_window(int(p["filter_window"]), self.n)
        b = self.buffers
        w = filter_weight(p, index)
        if w <= 0.0 or window <= 1:
            return compose(b["reflectance"], b["irradiance"], b["unfiltered"])
        filtered = filter_irradiance(b["irradiance"], b["depth"], b["normal"], window,
                                     float(p["depth_threshold"]), float(p["normal_threshold"]))
        if w < 1.0:
            filtered = w * filtered + (1.0 - w) * b["irradiance"]
        return compose(b["reflectance"], filtered, b["unfiltered"])


def filter_weight(params: dict, index: int) -> float:
    """Share of the filtered irradiance in accumulation frame ``index`` (see FrameAssembler.image)."""
    t = int(params.get("filter_frames", -1))
    if t < 0 or index < t or not params.get("consistent", False) or not params.get("accumulate", True):
        return 1.0
    return t / (index + 1.0)


def _asdict(params) -> dict:
    from common.params import params_to_dict

    return params_to_dict(params)
