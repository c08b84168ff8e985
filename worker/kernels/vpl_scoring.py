"""Scoring candidate VPLs against camera points (worker.vpl_importance): the per-pair loops of
shading.contribution_per_vpl, over every (camera point, candidate) pair of a set batch.

:func:`scored_draws` — per candidate, ``samples`` of its pairs drawn in proportion to their
unshadowed luminance toward the eye (one uniform per candidate, evenly spaced), and the distinct
pairs drawn (each traced once): a batch of sets has ~10⁶ pairs and draws ~10⁵, so no pair list
is written — each set's (camera points × candidates) block is weighed, summed and walked down
its columns while it is in cache (a pair list through three passes cost twice as much);
:func:`pair_luminance` — the drawn pairs' luminance with their shadow ray's answer and BSDF
factors;
:func:`acceptance` — the candidates' acceptance probabilities from their scores (one sort, a
running sum and a scan: a dozen numpy calls on ~240 numbers cost ~0.1 ms a set).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS

from . import vpl_gather as vg

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
def scored_draws(x, ns, ng, off, side, row, vmax,
                 vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam,
                 vdepth, mis, light_pdf, area, direct_count, tables, row_tab, inv_tavg, col_lo, col_hi, lum,
                 color, eye_weight, samples, column_u, out_draw_j, out_share, out_inverse,
                 out_i, out_j, out_w, out_pl, out_plain):
    """The scoring's draws among every (row, column) pair of rows x × columns [col_lo[i],
    col_hi[i]) (rows and columns as vpl_gather.pair_weights takes them), with no pair list.
    Rows come in runs of one range (the scoring's sets, each its camera points against its
    candidates); no column may lie in the ranges of two runs. Per run:

    1. its rows weighed (vpl_gather._stage) and each live pair's unshadowed luminance toward the
       eye — :func:`pair_luminance`'s w · Y(colour_j ⊙ eye_weight_i) — kept in the run's (rows ×
       columns) scratch, each column's total summed in row order (branch-free: dead pairs weigh
       0, and only each column's last live row is remembered);
    2. per column with a positive total, ``samples`` draws among its live pairs ∝ luminance, at
       the points (column_u[j] + s)/samples of its running sum down the rows, the last live pair
       taking the targets left (a pair of weight 0 is never passed by the sum, so the dead ones
       are never drawn). Each draw's row, weight, light pdf and luminance are noted while the
       run's scratch is in cache.

    Then, column by column: each draw's column and share W_j/samples in out_draw_j/out_share,
    the distinct pairs drawn (a column's draws never go back: a repeat is its predecessor) in
    out_i … out_plain, each draw's distinct pair in ``out_inverse`` (all m · samples long: give
    it only the columns the rows' ranges hold, :func:`column_window`).
    Returns (draws, distinct pairs): bit for bit the draws of pair_weights' live pairs through
    :func:`pair_luminance` and a walk along each column in pair order."""
    n = x.shape[0]
    m = vpos.shape[0]
    # One staging for a whole run (its weights are read again when its columns are drawn).
    rows, width_max = 1, 1
    r0 = np.int64(0)  # (not a literal 0: _stage would compile once more for Literal[int](0))
    while r0 < n:
        r1 = _run_end(r0, n, col_lo, col_hi)
        rows = max(rows, r1 - r0)
        width_max = max(width_max, col_hi[r0] - col_lo[r0])
        r0 = r1
    staging = vg.staging_for(rows, width_max, vpos, vnormal, spot_cutoff, vdepth)
    sw, spl = staging[0], staging[1]  # (columns × rows)
    # (roulette arguments typed, not literal: see worker.kernels.eye_paths — a literal would
    # compile _stage once more; no culling planes: the scoring's rays are the caller's,
    # vpl_gather.pair_rays)
    weighed = ((x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi),
               (vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis,
                light_pdf, area, direct_count),
               (lum, 0.0, np.int64(0), np.int64(0), np.zeros((0, vg.LOBE_FIELDS), np.float32),
                np.zeros(0, np.float32), np.zeros(0)),
               (np.zeros((0, 4), np.float32), np.zeros(m + 1, np.int64)))
    cr = np.empty(m)
    cg = np.empty(m)
    cb = np.empty(m)
    for j in range(m):
        cr[j], cg[j], cb[j] = color[j, 0], color[j, 1], color[j, 2]
    plain = np.empty((rows, width_max))
    total = np.zeros(m)
    last = np.full(m, -1, np.int64)  # each column's last live row
    claimed = np.zeros(m, np.bool_)  # columns of a run seen already
    # draw s of column j at j · samples + s: its row, weight, light pdf, luminance
    d_row = np.empty(m * samples, np.int64)
    d_w = np.empty(m * samples, np.float32)
    d_pl = np.empty(m * samples, np.float32)
    d_plain = np.empty(m * samples)
    r0 = np.int64(0)  # (not a literal 0: _stage would compile once more for Literal[int](0))
    while r0 < n:
        r1 = _run_end(r0, n, col_lo, col_hi)
        lo = max(col_lo[r0], 0)
        width = col_hi[r0] - lo
        if width > 0:
            for j in range(lo, lo + width):
                if claimed[j]:
                    raise ValueError("scored_draws: a column lies in the ranges of two runs of rows")
                claimed[j] = True
            vg._weigh(r0, r1 - r0, weighed, staging)
            for b in range(r1 - r0):
                i = r0 + b
                e0, e1, e2 = eye_weight[i, 0], eye_weight[i, 1], eye_weight[i, 2]
                for a in range(width):  # branch-free (SIMD lanes)
                    j = lo + a
                    w = sw[a, b]
                    live = w >= 0.0
                    v = (cr[j] * e0 * _WR + cg[j] * e1 * _WG + cb[j] * e2 * _WB) * np.float64(w)
                    v = v if (live and math.isfinite(v) and v > 0.0) else 0.0
                    plain[b, a] = v
                    total[j] += v
                    last[j] = i if live else last[j]
            _draw_columns(r0, r1, lo, width, samples, column_u, total, last, plain, sw, spl, row,
                          d_row, d_w, d_pl, d_plain)
        r0 = r1
    out = 0
    u = 0
    for j in range(m):
        if not total[j] > 0.0:
            continue
        share = total[j] / samples
        prev = -1
        for q in range(j * samples, (j + 1) * samples):
            out_draw_j[out] = j
            out_share[out] = share
            if d_row[q] != prev:
                prev = d_row[q]
                out_i[u] = prev
                out_j[u] = j
                out_w[u] = d_w[q]
                out_pl[u] = d_pl[q]
                out_plain[u] = d_plain[q]
                u += 1
            out_inverse[out] = u - 1
            out += 1
    return out, u


@njit(cache=True, nogil=True)
def column_window(col_lo, col_hi, m):
    """[c0, c1): the columns that some row's range holds (c0 = c1 = 0 when none does). A chunk
    of the scoring's rows holds ~240 of the ~5000 candidates of a batch: its draws take those
    columns alone (their buffers, and the kernels' per-column copies, sized to them)."""
    c0, c1 = m, 0
    for i in range(col_lo.shape[0]):
        lo = max(col_lo[i], 0)
        if col_hi[i] > lo:
            c0 = min(c0, lo)
            c1 = max(c1, col_hi[i])
    return (c0, c1) if c1 > c0 else (0, 0)


@njit(cache=True, nogil=True, inline="always")
def _run_end(r0, n, col_lo, col_hi):
    """The end of the run of rows from r0 with r0's column range."""
    r1 = r0 + 1
    while r1 < n and col_lo[r1] == col_lo[r0] and col_hi[r1] == col_hi[r0]:
        r1 += 1
    return r1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _draw_columns(r0, r1, lo, width, samples, column_u, total, last, plain, sw, spl, row,
                  d_row, d_w, d_pl, d_plain) -> None:
    """Step 2 of :func:`scored_draws` for the columns of run [r0, r1) (weights from the
    staging ``sw``/``spl``, rows from r0)."""
    for a in range(width):
        j = lo + a
        tj = total[j]
        if not tj > 0.0:
            continue
        sj = 0
        cj = 0.0
        target = column_u[j] / samples * tj
        q0 = j * samples
        for i in range(r0, r1):
            v = plain[i - r0, a]
            if i == last[j]:  # the column's last live pair takes every target left
                while sj < samples:
                    _note(q0 + sj, i, r0, a, v, sw, spl, row, d_row, d_w, d_pl, d_plain)
                    sj += 1
                break
            if not (cj + v <= target):
                while True:
                    _note(q0 + sj, i, r0, a, v, sw, spl, row, d_row, d_w, d_pl, d_plain)
                    sj += 1
                    if sj == samples:
                        break
                    target = (column_u[j] + sj) / samples * tj
                    if cj + v <= target:
                        break
                if sj == samples:
                    break
            cj += v


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _note(q, i, r0, a, v, sw, spl, row, d_row, d_w, d_pl, d_plain) -> None:
    """Draw q is the pair (row i, staged column a) of luminance v: its row, weight and glossy
    light pdf read while the run is staged."""
    d_row[q] = i
    d_plain[q] = v
    d_w[q] = sw[a, i - r0]
    d_pl[q] = spl[a, i - r0] if row[i] == vg.ROW_GLOSSY else np.float32(0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def acceptance(phi, target, mix, floor, out) -> bool:
    """out[j] = min(1, floor + mix·phi[j]/τ) (at least 0), with τ such that Σ out ≈ target,
    for scores ``phi`` (finite, >= 0, some > 0; fewer than ``target`` is the caller's case):
    with the c largest mix·phi saturated, τ = Σ_{j>c} a_j / (target - c - (n - c)·floor), the c
    taken the first whose τ saturates exactly those c. False (``out`` untouched) when no c
    does: too few lit candidates to reach the target."""
    n = phi.shape[0]
    a = np.sort(mix * phi)[::-1]  # descending
    rest = np.empty(n)  # rest[c] = Σ_{j>=c} a_j, summed from the smallest
    acc = 0.0
    for c in range(n - 1, -1, -1):
        acc = acc + a[c] if c < n - 1 else a[c]
        rest[c] = acc
    for c in range(n):
        free = target - c - (n - c) * floor
        tau = rest[c] / free if free > 0 else np.inf
        below = a[c - 1] if c > 0 else np.inf
        edge = (1 - floor) * tau
        if a[c] < edge and below >= edge and rest[c] > 0 and math.isfinite(tau):
            for j in range(n):
                out[j] = min(max(floor + mix * phi[j] / tau, 0.0), 1.0)
            return True
    return False
