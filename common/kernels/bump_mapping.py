"""Shading normals perturbed by a texture (Blinn 1978), as Mitsuba 3's ``normalmap`` and
``bumpmap`` perturb their nested BSDF's shading frame: compiled into hit reconstruction
(common.kernels.hit_surface.reconstruct), so every ray igi follows — eye paths, light walks,
photons, final gathers — shades a hit with the same perturbed normal.

The tables (common.bump_mapping.bump_tables): ``tri_row`` (F,) int32, a triangle's row of
``tangents`` (R, 6): its dp/du and dp/dv (-1: not perturbed; an empty array: no map in the
scene); ``maps`` (M, 14) float64 per material: kind (0 none, 1 normal map, 2 bump map), the
bitmap's base, height, width in ``pixels``, uv scale (2), offset (2), nearest, the bump scale,
whether to flip invalid normals, and a constant normal map's RGB (height 0)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.luminance import LUMINANCE_WEIGHTS

from .shading_frame import basis
from .texture import texel

_WR, _WG, _WB = LUMINANCE_WEIGHTS
NORMAL_MAP = 1
BUMP_MAP = 2
MAP_COLUMNS = 14


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _height(flat, base, h, w, xi, yi):
    """The luminance of texel (xi, yi), wrapped (Mitsuba's repeat)."""
    q = base + ((yi % h) * w + (xi % w)) * 3
    return _WR * flat[q] + _WG * flat[q + 1] + _WB * flat[q + 2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def height_gradient(flat, base, h, w, u0, v0, su, sv, ou, ov, nearest):
    """(∂height/∂u, ∂height/∂v) of the bitmap's luminance at (u0, v0): the derivative of the
    bilinear interpolation :func:`common.kernels.texture.texel` does (row 0 is v = 1, so the
    image's y runs against v), through the uv scale; 0 with ``nearest`` (piecewise constant)."""
    if nearest:
        return 0.0, 0.0
    u = u0 * su + ou
    v = v0 * sv + ov
    x = (u - math.floor(u)) * w - 0.5
    y = (1.0 - (v - math.floor(v))) * h - 0.5
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    fx = x - fx0
    fy = y - fy0
    x0 = np.int64(fx0)
    y0 = np.int64(fy0)
    f00 = _height(flat, base, h, w, x0, y0)
    f01 = _height(flat, base, h, w, x0 + 1, y0)
    f10 = _height(flat, base, h, w, x0, y0 + 1)
    f11 = _height(flat, base, h, w, x0 + 1, y0 + 1)
    d_dx = (f01 - f00) * (1.0 - fy) + (f11 - f10) * fy
    d_dy = (f10 - f00) * (1.0 - fx) + (f11 - f01) * fx
    return d_dx * w * su, -d_dy * h * sv


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _tangent(n0, n1, n2, d0, d1, d2):
    """dp/du made perpendicular to n and unit (Mitsuba's shading frame's s); any unit
    perpendicular where dp/du has no part off n (no uv on the triangle)."""
    k = n0 * d0 + n1 * d1 + n2 * d2
    t0, t1, t2 = d0 - n0 * k, d1 - n1 * k, d2 - n2 * k
    ln = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if ln > 1e-20 and math.isfinite(ln):
        return t0 / ln, t1 / ln, t2 / ln
    sx, sy, sz, _tx, _ty, _tz = basis(n0, n1, n2)
    return sx, sy, sz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def perturb(p, m, uv0, uv1, s0, s1, s2, g0, g1, g2, dx, dy, dz, tri_row, tangents, maps, pixels):
    """The shading normal (s0, s1, s2) of triangle ``p`` (material ``m``) at uv, hit by a ray
    along d, perturbed by the material's map; unchanged where it has none or the map gives no
    direction. With the map's ``flip_invalid_normals`` (Mitsuba's default) a perturbed normal
    facing away from wi = −d where the unperturbed one faces it (or the other way round) is
    mirrored about the unperturbed one (Schüssler et al. 2017), as Mitsuba does."""
    r = tri_row[p]
    if r < 0:
        return s0, s1, s2
    kind = maps[m, 0]
    base, h, w = np.int64(maps[m, 1]), np.int64(maps[m, 2]), np.int64(maps[m, 3])
    if kind == NORMAL_MAP:
        if h > 0:
            cr, cg, cb = texel(pixels, base, h, w, uv0, uv1, maps[m, 4], maps[m, 5], maps[m, 6], maps[m, 7],
                               maps[m, 8] != 0.0)
        else:
            cr, cg, cb = maps[m, 11], maps[m, 12], maps[m, 13]
        lx, ly, lz = 2.0 * cr - 1.0, 2.0 * cg - 1.0, 2.0 * cb - 1.0
        ta0, ta1, ta2 = _tangent(s0, s1, s2, tangents[r, 0], tangents[r, 1], tangents[r, 2])
        bi0, bi1, bi2 = s1 * ta2 - s2 * ta1, s2 * ta0 - s0 * ta2, s0 * ta1 - s1 * ta0  # n × s
        n0 = lx * ta0 + ly * bi0 + lz * s0
        n1 = lx * ta1 + ly * bi1 + lz * s1
        n2 = lx * ta2 + ly * bi2 + lz * s2
    elif kind == BUMP_MAP:
        gu, gv = height_gradient(pixels, base, h, w, uv0, uv1, maps[m, 4], maps[m, 5], maps[m, 6], maps[m, 7],
                                 maps[m, 8] != 0.0)
        scale = maps[m, 9]
        gu *= scale
        gv *= scale
        du0, du1, du2 = tangents[r, 0], tangents[r, 1], tangents[r, 2]
        dv0, dv1, dv2 = tangents[r, 3], tangents[r, 4], tangents[r, 5]
        ku = gu - (s0 * du0 + s1 * du1 + s2 * du2)
        kv = gv - (s0 * dv0 + s1 * dv1 + s2 * dv2)
        du0, du1, du2 = du0 + s0 * ku, du1 + s1 * ku, du2 + s2 * ku
        dv0, dv1, dv2 = dv0 + s0 * kv, dv1 + s1 * kv, dv2 + s2 * kv
        n0, n1, n2 = du1 * dv2 - du2 * dv1, du2 * dv0 - du0 * dv2, du0 * dv1 - du1 * dv0
        if n0 * g0 + n1 * g1 + n2 * g2 < 0.0:  # turned to the geometric normal's side, as Mitsuba
            n0, n1, n2 = -n0, -n1, -n2
    else:
        return s0, s1, s2
    if maps[m, 10] != 0.0 and (dx * s0 + dy * s1 + dz * s2) * (dx * n0 + dy * n1 + dz * n2) <= 0.0:
        k = 2.0 * (n0 * s0 + n1 * s1 + n2 * s2)
        n0, n1, n2 = k * s0 - n0, k * s1 - n1, k * s2 - n2
    ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if not (ln > 1e-20 and math.isfinite(ln)):
        return s0, s1, s2
    return n0 / ln, n1 / ln, n2 / ln
