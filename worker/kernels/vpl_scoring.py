"""Scoring candidate VPLs against camera points (worker.vpl_importance): the per-pair loops of
shading.contribution_per_vpl, over every (camera point, candidate) pair of a set batch.

:func:`pair_luminance` — each pair's luminance toward the eye (unshadowed, or with its shadow
ray's answer and BSDF factors);
:func:`systematic_pairs` — per candidate, ``samples`` pairs drawn in proportion to it (one
uniform per candidate, evenly spaced), in two passes over the pairs: a batch of sets has ~10⁶
pairs, where numpy's argsort and temporaries cost more than the scoring;
:func:`unique_runs` — the distinct pairs drawn (each traced once).
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
    points (column_u[j] + s)/samples of its cumulative weight (s = 0..samples-1), the pairs of a
    column taken in their order. Writes each draw's pair index and what it stands for
    (W_j / samples), column by column; returns how many were written (out arrays: m · samples).

    Two passes in pair order with a running sum per column (no sort: a counting sort's scatter
    and gather over ~10⁶ pairs missed the cache on every pair)."""
    n = pj.shape[0]
    total = np.zeros(m)
    last = np.full(m, -1, np.int64)
    for k in range(n):
        total[pj[k]] += weight[k]
        last[pj[k]] = k
    slot = np.empty(m, np.int64)  # first output position of each drawn column
    out = 0
    for j in range(m):
        slot[j] = out
        if total[j] > 0.0:
            out += samples
    c = np.zeros(m)
    s = np.zeros(m, np.int64)
    target = np.empty(m)  # each column's next target, kept: no division per pair
    for j in range(m):
        target[j] = column_u[j] / samples * total[j]
    for k in range(n):
        j = pj[k]
        if not total[j] > 0.0:
            continue
        sj = s[j]
        if sj == samples:
            continue
        if k == last[j]:  # the column's last pair takes every target left
            while sj < samples:
                out_draw[slot[j] + sj] = k
                sj += 1
        else:
            w = weight[k]
            if not (c[j] + w <= target[j]):
                while True:
                    out_draw[slot[j] + sj] = k
                    sj += 1
                    if sj == samples:
                        break
                    target[j] = (column_u[j] + sj) / samples * total[j]
                    if c[j] + w <= target[j]:
                        break
            c[j] += w
        s[j] = sj
    for j in range(m):
        if total[j] > 0.0:
            share = total[j] / samples
            for q in range(samples):
                out_share[slot[j] + q] = share
    return out


@njit(cache=True, nogil=True)
def unique_runs(draw, out_unique, out_inverse):
    """The distinct values of ``draw`` where equal values only ever stand next to each other
    (systematic_pairs' draws: a column's draws never go back): out_unique[:u] in first-seen
    order, draw[q] == out_unique[out_inverse[q]]; returns u. np.unique without its sort."""
    u = 0
    for q in range(draw.shape[0]):
        if u == 0 or draw[q] != out_unique[u - 1]:
            out_unique[u] = draw[q]
            u += 1
        out_inverse[q] = u - 1
    return u
