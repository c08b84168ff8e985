"""The numpy forms of the final gather's per-tile steps around the level finder
(worker.final_gather.near_arrivals and carry_back (now carry_batches) before they were compiled into
worker.kernels.final_gather_levels): oracles for tests/worker/test_final_gather.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.worker.arrivals import Arrivals
from igi.worker.final_gather import COMPENSATION_MAX_LEVEL, COMPENSATION_ROULETTE_LEVEL


def near_arrivals_numpy(end, rays, level, clamp_d2: float, max_depth: int, rng) -> Arrivals | None:
    ok, hits = rays.rows, rays.hits
    if len(ok) == 0:
        return None
    lv = np.broadcast_to(np.asarray(level, np.int64), (len(end),))[ok]
    near = hits.valid & (hits.t < np.sqrt(clamp_d2)) & ~rays.delta & (lv > 0)
    if max_depth >= 0:
        near &= end.segments[ok] + 2 <= max_depth
    rolled = lv >= COMPENSATION_ROULETTE_LEVEL
    if rolled.any():
        near &= ~rolled | (rng.random(len(near)) < 0.5)
    sel = np.nonzero(near)[0]
    if len(sel) == 0:
        return None
    t = hits.t[sel]
    share = np.clip(1.0 - t * t / clamp_d2, 0.0, 1.0) / np.where(rolled[sel], 0.5, 1.0)
    child = np.where(lv[sel] < COMPENSATION_MAX_LEVEL, lv[sel] + 1, 0)
    return Arrivals(hits.position[sel], hits.ns[sel], hits.ng[sel], hits.material[sel], hits.uv[sel], t,
                    rays.direction[sel], end.segments[ok[sel]] + 1, ok[sel], rays.weight[sel] * share[:, None], child)


def carry_back_numpy(sizes, parent, factor, gain, albedo: np.ndarray, irr: np.ndarray) -> None:
    stops = np.cumsum([0, *sizes])
    for i in range(len(sizes) - 1, 0, -1):
        radiance = albedo[stops[i]:stops[i + 1]] * irr[stops[i]:stops[i + 1]]
        if gain[i - 1] is not None:
            radiance *= gain[i - 1]
        rows = stops[i - 1] + parent[i - 1]
        np.add.at(irr, rows, bsdf.finite_or_zero(factor[i - 1] * radiance / np.maximum(albedo[rows], 1e-6)))
