"""Luminance: the CIE Y of linear sRGB, as Mitsuba 3 weighs colours (emitter power, sampling
densities, the guide's statistics). Defined once; ``common.lights`` re-exports it."""
from __future__ import annotations

import numpy as np

LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)  # linear sRGB -> Y (Mitsuba's luminance)


def luminance(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float64)
    wr, wg, wb = LUMINANCE_WEIGHTS
    return rgb[..., 0] * wr + rgb[..., 1] * wg + rgb[..., 2] * wb
