"""The numpy regularization gain that worker.kernels.regularization_gain replaced, kept as the
test oracle (worker.regularization's tables, keys and grouping, the per-point passes in numpy)."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.scene import ROUGHCONDUCTOR
from igi.worker.regularization import (_KEY_WEIGHTS, ALBEDO_MIN_COS, GAIN_MAX, GAIN_MIN, MU_BINS, _lobe_keys,
                                       _table, mu_dirs)


def _at(table: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """(N, C) the (MU_BINS, C) table linearly interpolated at cosines ``mu`` (held constant past
    the ends)."""
    x = np.clip(mu * MU_BINS - 0.5, 0.0, MU_BINS - 1.0)
    i = np.minimum(x.astype(np.int64), MU_BINS - 2)
    f = (x - i)[:, None]
    return table[i] * (1 - f) + table[i + 1] * f


def regularization_gain(surface: bsdf.SurfacePoints, regularized: bsdf.SurfacePoints,
                        wi: np.ndarray) -> np.ndarray:
    """(N, 3) factor that gives the widened BSDFs ``regularized`` (:func:`regularized_senders` of
    ``surface``) the directional albedo of the originals at ``wi`` (local; a VPL's incident
    direction, or by reciprocity the direction a receiver reflects toward): original albedo /
    (original albedo - what widening the lobe loses). 1 where the lobe was not widened; within
    [GAIN_MIN, GAIN_MAX]."""
    gain = np.ones((len(surface), 3))
    rows = np.nonzero(regularized.alpha != surface.alpha)[0]
    if len(rows) == 0:
        return gain
    orig = surface if len(rows) == len(surface) else surface.subset(rows)
    alpha = regularized.alpha[rows]
    # the cosine bsdf.albedo evaluates at, so the lobe tables and the total albedo agree
    mu = np.clip(np.abs(np.asarray(wi, dtype=np.float64)[rows, 2]), ALBEDO_MIN_COS, 1.0)
    keys = _lobe_keys(orig)
    combos = np.column_stack([keys, alpha.astype(np.float64)])
    # one lobe per material, as a rule: group rows by a 1-D projection of their keys (a sort of
    # floats, not np.unique over rows), each group's first row stands for it
    _, first, inverse = np.unique(combos @ _KEY_WEIGHTS, return_index=True, return_inverse=True)
    s_orig = np.empty((len(rows), 3))
    s_reg = np.empty((len(rows), 3))
    for c, r0 in enumerate(first):
        sel = np.nonzero(inverse == c)[0] if len(first) > 1 else slice(None)
        # both tables side by side: one interpolation pass over the points, not two
        both = np.concatenate([_table(orig, keys[r0], int(r0), float(orig.alpha[r0])),
                               _table(orig, keys[r0], int(r0), float(alpha[r0]))], axis=1)
        s = _at(both, mu[sel])
        s_orig[sel], s_reg[sel] = s[:, :3], s[:, 3:]
    spec = np.asarray(orig.specular, dtype=np.float64)
    lost = spec * np.maximum(s_orig - s_reg, 0.0)
    # A conductor is all lobe; a plastic's smooth albedo estimate is its diffuse layer plus its
    # coat's single-scattering reflectance at the original roughness (the coat tables, which the
    # widened lobe keeps): the original's total directional albedo.
    full = np.where((orig.kind == ROUGHCONDUCTOR)[:, None], spec * s_orig, bsdf.albedo(orig, mu_dirs(mu)))
    with np.errstate(divide="ignore", invalid="ignore"):
        g = full / (full - lost)
    gain[rows] = np.clip(np.where(np.isfinite(g) & (g > 0), g, 1.0), GAIN_MIN, GAIN_MAX)
    return gain
