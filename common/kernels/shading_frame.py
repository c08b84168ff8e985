"""The local shading frame of a unit normal (Duff et al. 2017, "Building an orthonormal basis,
revisited"), compiled: the scalar transforms the kernels share and the array forms
common.lights.to_local / to_world call (once per bounce of every tile, so the numpy form's
stacks and einsums were a visible share of the eye paths)."""
from __future__ import annotations

from numba import njit

_KERNEL = dict(cache=True, nogil=True, error_model="numpy")


@njit(**_KERNEL, inline="always")
def basis(nx, ny, nz):
    """Tangents (s, t) of unit normal n: ``sx, sy, sz, tx, ty, tz``."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return 1.0 + sign * nx * nx * a, sign * b, -sign * nx, b, sign + ny * ny * a, -ny


@njit(**_KERNEL, inline="always")
def to_local(wx, wy, wz, nx, ny, nz):
    """w in the shading frame of unit normal n."""
    sx, sy, sz, tx, ty, tz = basis(nx, ny, nz)
    return wx * sx + wy * sy + wz * sz, wx * tx + wy * ty + wz * tz, wx * nx + wy * ny + wz * nz


@njit(**_KERNEL, inline="always")
def to_world(lx, ly, lz, nx, ny, nz):
    """Local direction l of the shading frame of unit normal n, in world space."""
    sx, sy, sz, tx, ty, tz = basis(nx, ny, nz)
    return lx * sx + ly * tx + lz * nx, lx * sy + ly * ty + lz * ny, lx * sz + ly * tz + lz * nz


@njit(**_KERNEL)
def to_local_many(w, n, out):
    for i in range(w.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = to_local(w[i, 0], w[i, 1], w[i, 2], n[i, 0], n[i, 1], n[i, 2])


@njit(**_KERNEL)
def to_world_many(v, n, out):
    for i in range(v.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = to_world(v[i, 0], v[i, 1], v[i, 2], n[i, 0], n[i, 1], n[i, 2])
