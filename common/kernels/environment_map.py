"""An environment map's radiance, pdf and samples, compiled (``common.environment_map``).

One set of tables, built once per map by ``common.environment_map.EnvironmentMap`` and passed to
every kernel that reads the sky as a tuple ``ENV`` = (tex, to_local, to_world, row_cdf, col_cdf,
density, sin_rows):

- ``tex`` (H, W + 1, 3) float32: the lat-long image times its scale, with a last column repeating
  the first (periodic in azimuth), as Mitsuba 3's ``envmap`` keeps it; texel row r lies at polar
  angle θ = π r / (H - 1), texel column c at azimuth u = (c + ½) / W.
- ``to_local``, ``to_world`` (3, 3) float64: the map's rotation (Mitsuba's ``to_world``).
- The sampling density, as Mitsuba 3's warp: piecewise bilinear in (u, v) over the same grid,
  ∝ luminance × sin θ of the texel rows — where the bilinear radiance is positive, so is the
  density, and over a small bright sun L / p hardly varies. ``density`` (H, W + 1) holds the
  grid's values scaled so that the solid-angle pdf is bilinear(density) / sin θ; ``row_cdf`` (H,)
  and ``col_cdf`` (H - 1, W + 1) the cumulative sums of the (H - 1) × W patches' integrals (0
  first, 1 last); ``sin_rows`` (H,) sin θ of the texel rows. A sample picks a patch by the sums,
  then v and u inside it by the bilinear function's linear marginal and conditional.

Radiance is Mitsuba 3's ``envmap.eval``: local = to_local · ω, u = atan2(x, -z) / 2π,
v = acos(y) / π, bilinear between texel centres with the half-texel shift in u. An empty ``tex``
(0 rows) is "no map": callers keep their constant sky (kernels take the tuple either way, so
their types do not change with the scene).
"""
from __future__ import annotations

import math

from numba import njit

