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
    b² = box mean over the filter's window of (d² - c·v), at least 0     (c = ``filter_select``),
    a = b² / (b² + v),  smoothed over 3×3,     pixel = filtered mean - a · d  (RGB).

d is the filtered minus the raw running mean, so a = 0 keeps the filtered mean and a = 1 gives
the raw one; b²/(b² + v) is the weight that minimizes the mean squared error of the blend when
the filter's own variance is small beside the raw mean's (the James–Stein shrinkage of the raw
mean towards the filtered one, as in Rousselle, Knaus & Zwicker 2012's per-pixel selection
between filters by estimated error). d² - v estimates b² without bias, its mean over the window
(the bias of a filter varies at the filter's scale) makes it far less noisy, and c > 1 asks for
evidence beyond the noise before giving up any filtering: on a flat wall the estimate is noise,
and its false alarms cost more than the bias they would remove. As frames accumulate v falls
like 1/frames, a bias b ≠ 0 stands out and a → 1: the running mean is consistent wherever the
filter is biased, filtered wherever it is not.
"""
from __future__ import annotations

import numpy as np

from igi.master.kernels.filter_selection import select as select_kernel

MIN_FRAMES = 3  # frames before a pixel is weighed: a variance of two degrees of freedom at least (with one, the blend lost on cornell-box)


def select(mean: np.ndarray, shares: tuple | None) -> np.ndarray:
    """The running ``mean`` (H, W, 3) float32 with each pixel's filter share blended as above;
    ``shares``: (share sums (H, W, 3), luminance squares (H, W), frames, c, window reach) from
    ``EdgeStoppingGuide.shares_learnt``, or None (then ``mean`` itself)."""
    if shares is None:
        return mean
    sh, sh2, count, c, reach = shares
    if count < MIN_FRAMES or c <= 0 or sh.shape != mean.shape:
        return mean
    out = np.empty(mean.shape, np.float32)
    select_kernel(mean, sh, sh2, float(count), float(c), int(reach), out)
    return out
