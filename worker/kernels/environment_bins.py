"""The environment guide's equal-area direction bins (worker.env_guide), defined once: the numpy
callers (the guide's histogram and pdf, worker.portals) and the compiled eye paths' MIS weights
of lobe rays escaping to a guided sky (kernels.eye_paths) bin a direction the same way, bit for
bit (one atan2, numba's, for both)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import environment_map as env_map

BINS_Z, BINS_PHI = 16, 32  # equal-area bins: uniform in cos θ and φ about the world z axis
UNIFORM_SHARE = 0.5  # the guide's mixture: this share uniform (or the sky's map), the rest the histogram
_UNIFORM_PDF = UNIFORM_SHARE / (4 * np.pi)
_TWO_PI = 2 * np.pi


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def direction_bin(dx, dy, dz) -> int:
    """The bin of a unit world direction: cos θ = z in BINS_Z equal steps, φ = atan2(y, x) in
    [0, 2π) in BINS_PHI (a NaN coordinate: bin row or column 0, never outside the histogram)."""
    z = min(max(dz, -1.0), 1.0)
    sz = (z + 1) * 0.5 * BINS_Z
    bz = min(np.int64(sz), BINS_Z - 1) if sz >= 0.0 else 0
    phi = math.atan2(dy, dx)  # in [-π, π]: np.mod(φ, 2π) is φ + 2π below 0, φ above
    if phi < 0.0:
        phi += _TWO_PI
    sp = phi / _TWO_PI * BINS_PHI
    bp = min(np.int64(sp), BINS_PHI - 1) if sp >= 0.0 else 0
    return bz * BINS_PHI + bp


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def guide_pdf(density, env, dx, dy, dz) -> float:
    """The guide's mixture q(ω) per steradian (``density``: the histogram's pdf per bin): its
    UNIFORM_SHARE uniform over the sphere, or drawn from the environment map ``env`` where the
    sky is one (``common.kernels.environment_map``; an empty map: none)."""
    base = _UNIFORM_PDF if env[0].shape[0] == 0 else UNIFORM_SHARE * env_map.pdf(env, dx, dy, dz)
    return base + (1 - UNIFORM_SHARE) * density[direction_bin(dx, dy, dz)]


@njit(cache=True, nogil=True, error_model="numpy")
def direction_bins(d, out) -> None:
    """:func:`direction_bin` of each row of ``d`` (n, 3) into ``out`` (n,) int64."""
    for i in range(d.shape[0]):
        out[i] = direction_bin(d[i, 0], d[i, 1], d[i, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def guide_pdfs(density, env, d, out) -> None:
    """:func:`guide_pdf` of each row of ``d`` (n, 3) into ``out`` (n,)."""
    for i in range(d.shape[0]):
        out[i] = guide_pdf(density, env, d[i, 0], d[i, 1], d[i, 2])
