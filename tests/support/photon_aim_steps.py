"""The steps of worker.kernels.photon_aim.aimed_emission on their own, over arrays, through the
product's own cone and mixture helpers: what the tests check against the numpy original
(tests/support/oracle_photon_aim.py) and the mixture's normalization. (The product traces
no photon through them: aimed_emission fuses them.)"""
from __future__ import annotations

from numba import njit

from igi.worker.kernels.photon_aim import _cone, _mixture_pdf


@njit(nogil=True, error_model="numpy")
def chosen_cones(pos, choice, centres, radii, out_cos, out_axis) -> None:
    """Photon n aims at target t = min(⌊choice[n]·T⌋, T - 1): out_cos[n] the cosine of the
    half-angle of the cone that sphere subtends from pos[n] (-1 from inside it), out_axis[n]
    the unit direction to its centre."""
    targets = radii.shape[0]
    for n in range(pos.shape[0]):
        t = min(int(choice[n] * targets), targets - 1)
        x, y, z, far, cos_max = _cone(pos[n, 0], pos[n, 1], pos[n, 2], centres[t, 0], centres[t, 1],
                                      centres[t, 2], radii[t])
        out_cos[n] = cos_max
        out_axis[n, 0] = x / far
        out_axis[n, 1] = y / far
        out_axis[n, 2] = z / far


@njit(nogil=True, error_model="numpy")
def cone_mixture_pdf(pos, d, centres, radii, out) -> None:
    """out[n]: the solid-angle pdf of direction d[n] from pos[n] when a target is chosen
    uniformly and the direction uniformly in its cone (the cones that contain d[n] count; from
    inside a sphere its cone is the whole sphere)."""
    for n in range(pos.shape[0]):
        out[n] = _mixture_pdf(pos[n, 0], pos[n, 1], pos[n, 2], d[n, 0], d[n, 1], d[n, 2], centres, radii)
