"""What defines one frame, and the per-pixel buffers a task returns.

A frame's image depends only on (scene version, camera, parameters, seed): any worker that
renders task (frame, k, tile) returns the same buffers.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

BUFFER_NAMES = ("reflectance", "irradiance", "unfiltered", "lobe", "depth", "normal")
# A lobe value below zero: the pixel has no filtered lobe (radiance is never negative).
NO_LOBE = -1.0
SEED_MODULUS = 2**31  # frame seeds stay inside common.params' declared range


@dataclass(frozen=True)
class FrameSpec:
    frame: int  # frame number (monotonic per master)
    seed: int  # scrambling seed of the Sobol stream; same seed -> same VPL/photon sets
    camera_to_world: tuple  # 16 floats, row-major 4x4
    fov_x: float  # degrees
    width: int
    height: int
    params: dict  # params_to_dict(Params)
    scene_version: int = 0
    jitter: tuple = (0.5, 0.5)  # sub-pixel position of the eye ray (0.5, 0.5 = centre)


def frame_seed(base_seed: int, index: int) -> int:
    """The seed of accumulation frame ``index`` after a reset with seed ``base_seed`` (each
    accumulated frame a new realization of the VPL/photon sets; master.accumulation)."""
    return (int(base_seed) + int(index)) % SEED_MODULUS


def accumulation_index(spec: FrameSpec) -> int:
    """Frames accumulated before this one (0 while the view changes): the inverse of
    :func:`frame_seed`."""
    if not spec.params.get("accumulate", True):
        return 0
    return (spec.seed - int(spec.params.get("seed", 0))) % SEED_MODULUS


@dataclass(frozen=True)
class Tile:
    """A rectangle of the sub-image of interleave index k.

    Sub-image k of an n x n interleave holds pixels (x, y) with x % n == k % n and
    y % n == k // n; sub-image pixel (sx, sy) is image pixel (sx*n + k%n, sy*n + k//n).
    """

    k: int
    sx0: int
    sy0: int
    sx1: int  # exclusive
    sy1: int

    def pixels(self, n: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates (x, y) of the tile's pixels, row-major, clipped to the image
        (read-only arrays: a frame's tiles come back every frame, so they are made once)."""
        return _tile_pixels(self.k, self.sx0, self.sy0, self.sx1, self.sy1, n, width, height)


@dataclass
class TileBuffers:
    """Per-pixel results of one task, in the order of Tile.pixels()."""

    reflectance: np.ndarray  # (P, 3) float32: albedo x specular-chain throughput at the end point
    irradiance: np.ndarray  # (P, 3) float32: filtered part, radiance = reflectance * irradiance
    unfiltered: np.ndarray  # (P, 3) float32: emission seen, specular-chain emission, ...
    depth: np.ndarray  # (P,) float32: eye-path length to the end point (inf = miss)
    normal: np.ndarray  # (P, 3) float32: shading normal at the end point
    # (P, 3) float32: a split glossy coat's lobe radiance, filtered on its own and added after
    # the filter (not over the reflectance: a textured layer's would skew it); NO_LOBE where none
    lobe: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.lobe is None:
            self.lobe = np.full(np.shape(self.depth) + (3,), NO_LOBE, np.float32)

    def __len__(self) -> int:
        return len(self.depth)

    @property
    def has_lobe(self) -> bool:
        """Whether any pixel carries a lobe (the wire then holds the lobe section)."""
        return bool(len(self.lobe)) and bool(np.any(np.asarray(self.lobe)[:, 0] >= 0))


@functools.lru_cache(maxsize=1024)
def _tile_pixels(k: int, sx0: int, sy0: int, sx1: int, sy1: int, n: int, width: int,
                 height: int) -> tuple[np.ndarray, np.ndarray]:
    kx, ky = k % n, k // n
    xs = np.arange(sx0, sx1) * n + kx
    ys = np.arange(sy0, sy1) * n + ky
    xs = xs[xs < width]
    ys = ys[ys < height]
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    xx, yy = xx.ravel(), yy.ravel()
    xx.flags.writeable = False
    yy.flags.writeable = False
    return xx, yy

