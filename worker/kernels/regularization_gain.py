"""The regularized lobes' energy gain per point (worker.regularization.regularization_gain), its
per-point arithmetic in one compiled pass: interpolate each point's lobe-albedo tables at its
cosine, the light widening loses, the original's albedo over that, bounded.

In numpy it was a dozen passes over (points × 3) temporaries, ~1.1 ms a call for the ~3,000
widened senders of a modern-hall task's final-gather levels (3% of its frame). The same float64
operations in the same order as the numpy form (tests/support/oracle_regularization.py), so
bit for bit the same gains.
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def gains(tables, group, mu, spec, conductor, albedo, mu_bins, gain_min, gain_max, rows, out) -> None:
    """``out[rows[q]]`` (3 channels) = the gain of point q: ``tables`` (G, mu_bins, 6) each
    group's lobe albedo at the original roughness (channels 0-2) and the widened one (3-5) over
    the bins' cosines, ``group`` (N,) point q's table, ``mu`` (N,) its cosine, ``spec`` (N, 3)
    its specular factor, ``conductor`` (N,) all lobe (else a plastic: its total albedo
    ``albedo`` (N, 3)). A point whose cosine is NaN keeps ``out``'s row (the numpy form raised
    IndexError there)."""
    top = mu_bins - 1.0
    for q in range(group.shape[0]):
        x = mu[q] * mu_bins - 0.5
        if x != x:  # a non-finite direction: no cosine to read the tables at, its gain stays 1
            continue
        x = min(max(x, 0.0), top)  # np.clip
        i = min(int(x), mu_bins - 2)
        f = x - i
        t = tables[group[q]]
        r = rows[q]
        for c in range(3):
            s_orig = t[i, c] * (1 - f) + t[i + 1, c] * f
            s_reg = t[i, c + 3] * (1 - f) + t[i + 1, c + 3] * f
            d = s_orig - s_reg
            lost = spec[q, c] * (d if (d >= 0.0 or d != d) else 0.0)  # np.maximum(d, 0): NaN kept
            full = spec[q, c] * s_orig if conductor[q] else albedo[q, c]
            g = full / (full - lost)
            v = g if (math.isfinite(g) and g > 0) else 1.0
            out[r, c] = min(max(v, gain_min), gain_max)
