"""One bounce of the paths that leave the lights — the light walks behind the VPLs
(worker.vpl) and the caustic photons (worker.caustics) — through the compiled
worker.kernels.light_paths."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry

from .kernels import light_paths

_NO_SURVIVAL = np.zeros((0, 0))


def continue_paths(sp: bsdf.SurfacePoints, geom: Geometry, sel: np.ndarray, rows: np.ndarray, pos: np.ndarray,
                   ns: np.ndarray, ng: np.ndarray, d: np.ndarray, o: np.ndarray, flux: np.ndarray, u: np.ndarray,
                   col: int, survival: np.ndarray | None = None, bounce: int = 0) -> np.ndarray:
    """Hits ``sel`` (of the per-hit arrays ``sp``, ``pos``, ``ns``, ``ng``) of paths ``rows``
    continue: their BSDF sampled (importance mode) with u[path, col : col + 3], Russian roulette
    on ``survival[path, bounce]`` where given, the path's flux, direction ``d`` and origin ``o``
    (float64 (paths, 3), C order: updated in place) set for the next ray. Returns the paths of
    ``sel`` whose flux still carries light, in order."""
    for a in (d, o, flux):
        if a.dtype != np.float64 or not a.flags.c_contiguous:
            raise ValueError("continue_paths updates d, o and flux in place: float64, C order")
    P, prow = bsdf.packed_rows(sp)
    out = np.empty(len(sel), np.int64)
    c = np.ascontiguousarray
    n = light_paths.continue_paths(P, prow, c(sel, np.int64), c(rows, np.int64), c(pos, np.float64),
                                   c(ns, np.float64), c(ng, np.float64), d, o, flux, c(u, np.float64), int(col),
                                   survival is not None, _NO_SURVIVAL if survival is None else c(survival, np.float64),
                                   int(bounce), *geom.offset_terms(), out)
    return out[:n]
