"""The numpy original of worker.kernels.photon_aim (a test oracle, not product code)."""
from __future__ import annotations

import numpy as np


def cone_mixture_pdf(origin, dirs, centres, radii):
    """Pdf (solid angle) of choosing a direction uniformly in one of the target cones; with
    each cone's cos θ_max and the unit directions to the centres, per (origin, target)."""
    to_c = centres[None, :, :] - origin[:, None, :]
    dist = np.linalg.norm(to_c, axis=2)
    inside = dist <= radii[None, :]
    sin2 = np.clip((radii[None, :] / np.maximum(dist, 1e-300)) ** 2, 0, 1)
    cos_max = np.where(inside, -1.0, np.sqrt(1 - sin2))
    solid = 2 * np.pi * (1 - cos_max)
    cos_d = np.einsum("nk,ntk->nt", dirs, to_c) / np.maximum(dist, 1e-300)
    in_cone = inside | (cos_d >= cos_max)
    return (in_cone / solid).sum(axis=1) / len(radii), cos_max, to_c / np.maximum(dist, 1e-300)[:, :, None]
