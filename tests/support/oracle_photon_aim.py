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


def aimed_emission(pos, nrm, u, centres, radii, emitter, area, radiance, total, offset):
    """worker.caustics' numpy emission before worker.kernels.photon_aim.aimed_emission: (d, pdf,
    flux, origin) of each photon aimed at the targets (``offset``: Geometry.offset)."""
    from igi.common.lights import to_world
    from tests.support import photon_aim_steps as steps

    n = len(pos)
    cm, axis = np.empty(n), np.empty((n, 3))
    steps.chosen_cones(pos, np.ascontiguousarray(u[:, 2]), centres, radii, cm, axis)
    cz = 1 - u[:, 3] * (1 - cm)
    r = np.sqrt(np.maximum(0, 1 - cz * cz))
    phi = 2 * np.pi * u[:, 4]
    d = to_world(np.stack([r * np.cos(phi), r * np.sin(phi), cz], axis=1), axis)
    pdf = np.empty(n)
    steps.cone_mixture_pdf(pos, d, centres, radii, pdf)
    flux = np.zeros((n, 3))
    o = pos.copy()
    a = np.nonzero(area)[0]
    # (the product's sum of three products, left to right: numpy's einsum adds x and z first)
    cos_e = d[a, 0] * nrm[a, 0] + d[a, 1] * nrm[a, 1] + d[a, 2] * nrm[a, 2]
    flux[a] = radiance[emitter[a]] * (np.maximum(cos_e, 0) * total[emitter[a]] / pdf[a])[:, None]
    o[a] = offset(pos[a], nrm[a], d[a])
    return d, pdf, flux, o