INV_2PI = 1.0 / (2.0 * math.pi)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _local_uv(env, dx, dy, dz):
    """(u, v) in [0, 1)² of world direction (dx, dy, dz) (unit) in the map's lat-long frame."""
    m = env[1]
    x = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    y = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    z = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    u = math.atan2(x, -z) * INV_2PI
    u -= math.floor(u)
    v = math.acos(min(1.0, max(-1.0, y))) / math.pi
    return u, v


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def radiance(env, dx, dy, dz):
    """The map's radiance (r, g, b) arriving from world direction (dx, dy, dz) (unit, pointing
    at the sky): Mitsuba 3's bilinear lookup."""
    tex = env[0]
    H = tex.shape[0]
    W = tex.shape[1] - 1
    u, v = _local_uv(env, dx, dy, dz)
    if not (u >= 0.0 and v >= 0.0):  # a NaN direction: no texel to read
        return 0.0, 0.0, 0.0
    px, py, fx, fy = _cell(u, v, W, H)
    gx = 1.0 - fx
    gy = 1.0 - fy
    return _bilinear(tex, py, px, fx, fy, gx, gy, 0), _bilinear(tex, py, px, fx, fy, gx, gy, 1), \
        _bilinear(tex, py, px, fx, fy, gx, gy, 2)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cell(u, v, W, H):
    """The grid cell (px, py) of lat-long (u, v) and the fractions (fx, fy) inside it: texel
    columns at u = (c + ½) / W (u shifted by half a texel, wrapped), rows at v = r / (H - 1)."""
    u -= 0.5 / W
    u -= math.floor(u)
    x = u * W
    y = v * (H - 1)
    px = min(int(x), W - 1)
    py = min(int(y), H - 2)
    return px, py, x - px, y - py


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bilinear(tex, py, px, fx, fy, gx, gy, c) -> float:
    """Channel ``c`` between texels (py, px) .. (py + 1, px + 1) with weights (gx, fx) x (gy, fy)."""
    return gy * (gx * tex[py, px, c] + fx * tex[py, px + 1, c]) + fy * (gx * tex[py + 1, px, c]
                                                                        + fx * tex[py + 1, px + 1, c])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bilinear2(grid, py, px, fx, fy) -> float:
    """``grid`` (2-D) between (py, px) .. (py + 1, px + 1) at fractions (fx, fy)."""
    return (1.0 - fy) * ((1.0 - fx) * grid[py, px] + fx * grid[py, px + 1]) + fy * (
        (1.0 - fx) * grid[py + 1, px] + fx * grid[py + 1, px + 1])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def pdf(env, dx, dy, dz) -> float:
    """Solid-angle pdf with which :func:`sample` draws world direction (dx, dy, dz)."""
    H = env[0].shape[0]
    W = env[0].shape[1] - 1
    u, v = _local_uv(env, dx, dy, dz)
    if not (u >= 0.0 and v >= 0.0):  # a NaN direction
        return 0.0
    px, py, fx, fy = _cell(u, v, W, H)
    return _bilinear2(env[5], py, px, fx, fy) / max(math.sin(v * math.pi), 1e-7)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _search(cdf, lo, hi, x) -> int:
    """The largest i in [lo, hi) with cdf[i] <= x (cdf ascending)."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if cdf[mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _linear(a, b, xi) -> float:
    """x in [0, 1] drawn from the density ∝ (1 - x) a + x b (a, b >= 0, not both 0) for uniform
    xi: the inverse of its CDF, in the form without cancellation (a = b: x = xi)."""
    return min(xi * (a + b) / max(a + math.sqrt(max(a * a + xi * (b * b - a * a), 0.0)), 1e-300), 1.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def sample(env, u0, u1):
    """A world direction (dx, dy, dz) drawn from the map's density for uniforms (u0, u1), and its
    solid-angle pdf: a patch row by ``row_cdf``, a patch in it by ``col_cdf`` (each uniform's
    fraction inside its interval reused), then v and u inside the patch from the bilinear
    density's marginal and conditional (both linear)."""
    H = env[0].shape[0]
    W = env[0].shape[1] - 1
    rows, cols, dens = env[3], env[4], env[5]
    r = _search(rows, 0, H - 1, u0)
    w = rows[r + 1] - rows[r]
    xv = min(max((u0 - rows[r]) / w, 0.0), 1.0) if w > 0 else 0.5
    cr = cols[r]
    c = _search(cr, 0, W, u1)
    w = cr[c + 1] - cr[c]
    xu = min(max((u1 - cr[c]) / w, 0.0), 1.0) if w > 0 else 0.5
    a, b, cc, d = dens[r, c], dens[r, c + 1], dens[r + 1, c], dens[r + 1, c + 1]
    # (never exactly on a pole row: there sin θ = 0 and the density with it, where L need not be)
    fv = min(max(_linear(a + b, cc + d, xv), 1e-9), 1.0 - 1e-9)
    fu = _linear((1.0 - fv) * a + fv * cc, (1.0 - fv) * b + fv * d, xu)
    v = (r + fv) / (H - 1)
    st = math.sin(v * math.pi)
    ct = math.cos(v * math.pi)
    phi = 2.0 * math.pi * ((c + 0.5 + fu) / W)
    lx = math.sin(phi) * st
    ly = ct
    lz = -math.cos(phi) * st
    m = env[2]
    dx = m[0, 0] * lx + m[0, 1] * ly + m[0, 2] * lz
    dy = m[1, 0] * lx + m[1, 1] * ly + m[1, 2] * lz
    dz = m[2, 0] * lx + m[2, 1] * ly + m[2, 2] * lz
    n = math.sqrt((dx * dx + dy * dy) + dz * dz)
    p = _bilinear2(dens, r, c, fu, fv) / max(st, 1e-7)
    return dx / n, dy / n, dz / n, p


@njit(cache=True, nogil=True, error_model="numpy")
def radiance_many(env, d, out) -> None:
    """:func:`radiance` of each row of ``d`` (N, 3) into ``out`` (N, 3)."""
    for i in range(d.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = radiance(env, d[i, 0], d[i, 1], d[i, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def pdf_many(env, d, out) -> None:
    """:func:`pdf` of each row of ``d`` (N, 3) into ``out`` (N,)."""
    for i in range(d.shape[0]):
        out[i] = pdf(env, d[i, 0], d[i, 1], d[i, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def sample_many(env, u, d, p) -> None:
    """:func:`sample` for each row of ``u`` (N, 2): directions into ``d`` (N, 3), pdfs into ``p``."""
    for i in range(u.shape[0]):
        d[i, 0], d[i, 1], d[i, 2], p[i] = sample(env, u[i, 0], u[i, 1])
