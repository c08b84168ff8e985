"""Fresnel terms and mirror/refraction directions in the local shading frame (z = normal).

Vectorized numpy re-derivations of Mitsuba 3's ``fresnel.h``: every function takes arrays of
N points (directions as (N, 3)) and works in the floating type of its inputs. The BSDFs use
the compiled scalar versions in common.kernels.bsdf; these serve the rough-plastic table
precomputation (common.microfacet).
"""
from __future__ import annotations

import numpy as np


def fresnel_dielectric(cos_theta_i, eta):
    """Unpolarized Fresnel reflectance at a dielectric interface.

    ``eta`` is int/ext; ``cos_theta_i`` < 0 means the incident direction is inside.
    Returns ``(R, cos_theta_t, eta_it, eta_ti)`` as Mitsuba's ``fresnel()``: ``cos_theta_t`` has the
    opposite sign of ``cos_theta_i`` (and is 0 under total internal reflection, where R = 1),
    ``eta_it`` is the relative index in the direction of travel, ``eta_ti`` its reciprocal (the
    factor on the tangential components of the refracted direction).
    """
    cos_i = np.asarray(cos_theta_i)
    eta = np.asarray(eta, dtype=cos_i.dtype if cos_i.dtype.kind == "f" else np.float64)
    outside = cos_i >= 0
    rcp_eta = 1.0 / eta
    eta_it = np.where(outside, eta, rcp_eta)
    eta_ti = np.where(outside, rcp_eta, eta)
    cos_t_sqr = 1.0 - (1.0 - cos_i * cos_i) * (eta_ti * eta_ti)
    cos_i_abs = np.abs(cos_i)
    cos_t_abs = np.sqrt(np.maximum(cos_t_sqr, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = (cos_i_abs - eta_it * cos_t_abs) / (cos_i_abs + eta_it * cos_t_abs)
        a_p = (cos_t_abs - eta_it * cos_i_abs) / (cos_t_abs + eta_it * cos_i_abs)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    index_matched = eta == 1.0
    special = index_matched | (cos_i_abs == 0.0)
    r = np.where(special, np.where(index_matched, 0.0, 1.0), r)
    r = np.where(cos_t_sqr <= 0.0, 1.0, r)  # total internal reflection (exactly as the formula gives)
    cos_t = np.where(cos_i >= 0, -cos_t_abs, cos_t_abs)
    return r.astype(cos_i.dtype, copy=False), cos_t, eta_it, eta_ti


def fresnel_conductor(cos_theta_i, eta, k):
    """Unpolarized Fresnel reflectance of a conductor with complex IOR ``eta + i k``.

    ``cos_theta_i``: (N,) (assumed >= 0); ``eta``, ``k``: (N, 3) or broadcastable. Returns (N, 3).
    ``eta = k = 0`` is the perfect mirror (R = 1), as the formula gives in the limit.
    """
    c = np.asarray(cos_theta_i)[..., None]
    eta = np.asarray(eta)
    k = np.asarray(k)
    c2 = c * c
    s2 = 1.0 - c2
    s4 = s2 * s2
    temp1 = eta * eta - k * k - s2
    a2pb2 = np.sqrt(np.maximum(temp1 * temp1 + 4.0 * k * k * eta * eta, 0.0))
    a = np.sqrt(np.maximum(0.5 * (a2pb2 + temp1), 0.0))
    term1 = a2pb2 + c2
    term2 = 2.0 * c * a
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (term1 - term2) / (term1 + term2)
        term3 = a2pb2 * c2 + s4
        term4 = term2 * s2
        r_p = r_s * (term3 - term4) / (term3 + term4)
    r = 0.5 * (r_s + r_p)
    mirror = (eta == 0) & (k == 0)
    r = np.where(mirror | ~np.isfinite(r), 1.0, np.maximum(r, 0.0))  # ~-1e-17 at eta = 1, k = 0
    return r


def fresnel_diffuse_reflectance(eta):
    """Fdr: hemispherically averaged (cosine-weighted) Fresnel reflectance, Mitsuba's fits
    (Egan & Hilgeman for eta < 1, d'Eon & Irving for eta >= 1)."""
    eta = np.asarray(eta, dtype=np.float64)
    low = -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    ie = 1.0 / eta
    high = (0.919317 - 3.4793 * ie + 6.75335 * ie ** 2 - 7.80989 * ie ** 3
            + 4.98554 * ie ** 4 - 1.36881 * ie ** 5)
    out = np.where(eta < 1.0, low, high)
    return out if out.ndim else float(out)


def reflect_m(w, m):
    """Mirror ``w`` about the (unit) microfacet normal ``m``."""
    d = np.sum(w * m, axis=-1, keepdims=True)
    return 2.0 * d * m - w


def refract_m(w, m, cos_theta_t, eta_ti):
    """Refract ``w`` about the microfacet normal ``m``."""
    d = np.sum(w * m, axis=-1)
    return m * (d * eta_ti + cos_theta_t)[:, None] - w * np.asarray(eta_ti)[..., None]
