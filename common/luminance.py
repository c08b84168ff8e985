"""Luminance: the CIE Y of linear sRGB, as Mitsuba 3 weighs colours (emitter power, sampling
densities, the guide's statistics). Defined once; ``common.lights`` re-exports it."""
from __future__ import annotations

import numpy as np

LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)  # linear sRGB -> Y (Mitsuba's luminance)

# CIE XYZ -> linear sRGB (D65), the matrix Mitsuba 3 converts with.
XYZ_TO_LINEAR_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                               [-0.969256, 1.875991, 0.041556],
                               [0.055648, -0.204043, 1.057311]])
# The equal-energy illuminant E at unit luminance (XYZ = 1, 1, 1) in linear sRGB: (1.2048, 0.9483, 0.9089), a pink
# beside sRGB's D65 white. Mitsuba 3's RGB variants read an emitter's uniform <spectrum> as this light.
EQUAL_ENERGY_SRGB = XYZ_TO_LINEAR_SRGB @ np.ones(3)


def luminance(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float64)
    wr, wg, wb = LUMINANCE_WEIGHTS
    return rgb[..., 0] * wr + rgb[..., 1] * wg + rgb[..., 2] * wb
