"""The numpy originals of worker.kernels.vpl_scoring (test oracles, not product code)."""
from __future__ import annotations

import numpy as np

from igi.common.lights import luminance


def pair_luminance(pi, pj, w, blocked, factor, color, eye_weight) -> np.ndarray:
    rgb = color[pj] * eye_weight[pi]
    if len(factor):
        rgb = rgb * factor
    lum = np.where(blocked, 0.0, luminance(rgb) * w) if len(blocked) else luminance(rgb) * w
    return np.maximum(np.nan_to_num(lum, nan=0.0, posinf=0.0, neginf=0.0), 0.0)


def systematic_pairs_sorted(pj, weight, m, samples, column_u):
    """Per column with a positive total, ``samples`` draws ∝ weight by a stable sort of the pairs
    by column and a walk along each column (same sums in the same order as the compiled
    scoring: its exact reference)."""
    order = np.argsort(pj, kind="stable")
    total = np.zeros(m)
    for k in range(len(pj)):
        total[pj[k]] += weight[k]
    count = np.bincount(pj, minlength=m)
    start = np.concatenate([[0], np.cumsum(count)])
    draw, share = [], []
    for j in range(m):
        if not total[j] > 0.0:
            continue
        p, last, c = start[j], start[j + 1] - 1, 0.0
        for s in range(samples):
            target = (column_u[j] + s) / samples * total[j]
            while p < last and c + weight[order[p]] <= target:
                c += weight[order[p]]
                p += 1
            draw.append(order[p])
            share.append(total[j] / samples)
    return np.array(draw, np.int64), np.array(share)


def acceptance(phi, target, mix, floor):
    """vpl_importance.acceptance's solve in numpy (phi finite, >= 0, some > 0; target < n)."""
    n = len(phi)
    a = np.sort(mix * phi)[::-1]
    rest = np.cumsum(a[::-1])[::-1]
    c = np.arange(n)
    free = target - c - (n - c) * floor
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(free > 0, rest / free, np.inf)
    below = np.concatenate([[np.inf], a[:-1]])
    ok = (a < (1 - floor) * tau) & (below >= (1 - floor) * tau) & (rest > 0) & np.isfinite(tau)
    if not ok.any():
        return None
    return np.clip(floor + mix * phi / tau[np.argmax(ok)], 0.0, 1.0)
