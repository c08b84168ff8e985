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
    one = np.float32(1.0)
    for i in range(uv.shape[0]):
        u = uv[i, 0] * su + ou
        v = uv[i, 1] * sv + ov
        u = u - math.floor(u)
        v = v - math.floor(v)
        x = u * w
        y = (1.0 - v) * h  # row 0 of the bitmap is v = 1
        if nearest:
            xi = min(max(np.int64(x), 0), w - 1)
            yi = min(max(np.int64(y), 0), h - 1)
            for c in range(3):
                out[i, c] = img[yi, xi, c]
            continue
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
        for c in range(3):
            top = img[y0, x0, c] * (one - fx) + img[y0, x1, c] * fx
            bot = img[y1, x0, c] * (one - fx) + img[y1, x1, c] * fx
            out[i, c] = top * (one - fy) + bot * fy
