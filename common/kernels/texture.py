"""Bitmap texture lookups (common.scene.Texture.eval), compiled: Mitsuba's conventions (v up,
repeat wrap, texel centres at half-integers), float32 filtering like the numpy form it replaced
(every bounce of every tile looks textures up: the numpy form's ~20 passes per lookup were a
tenth of a textured room's eye paths)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def lookup(img, uv, su, sv, ou, ov, nearest, out):
    """``out[i]`` = the (H, W, 3) float32 image at uv[i] scaled by (su, sv), offset by (ou, ov)."""
    h, w = img.shape[0], img.shape[1]
    flat = img.reshape(h * w * 3)
    for i in range(uv.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = texel(flat, 0, h, w, uv[i, 0], uv[i, 1], su, sv, ou, ov, nearest)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def texel(flat, base, h, w, u0, v0, su, sv, ou, ov, nearest):
    """The float32 RGB of the (h, w, 3) image stored row-major at ``flat[base:]`` at (u0, v0)
    scaled by (su, sv), offset by (ou, ov): bilinear between texel centres, or ``nearest``."""
    one = np.float32(1.0)
    u = u0 * su + ou
    v = v0 * sv + ov
    u = u - math.floor(u)
    v = v - math.floor(v)
    x = u * w
    y = (1.0 - v) * h  # row 0 of the bitmap is v = 1
    if nearest:
        xi = min(max(np.int64(x), 0), w - 1)
        yi = min(max(np.int64(y), 0), h - 1)
        q = base + (yi * w + xi) * 3
        return flat[q], flat[q + 1], flat[q + 2]
    x -= 0.5
    y -= 0.5
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    fx = np.float32(x - fx0)
    fy = np.float32(y - fy0)
    x0 = np.int64(fx0) % w
    y0 = np.int64(fy0) % h
    x1 = (x0 + 1) % w
    y1 = (y0 + 1) % h
    q00 = base + (y0 * w + x0) * 3
    q01 = base + (y0 * w + x1) * 3
    q10 = base + (y1 * w + x0) * 3
    q11 = base + (y1 * w + x1) * 3
    top = flat[q00] * (one - fx) + flat[q01] * fx
    bot = flat[q10] * (one - fx) + flat[q11] * fx
    r = top * (one - fy) + bot * fy
    top = flat[q00 + 1] * (one - fx) + flat[q01 + 1] * fx
    bot = flat[q10 + 1] * (one - fx) + flat[q11 + 1] * fx
    g = top * (one - fy) + bot * fy
    top = flat[q00 + 2] * (one - fx) + flat[q01 + 2] * fx
    bot = flat[q10 + 2] * (one - fx) + flat[q11 + 2] * fx
    b = top * (one - fy) + bot * fy
    return r, g, b
