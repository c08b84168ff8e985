"""The numpy regularization gain that worker.kernels.regularization_gain replaced, kept as the
test oracle: the per-point passes in numpy on the product's own rows, cosines and lobe tables
(worker.regularization.widened_lobes)."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.scene import ROUGHCONDUCTOR
from igi.worker.regularization import GAIN_MAX, GAIN_MIN, MU_BINS, mu_dirs, widened_lobes


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
    widened = widened_lobes(surface, regularized, wi)  # the product's rows, cosines and tables
    if widened is None:
        return gain
    rows, orig, mu, tables, group = widened
    s_orig = np.empty((len(rows), 3))
    s_reg = np.empty((len(rows), 3))
    for c in range(len(tables)):
        sel = np.nonzero(group == c)[0] if len(tables) > 1 else slice(None)
        s = _at(tables[c], mu[sel])
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
