"""Isotropic Beckmann / GGX microfacet distributions, re-derived from Mitsuba 3's ``microfacet.h``.

Every function is vectorized over N points: ``alpha`` (N,) roughness (clamped to >= 1e-4 as
Mitsuba does), ``beckmann`` (N,) bool (False = GGX); directions are (N, 3) in the local frame.
Sampling is Mitsuba's default visible-normal sampling (Heitz & d'Eon 2014; Jakob's numerical
Beckmann inversion, Heitz's 2017 GGX routine).

Also the rough-dielectric reflectance/transmittance integrals that Mitsuba's roughplastic
precomputes (``eval_reflectance`` / ``eval_transmittance``), with a per-(alpha, eta,
distribution) cache (:func:`rough_plastic_tables`).

The BSDFs themselves evaluate the compiled scalar versions in common.kernels.bsdf; these
vectorized ones serve the table precomputation (in float32, as Mitsuba's scalar variants).
"""
from __future__ import annotations

import sys
import threading

import numpy as np
from scipy.special import erf, erfinv

from igi.common import fresnel, table_cache
from igi.common.fresnel import fresnel_dielectric, reflect_m, refract_m

INV_SQRT_PI = 1.0 / np.sqrt(np.pi)
ROUGH_TRANSMITTANCE_RES = 64  # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES


def _prep(alpha, beckmann, n, dtype):
    a = np.broadcast_to(np.maximum(np.asarray(alpha, dtype=dtype), 1e-4), (n,))
    b = np.broadcast_to(np.asarray(beckmann, dtype=bool), (n,))
    return a, b


