"""Scoring candidate VPLs against camera points (worker.vpl_importance): the per-pair loops of
shading.contribution_per_vpl, over every (camera point, candidate) pair of a set batch.

:func:`pair_luminance` — each pair's luminance toward the eye (unshadowed, or with its shadow
ray's answer and BSDF factors);
:func:`systematic_pairs` — per candidate, ``samples`` pairs drawn in proportion to it (one
uniform per candidate, evenly spaced), by a counting sort over the candidates: the pairs of a
batch of sets number ~10⁶, where numpy's argsort and temporaries cost more than the scoring.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS

_WR, _WG, _WB = LUMINANCE_WEIGHTS


@njit(cache=True, nogil=True, error_model="numpy")
def pair_luminance(pi, pj, w, blocked, factor, color, eye_weight, out):
    """out[k] = w_k · Y(colour_j ⊙ eye_weight_i ⊙ factor_k) of pair k = (i, j); 0 where
    blocked[k] or where that is not a positive finite number. ``blocked`` empty: none is;
    ``factor`` with no rows: 1."""
    use_blocked = blocked.shape[0] > 0
    use_factor = factor.shape[0] > 0
    for k in range(pi.shape[0]):
        if use_blocked and blocked[k]:
            out[k] = 0.0
            continue
        i = pi[k]
        j = pj[k]
        r = color[j, 0] * eye_weight[i, 0]
        g = color[j, 1] * eye_weight[i, 1]
        b = color[j, 2] * eye_weight[i, 2]
        if use_factor:
            r *= factor[k, 0]
            g *= factor[k, 1]
            b *= factor[k, 2]
        v = (r * _WR + g * _WG + b * _WB) * np.float64(w[k])
        out[k] = v if (math.isfinite(v) and v > 0.0) else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def systematic_pairs(pj, weight, m, samples, column_u, out_draw, out_share):
    """Per column j with Σ weight > 0: ``samples`` draws among its pairs ∝ ``weight``, at the
    points (column_u[j] + s)/samples of its cumulative weight (s = 0..samples-1). Writes each
    draw's pair index and what it stands for (W_j / samples); returns how many were written
    (out arrays: m · samples)."""
    n = pj.shape[0]
    start = np.zeros(m + 1, np.int64)
    total = np.zeros(m)
    for k in range(n):
        start[pj[k] + 1] += 1
        total[pj[k]] += weight[k]
    for j in range(m):
        start[j + 1] += start[j]
    order = np.empty(n, np.int64)
    fill = start[:m].copy()
    for k in range(n):  # stable counting sort by column
        j = pj[k]
        order[fill[j]] = k
        fill[j] += 1
    out = 0
    for j in range(m):
        if not total[j] > 0.0:
            continue
        p = start[j]
        last = start[j + 1] - 1
        c = 0.0
        share = total[j] / samples
        for s in range(samples):
            target = (column_u[j] + s) / samples * total[j]
            while p < last and c + weight[order[p]] <= target:
                c += weight[order[p]]
                p += 1
            out_draw[out] = order[p]
            out_share[out] = share
            out += 1
    return out
