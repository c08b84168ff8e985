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


def systematic_pairs(pj, weight, m, samples, column_u):
    order = np.argsort(pj, kind="stable")
    cs = np.cumsum(weight[order])
    total = np.bincount(pj, weights=weight, minlength=m)
    count = np.bincount(pj, minlength=m)
    stop = np.cumsum(count)
    start = stop - count
    lit = np.nonzero(total > 0)[0]
    if len(lit) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    base = np.where(start[lit] > 0, cs[np.maximum(start[lit] - 1, 0)], 0.0)
    at = base[:, None] + (column_u[lit][:, None] + np.arange(samples)[None, :]) / samples * total[lit, None]
    k = np.searchsorted(cs, at.ravel(), side="right")
    k = np.clip(k, np.repeat(start[lit], samples), np.repeat(stop[lit] - 1, samples))
    return order[k], np.repeat(total[lit] / samples, samples)


def systematic_pairs_sorted(pj, weight, m, samples, column_u):
    """The same draws by a stable sort of the pairs by column and a walk along each column (the
    compiled kernel's earlier form, kept as its exact reference: same sums in the same order)."""
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
