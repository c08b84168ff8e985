"""How much of the discontinuity buffer a pixel of the running mean keeps: the filtered mean
where the filter's bias is small beside the noise it removes, the raw mean where it is not.

The discontinuity buffer (paper §4.3) trades noise for bias: averaging a pixel's irradiance with
its neighbours' removes most of one frame's noise, and adds their difference. The
edge-stopping guide (``master.edge_stopping``) keeps neighbours whose *own* means differ by less
than their noise; many small differences of one sign — a sun's terminator on a ball, the
curvature of a penumbra — still add up to a bias, which no number of frames removes, while the
raw running mean's noise falls like 1/frames. With the camera still the master measures that
bias: per pixel, the filter's share of each frame (its radiance less the radiance of its own
raw irradiance and lobe, ``master.kernels.discontinuity.finish_sub``) summed over the frames:

    d = mean share (its luminance),  v = its variance over the frames / (frames - 1),
    B = box mean over the filter's window of d² - (c + 2/(frames - 1))·v     (c = ``filter_select``),
    V = box mean of v over the same window,
    a = max(B, 0) / (max(B, 0) + V),  smoothed over 3×3,     pixel = filtered mean - a · d  (RGB).

d is the filtered minus the raw running mean, so a = 0 keeps the filtered mean and a = 1 gives
the raw one; b²/(b² + v) is the weight that minimizes the mean squared error of the blend when
the filter's own variance is small beside the raw mean's (the James–Stein shrinkage of the raw
mean towards the filtered one, as in Rousselle, Knaus & Zwicker 2012's per-pixel selection
between filters by estimated error). d² - v estimates b² without bias; its mean over the window
(the bias of a filter varies at the filter's scale) makes it far less noisy, and so does the
window's mean of v in the weight (one pixel's v from a few frames is itself noise). c > 1 asks
for evidence beyond the noise before giving up any filtering: on a flat wall the estimate is
noise, and its false alarms cost more than the bias they would remove; 2/(frames - 1) asks for
more while v has few degrees of freedom (its relative error is sqrt(2/(frames - 1))). As frames
accumulate v falls like 1/frames, a bias b ≠ 0 stands out and a → 1: the running mean is
consistent wherever the filter is biased, filtered wherever it is not.

Measured on the frames of one run each (filtered and raw means of the same frames, relMSE
against the Mitsuba references, half resolution): a sun-lit scene (tests/data/envmap/outdoor.xml)
0.23 / 0.67 / 0.62 of the filtered mean's error at 3 / 6 / 128 frames; grey-white-room 0.86,
cornell-box-glossy 0.93, cornell-box 0.97 at 64 frames; modern-hall, whose filter is right
everywhere, 1.00–1.03. Without the pooled V and the 2/(frames - 1) a pixel whose few frames
happened to agree took its raw noise back (modern-hall 1.27 at 3 frames).
"""
from __future__ import annotations

import numpy as np

from igi.master.kernels.filter_selection import select as select_kernel

MIN_FRAMES = 3  # frames before a pixel is weighed: a variance of two degrees of freedom at least


def select(mean: np.ndarray, shares: tuple | None) -> np.ndarray:
    """The running ``mean`` (H, W, 3) float32 with each pixel's filter share blended as above;
    ``shares``: (share sums, luminance squares, their layout, frames, c, window reach, scratch
    planes for a shape, the frames' (H, W)) from
    ``EdgeStoppingGuide.shares_learnt`` (sums in the frame planes' layout, ``master.frame_assembly``),
    or None (then ``mean`` itself)."""
    if shares is None:
        return mean
    sh, sh2, layout, count, c, reach, scratch, shape = shares
    n, pad, sw = layout[:3]
    if count < MIN_FRAMES or c <= 0 or tuple(shape) != mean.shape[:2]:
        return mean
    out = np.empty(mean.shape, np.float32)
    select_kernel(mean, sh, sh2, n, pad, sw, float(count), float(c), int(reach), scratch(mean.shape[:2]), out)
    return out
