"""The numpy ray-vs-bounding-spheres test that common.kernels.bounding_spheres replaced."""
from __future__ import annotations

import numpy as np


def any_hit_numpy(o, d, c, r):
    oc = c[None, :, :] - o[:, None, :]
    tca = np.einsum("nek,nk->ne", oc, d)
    d2 = np.einsum("nek,nek->ne", oc, oc) - tca * tca
    inside = np.einsum("nek,nek->ne", oc, oc) <= r[None, :] ** 2
    hit = inside | ((tca > 0) & (d2 <= r[None, :] ** 2))
    return hit.any(axis=1)
