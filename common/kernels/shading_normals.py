"""Light carried from the lights with shading normals (Veach 1997, §5.3, "non-symmetry due to
shading normals"): where a surface's shading normal ns differs from its geometric one ng — an
interpolated normal, a normal or bump map (common.kernels.bump_mapping) — light arriving from
wi is met by the surface in proportion to |wi·ng| (its true area), while the radiance the BSDF
reflects weighs it by |wi·ns|. Eye paths carry radiance and need nothing; what igi traces from
the lights does: a light walk's or photon's flux arriving at a surface is scaled by
|wi·ns| / |wi·ng| (:func:`incident_ratio`; a VPL, a stored photon), and one leaving it towards
wo by |wo·ng| / |wo·ns| beside the BSDF's value (:func:`exit_ratio`: a VPL's light toward a
receiver; :func:`adjoint_correction`: both, a light path's next bounce). Where ns is ng (a
triangle without vertex normals) each is exactly 1, and its callers skip it: such scenes
render bit for bit as before."""
from __future__ import annotations

from numba import njit

_KERNEL = dict(cache=True, nogil=True, error_model="numpy")
_GRAZING = 1e-9  # |w·n| below this: the direction runs along the surface


@njit(**_KERNEL, inline="always")
def _cos_ratio(wx, wy, wz, ax, ay, az, bx, by, bz):
    """|w·a| / |w·b|: 1 where a is b, 0 where w runs along b's plane."""
    if ax == bx and ay == by and az == bz:
        return 1.0
    cb = abs(wx * bx + wy * by + wz * bz)
    if not cb > _GRAZING:
        return 0.0
    return abs(wx * ax + wy * ay + wz * az) / cb


@njit(**_KERNEL, inline="always")
def incident_ratio(wx, wy, wz, sx, sy, sz, gx, gy, gz):
    """|w·ns| / |w·ng| for light arriving from w (1 where ns is ng; 0 along the true surface,
    where no light arrives)."""
    return _cos_ratio(wx, wy, wz, sx, sy, sz, gx, gy, gz)


@njit(**_KERNEL, inline="always")
def exit_ratio(wx, wy, wz, sx, sy, sz, gx, gy, gz):
    """|w·ng| / |w·ns| for light leaving toward w, whose BSDF value (f·|w·ns|) counted the
    shading normal's cosine where the true surface's belongs (1 where ns is ng; 0 along the
    shading plane, where the BSDF gave nothing)."""
    return _cos_ratio(wx, wy, wz, gx, gy, gz, sx, sy, sz)


@njit(**_KERNEL, inline="always")
def adjoint_correction(ix, iy, iz, ox, oy, oz, sx, sy, sz, gx, gy, gz):
    """The factor a light path's BSDF-sampled weight (f·|wo·ns| / pdf) takes on at a surface, wi
    toward where the light came from, wo where it goes: |wi·ns| |wo·ng| / (|wi·ng| |wo·ns|)."""
    if sx == gx and sy == gy and sz == gz:
        return 1.0
    return incident_ratio(ix, iy, iz, sx, sy, sz, gx, gy, gz) * exit_ratio(ox, oy, oz, sx, sy, sz, gx, gy, gz)


@njit(**_KERNEL)
def incident_ratios(w, ns, ng, out) -> None:
    """:func:`incident_ratio` per row (the numpy loops' form of what the compiled walks do)."""
    for i in range(w.shape[0]):
        out[i] = incident_ratio(w[i, 0], w[i, 1], w[i, 2], ns[i, 0], ns[i, 1], ns[i, 2], ng[i, 0], ng[i, 1], ng[i, 2])
