"""Progressive accumulation (master.accumulation), compiled: one pass that adds a float32
frame to the float64 running sum and to its half's sum, and one that writes the float32 mean.

Why: numpy made one pass per sum plus a float64 temporary for the mean; the float64
additions and the final division are the same operations per element, so the results are
bit-identical (tests/master/test_master_kernels.py). Flat (contiguous, raveled) arrays.
``error_model="numpy"``: the mean's division is not checked for 0 (count >= 1).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def add_frame(total, half, img) -> None:
    """total += img; half += img (float64 sums of a float32 frame, element by element)."""
    for i in range(img.shape[0]):
        v = np.float64(img[i])
        total[i] += v
        half[i] += v


@njit(cache=True, nogil=True, error_model="numpy")
def mean(total, count, out) -> None:
    """out = float32(total / count)."""
    c = np.float64(count)
    for i in range(total.shape[0]):
        out[i] = np.float32(total[i] / c)
