"""Aiming caustic photons at the mirror and glass objects (worker.caustics), compiled: the
cone each photon's target sphere subtends from its emission point, and the pdf of the
direction it took under the mixture of all targets' cones (Jarosz 2002 §3) — per photon, with
no (photons × targets × 3) temporaries.

Sums of three products run left to right and the mixture over targets in target order (numpy's
einsum and pairwise sums round some of them differently in the last bit).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point

_TINY = 1e-300  # distances below this are clamped (a point at a sphere's centre)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cone(px, py, pz, cx, cy, cz, radius):
    """(x, y, z to the centre, its length clamped, cosine of the cone's half-angle: -1 from
    inside the sphere)."""
    x = cx - px
    y = cy - py
    z = cz - pz
    dist = math.sqrt(x * x + y * y + z * z)
    far = max(dist, _TINY)
    s = radius / far
    sin2 = min(max(s * s, 0.0), 1.0)
    cos_max = -1.0 if dist <= radius else math.sqrt(1.0 - sin2)
    return x, y, z, far, cos_max


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mixture_pdf(px, py, pz, dx, dy, dz, centres, radii):
    targets = radii.shape[0]
    two_pi = 2 * np.pi
    acc = 0.0
    for t in range(targets):
        x, y, z, far, cos_max = _cone(px, py, pz, centres[t, 0], centres[t, 1], centres[t, 2], radii[t])
        cos_d = (dx * x + dy * y + dz * z) / far
        if cos_max == -1.0 or cos_d >= cos_max:
            acc += 1.0 / (two_pi * (1.0 - cos_max))
    return acc / targets


@njit(cache=True, nogil=True, error_model="numpy")
def aimed_emission(pos, nrm, u, centres, radii, emitter, area, radiance, total, center, eps, ulps, out_d, out_pdf,
                   out_flux, out_o) -> None:
    """Photon n's emission aimed at the targets (worker.caustics): the cone target
    min(⌊u[n, 2]·T⌋, T - 1) subtends from pos[n] (the whole sphere from inside it), the
    direction uniform in it (u[n, 3], u[n, 4]) in world space, and its solid-angle pdf under the
    mixture of all targets' cones (the cones that contain it count); for a photon of an area emitter (``area[n]``) the flux
    radiance[emitter[n]] · max(cos, 0) · total[emitter[n]] / pdf and the origin offset off the
    emitter toward the direction, else flux 0 and the origin ``pos[n]`` — worker.caustics'
    numpy form's arithmetic, in its order (its cosine's three products summed left to right,
    where numpy's einsum added x and z first: the flux of a tilted emitter's photon may differ
    in the last bit)."""
    targets = radii.shape[0]
    two_pi = 2 * np.pi
    for n in range(pos.shape[0]):
        px, py, pz = pos[n, 0], pos[n, 1], pos[n, 2]
        t = min(int(u[n, 2] * targets), targets - 1)
        x, y, z, far, cos_max = _cone(px, py, pz, centres[t, 0], centres[t, 1], centres[t, 2], radii[t])
        cz = 1 - u[n, 3] * (1 - cos_max)
        r = math.sqrt(max(0.0, 1 - cz * cz))
        phi = two_pi * u[n, 4]
        dx, dy, dz = shading_frame.to_world(r * math.cos(phi), r * math.sin(phi), cz, x / far, y / far, z / far)
        out_d[n, 0], out_d[n, 1], out_d[n, 2] = dx, dy, dz
        pdf = _mixture_pdf(px, py, pz, dx, dy, dz, centres, radii)
        out_pdf[n] = pdf
        if area[n]:
            e = emitter[n]
            nx, ny, nz = nrm[n, 0], nrm[n, 1], nrm[n, 2]
            s = max(dx * nx + dy * ny + dz * nz, 0.0) * total[e] / pdf
            for c in range(3):
                out_flux[n, c] = radiance[e, c] * s
            out_o[n, 0], out_o[n, 1], out_o[n, 2] = offset_point(px, py, pz, nx, ny, nz, dx, dy, dz, center, eps, ulps)
        else:
            for c in range(3):
                out_flux[n, c] = 0.0
            out_o[n, 0], out_o[n, 1], out_o[n, 2] = px, py, pz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _disk_mixture_pdf(px, py, pz, dx, dy, dz, centres, radii):
    """Area pdf, in the plane across unit d, of a point drawn as :func:`distant_emission` draws
    it: the mixture of the targets' shadow disks (each the disk its sphere casts along d)."""
    targets = radii.shape[0]
    acc = 0.0
    for t in range(targets):
        x = px - centres[t, 0]
        y = py - centres[t, 1]
        z = pz - centres[t, 2]
        a = x * dx + y * dy + z * dz  # off the plane through the centre: measured across d only
        x -= a * dx
        y -= a * dy
        z -= a * dz
        r = radii[t]
        if x * x + y * y + z * z <= r * r * (1.0 + 1e-9):  # (a point drawn on the rim keeps its disk)
            acc += 1.0 / (np.pi * max(r * r, _TINY))
    return acc / targets


@njit(cache=True, nogil=True, error_model="numpy")
def distant_emission(d, u, centres, radii, center, radius, out_o, out_pdf) -> None:
    """Photon n of a distant light (a sun: parallel rays along unit ``d[n]``) aimed at the
    targets: a point uniform on the shadow disk of target min(⌊u[n, 2]·T⌋, T - 1) — its centre
    and radius, in the plane across d[n] — at radius r·√u[n, 3] and angle 2π·u[n, 4]; its area
    pdf under the mixture of all targets' disks (every disk that holds it counts: a ray that
    meets a sphere crosses its disk); the origin moved back along -d[n] out of the scene's
    bounding sphere (``center``, ``radius``), so the ray meets whatever shades the target."""
    targets = radii.shape[0]
    two_pi = 2 * np.pi
    for n in range(d.shape[0]):
        dx, dy, dz = d[n, 0], d[n, 1], d[n, 2]
        t = min(int(u[n, 2] * targets), targets - 1)
        sx, sy, sz, tx, ty, tz = shading_frame.basis(dx, dy, dz)
        rho = radii[t] * math.sqrt(u[n, 3])
        phi = two_pi * u[n, 4]
        a, b = rho * math.cos(phi), rho * math.sin(phi)
        px = centres[t, 0] + a * sx + b * tx
        py = centres[t, 1] + a * sy + b * ty
        pz = centres[t, 2] + a * sz + b * tz
        out_pdf[n] = _disk_mixture_pdf(px, py, pz, dx, dy, dz, centres, radii)
        # back to the plane that touches the bounding sphere upstream (a little beyond it)
        back = (px - center[0]) * dx + (py - center[1]) * dy + (pz - center[2]) * dz + 1.01 * radius
        back = max(back, 0.0)
        out_o[n, 0], out_o[n, 1], out_o[n, 2] = px - back * dx, py - back * dy, pz - back * dz