def D(m, alpha, beckmann):
    """Microfacet normal distribution D(m)."""
    n = len(m)
    a, b = _prep(alpha, beckmann, n, m.dtype)
    a2 = a * a
    mz = m[:, 2]
    cos2 = mz * mz
    xy2 = m[:, 0] * m[:, 0] + m[:, 1] * m[:, 1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if b.all():
            res = np.exp(-xy2 / (a2 * cos2)) / (np.pi * a2 * cos2 * cos2)
        else:
            t = xy2 / a2 + cos2
            res = 1.0 / (np.pi * a2 * t * t)
            if b.any():
                beck = np.exp(-xy2 / (a2 * cos2)) / (np.pi * a2 * cos2 * cos2)
                res = np.where(b, beck, res)
        ok = res * mz > 1e-20
    return np.where(ok, res, 0.0).astype(m.dtype, copy=False)


def smith_g1(v, m, alpha, beckmann):
    """Smith's shadowing-masking term for one direction (Mitsuba's rational Beckmann fit)."""
    n = len(v)
    a, b = _prep(alpha, beckmann, n, v.dtype)
    vz = v[:, 2]
    xy_alpha_2 = (a * a) * (v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan_theta_alpha_2 = xy_alpha_2 / (vz * vz)
        if b.any():
            ab = 1.0 / np.sqrt(tan_theta_alpha_2)
            ab2 = ab * ab
            beck = np.where(ab >= 1.6, 1.0, (3.535 * ab + 2.181 * ab2) / (1.0 + 2.276 * ab + 2.577 * ab2))
        if not b.all():
            ggx = 2.0 / (1.0 + np.sqrt(1.0 + tan_theta_alpha_2))
    res = beck if b.all() else (ggx if not b.any() else np.where(b, beck, ggx))
    res = np.where(xy_alpha_2 == 0.0, 1.0, res)
    vm = np.sum(v * m, axis=-1)
    res = np.where(vm * vz <= 0.0, 0.0, res)
    return np.nan_to_num(res, nan=0.0).astype(v.dtype, copy=False)


def G(wi, wo, m, alpha, beckmann):
    """Separable Smith shadowing-masking G1(wi) G1(wo)."""
    return smith_g1(wi, m, alpha, beckmann) * smith_g1(wo, m, alpha, beckmann)


def square_to_uniform_disk_concentric(u):
    """Shirley-Chiu concentric square -> disk map; ``u`` (N, 2) in [0,1)^2; returns (x, y)."""
    x = 2.0 * u[:, 0] - 1.0
    y = 2.0 * u[:, 1] - 1.0
    q13 = np.abs(x) < np.abs(y)
    r = np.where(q13, y, x)
    rp = np.where(q13, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(q13, 0.5 * np.pi - phi, phi)
    phi = np.where((x == 0) & (y == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _sample_visible_11_ggx(cos_theta_i, u):
    px, py = square_to_uniform_disk_concentric(u)
    s = 0.5 * (1.0 + cos_theta_i)
    h = np.sqrt(np.maximum(1.0 - px * px, 0.0))
    py = h + (py - h) * s  # lerp(h, py, s)
    z = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
    sin_theta_i = np.sqrt(np.maximum(1.0 - cos_theta_i * cos_theta_i, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = 1.0 / (sin_theta_i * py + cos_theta_i * z)
    return (cos_theta_i * py - sin_theta_i * z) * norm, px * norm


def _sample_visible_11_beckmann(cos_theta_i, u):
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan_theta_i = np.sqrt(np.maximum(1.0 - cos_theta_i * cos_theta_i, 0.0)) / cos_theta_i
        cot_theta_i = 1.0 / tan_theta_i
        maxval = erf(cot_theta_i)
        u = np.clip(u, 1e-6, 1.0 - 1e-6)
        ux = u[:, 0]
        x = maxval - (maxval + 1.0) * erf(np.sqrt(-np.log(ux)))
        tail = INV_SQRT_PI * tan_theta_i * np.exp(-cot_theta_i * cot_theta_i)
        tail = np.where(tan_theta_i == 0.0, 0.0, tail)
        ux = ux * (1.0 + maxval + tail)
        for _ in range(3):  # Newton on the CDF, parameterized in the erf() domain
            slope = erfinv(x)
            value = 1.0 + x + INV_SQRT_PI * tan_theta_i * np.exp(-slope * slope) - ux
            value = np.where(tan_theta_i == 0.0, 1.0 + x - ux, value)
            deriv = 1.0 - slope * tan_theta_i
            deriv = np.where(tan_theta_i == 0.0, 1.0, deriv)
            x = x - value / deriv
        return erfinv(x), erfinv(2.0 * u[:, 1] - 1.0)


def _sincos_phi(v):
    r2 = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]
    small = r2 <= 4.0 * np.finfo(v.dtype).eps
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.sqrt(r2)
        c = np.where(small, 1.0, np.clip(v[:, 0] * inv, -1.0, 1.0))
        s = np.where(small, 0.0, np.clip(v[:, 1] * inv, -1.0, 1.0))
    return s, c


def sample_visible(wi, u, alpha, beckmann, with_pdf=True):
    """Sample a microfacet normal from the distribution of normals visible from ``wi`` (wi.z > 0).

    ``u``: (N, 2). Returns ``(m (N, 3), pdf (N,))`` with pdf = D(m) G1(wi, m) |wi.m| / wi.z.
    """
    n = len(wi)
    dt = np.result_type(wi, np.float32)
    wi = wi.astype(dt, copy=False)
    u = np.asarray(u, dtype=dt)
    a, b = _prep(alpha, beckmann, n, dt)
    wp = np.stack([a * wi[:, 0], a * wi[:, 1], wi[:, 2]], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        wp /= np.linalg.norm(wp, axis=-1, keepdims=True)
    sin_phi, cos_phi = _sincos_phi(wp)
    cos_theta = wp[:, 2]
    sx = np.empty(n, dt)
    sy = np.empty(n, dt)
    if b.all():
        sx[:], sy[:] = _sample_visible_11_beckmann(cos_theta, u)
    elif not b.any():
        sx[:], sy[:] = _sample_visible_11_ggx(cos_theta, u)
    else:
        sx[b], sy[b] = _sample_visible_11_beckmann(cos_theta[b], u[b])
        g = ~b
        sx[g], sy[g] = _sample_visible_11_ggx(cos_theta[g], u[g])
    tx = (cos_phi * sx - sin_phi * sy) * a
    ty = (sin_phi * sx + cos_phi * sy) * a
    m = np.stack([-tx, -ty, np.ones_like(tx)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
    m = np.nan_to_num(m, nan=0.0)
    return m, (pdf_visible(wi, m, a, b) if with_pdf else None)


def pdf_visible(wi, m, alpha, beckmann):
    """Density of :func:`sample_visible` over microfacet normals (solid angle of m)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p = D(m, alpha, beckmann) * smith_g1(wi, m, alpha, beckmann) * np.abs(np.sum(wi * m, axis=-1)) / wi[:, 2]
    return np.nan_to_num(p, nan=0.0, posinf=0.0, neginf=0.0)


# ----------------------------------------------------------------------------------------------
# Rough dielectric interface integrals (roughplastic precomputation)


def _gl_nodes(res):
    nodes, weights = np.polynomial.legendre.leggauss(res)
    nx, ny = np.meshgrid(nodes, nodes, indexing="ij")
    wx, wy = np.meshgrid(weights, weights, indexing="ij")
    u = np.stack([nx.ravel(), ny.ravel()], axis=-1) * 0.5 + 0.5
    w = (wx * wy).ravel() * 0.25
    return u, w


def _quadrature(wi_list, alpha, eta, beckmann, transmit):
    """Average over visible normals of G1(wo, m) x (F or 1 - F) for each wi (Mitsuba's
    eval_reflectance / eval_transmittance), by a 2D Gauss-Legendre rule on the sample square.
    Evaluated in float32 like Mitsuba's scalar variants, accumulated in float64."""
    res = 32 if eta > 1 else 128
    u, w = _gl_nodes(res)
    k = len(u)
    out = np.empty(len(wi_list))
    dt = np.float32
    u = u.astype(dt)
    chunk = max(1, (1 << 19) // k)  # directions per batch
    for s0 in range(0, len(wi_list), chunk):
        wis = np.asarray(wi_list[s0:s0 + chunk], dt)
        c = len(wis)
        wi = np.repeat(wis, k, axis=0)
        uu = np.tile(u, (c, 1))
        m, _ = sample_visible(wi, uu, np.float32(alpha), beckmann, with_pdf=False)
        cos_im = np.sum(wi * m, axis=-1)
        f, cos_t, _eta_it, eta_ti = fresnel_dielectric(cos_im, np.float32(eta))
        if transmit:
            wo = refract_m(wi, m, cos_t, eta_ti)
            val = smith_g1(wo, m, np.float32(alpha), beckmann) * (1.0 - f)
            val = np.where(wo[:, 2] * wi[:, 2] >= 0.0, 0.0, val)
        else:
            wo = reflect_m(wi, m)
            val = smith_g1(wo, m, np.float32(alpha), beckmann) * f
            val = np.where((wo[:, 2] <= 0.0) | (wi[:, 2] <= 0.0), 0.0, val)
        out[s0:s0 + c] = val.reshape(c, k).astype(np.float64) @ w
    return out


def eval_reflectance(mu, alpha, eta, beckmann):
    """Directional albedo of a rough dielectric interface's reflection at cos(theta_i) = mu."""
    mu = np.atleast_1d(np.asarray(mu, np.float64))
    wi = np.stack([np.sqrt(1 - mu * mu), np.zeros_like(mu), mu], axis=-1)
    return _quadrature(wi, alpha, eta, beckmann, transmit=False)


def eval_transmittance(mu, alpha, eta, beckmann):
    """Directional transmittance of a rough dielectric interface at cos(theta_i) = mu."""
    mu = np.atleast_1d(np.asarray(mu, np.float64))
    wi = np.stack([np.sqrt(1 - mu * mu), np.zeros_like(mu), mu], axis=-1)
    return _quadrature(wi, alpha, eta, beckmann, transmit=True)


_TABLES: dict = {}
_TABLES_LOCK = threading.Lock()
_VERSION: str | None = None  # table_cache.source_version of the code computing the tables


def _table_file(key: tuple) -> str | None:
    """The disk-cache name of one coat's tables: the version of this module's and the Fresnel
    code (table_cache.source_version), the resolution and the float32 key (exact: repr
    round-trips); None when there is no cache or no source to version."""
    global _VERSION
    if table_cache.cache_dir() is None:
        return None
    if _VERSION is None:
        try:
            _VERSION = table_cache.source_version(sys.modules[__name__], fresnel)
        except OSError:  # installed without sources: nothing to version the tables by
            return None
    alpha, eta, beckmann = key
    return f"coat-{_VERSION}-{ROUGH_TRANSMITTANCE_RES}-{alpha!r}-{eta!r}-{int(beckmann)}.npz"


def _stored_tables(name: str | None) -> tuple | None:
    """One coat's tables from the disk cache file ``name`` (:func:`_table_file`), or None (no
    cache, absent, unreadable or malformed: the arrays must be exactly what the computation
    gives, float64 of the table's shape, finite)."""
    z = table_cache.load(name) if name else None
    if z is None:
        return None
    try:
        ext_t, int_r, ext_r = z["ext_t"], z["int_r"], z["ext_r"]
        shape = (ROUGH_TRANSMITTANCE_RES,)
        if not (ext_t.shape == shape and ext_r.shape == shape and int_r.shape == ()
                and ext_t.dtype == ext_r.dtype == int_r.dtype == np.float64
                and np.all(np.isfinite(ext_t)) and np.all(np.isfinite(ext_r)) and np.isfinite(int_r)):
            return None
        return ext_t, float(int_r), ext_r
    except Exception:  # noqa: BLE001 - a malformed file means "recompute"
        return None


def rough_plastic_tables(alpha: float, eta: float, beckmann: bool) -> tuple[np.ndarray, float, np.ndarray]:
    """Mitsuba roughplastic's precomputed ``(external_transmittance[64], internal_reflectance)``
    plus ``external_reflectance[64]`` (the coat's single-scattering directional albedo, used only
    for :func:`common.bsdf.albedo`).

    The tables are over cos(theta) = linspace(0, 1, 64) (first node 1e-6); the internal
    reflectance is Fdr of the rough interface seen from inside (eta -> 1/eta), i.e.
    2 * mean(R(mu) * mu) over the same nodes. Cached per (alpha, eta, distribution).
    """
    # keyed on float32 values: float32 per-point arrays and float64 material values agree
    alpha = float(np.float32(max(float(alpha), 1e-4)))
    eta = float(np.float32(eta))
    key = (alpha, eta, bool(beckmann))
    tab = _TABLES.get(key)
    if tab is not None:
        return tab
    name = _table_file(key)
    tab = _stored_tables(name)
    if tab is None:
        mu = np.maximum(1e-6, np.linspace(0.0, 1.0, ROUGH_TRANSMITTANCE_RES))
        ext_t = eval_transmittance(mu, alpha, float(eta), bool(beckmann))
        int_r = float(np.mean(eval_reflectance(mu, alpha, 1.0 / float(eta), bool(beckmann)) * mu) * 2.0)
        ext_r = eval_reflectance(mu, alpha, float(eta), bool(beckmann))
        tab = (ext_t, int_r, ext_r)
        if name:
            table_cache.store(name, ext_t=ext_t, int_r=np.float64(int_r), ext_r=ext_r)
    with _TABLES_LOCK:
        _TABLES[key] = tab
    return tab


def lerp_gather(tables, rows, x):
    """Mitsuba's ``lerp_gather``: linear interpolation in tables sampled at linspace(0, 1, R).

    ``tables`` (G, R); ``rows`` (n,) int row per point (or None when G == 1); ``x`` (n,) in [0, 1].
    """
    size = tables.shape[1]
    xs = np.asarray(x) * (size - 1)
    idx = np.minimum(np.maximum(xs, 0).astype(np.int64), size - 2)
    w1 = (xs - idx).astype(np.asarray(x).dtype, copy=False)
    if rows is None:
        t = tables[0]
        v0, v1 = t[idx], t[idx + 1]
    else:
        v0, v1 = tables[rows, idx], tables[rows, idx + 1]
    return (v0 + (v1 - v0) * w1).astype(xs.dtype, copy=False)
