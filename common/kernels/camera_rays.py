"""Primary rays of Mitsuba's perspective camera (common.camera), compiled: the per-pixel
sub-pixel rotation of accumulated frames and the film-to-camera directions, in one pass per
tile instead of ~15 numpy passes. The camera-to-world rotation stays numpy's matrix product
(BLAS's summation order, which a loop here would not reproduce bit for bit)."""
from __future__ import annotations

import math

from numba import njit

_KERNEL = dict(cache=True, nogil=True, error_model="numpy")


@njit(**_KERNEL)
def rotated_jitter(tile, jx, jy, px, py, out) -> None:
    """out[i] = (tile[py % 8, px % 8] + (jx, jy)) mod 1: the frame's jitter point rotated by
    the pixel's offset in the 8 x 8 Sobol' tile (common.camera.pixel_jitter)."""
    for i in range(px.shape[0]):
        x = tile[py[i] % 8, px[i] % 8, 0] + jx
        y = tile[py[i] % 8, px[i] % 8, 1] + jy
        out[i, 0] = x - math.floor(x)
        out[i, 1] = y - math.floor(y)


@njit(**_KERNEL)
def film_directions(px, py, jit, per_pixel, width, height, tan_half, out) -> None:
    """Camera-space directions through pixels (px, py) at sub-pixel ``jit`` (row i, or row 0
    for all when not ``per_pixel``): ((1 - 2 sx) t, (1 - 2 sy) t / aspect, 1)."""
    aspect = width / height
    for i in range(px.shape[0]):
        r = i if per_pixel else 0
        sx = (px[i] + jit[r, 0]) / width
        sy = (py[i] + jit[r, 1]) / height
        out[i, 0] = (1 - 2 * sx) * tan_half
        out[i, 1] = (1 - 2 * sy) * tan_half / aspect
        out[i, 2] = 1.0


@njit(**_KERNEL)
def normalize_rows(d) -> None:
    """d[i] /= |d[i]| (numpy's norm: the squares summed in order)."""
    for i in range(d.shape[0]):
        n = math.sqrt(d[i, 0] * d[i, 0] + d[i, 1] * d[i, 1] + d[i, 2] * d[i, 2])
        d[i, 0] /= n
        d[i, 1] /= n
        d[i, 2] /= n
