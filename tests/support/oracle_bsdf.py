"""The numpy BSDFs that the compiled kernels (common.kernels.bsdf) replaced, kept verbatim as
a test oracle.

Not part of the product: tests/common/test_bsdf_kernel.py checks common.bsdf's eval, pdf,
sample, sample_lobe, albedo, specular_components and coat_transmittance against these on
random inputs. Vectorized over N points, grouped by kind, computing in the inputs' float type.
"""
from __future__ import annotations

import numpy as np

from igi.common import microfacet as mf
from igi.common.bsdf import TRANSMISSIVE_KINDS, SurfacePoints
from igi.common.fresnel import (
    fresnel_conductor,
    fresnel_diffuse_reflectance,
    fresnel_dielectric,
    reflect_m,
)
from igi.common.scene import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    PLASTIC,
    ROUGHCONDUCTOR,
    ROUGHDIELECTRIC,
    ROUGHPLASTIC,
    ROUGHPLASTIC_DIFFUSE,
    ROUGHPLASTIC_LOBE,
    THINDIELECTRIC,
)

INV_PI = 1.0 / np.pi


# numpy helpers the product no longer uses (from common.fresnel and common.microfacet)


def reflect(w):
    """Mirror about the shading normal (local frame): (-x, -y, z)."""
    out = np.empty_like(w)
    out[:, 0] = -w[:, 0]
    out[:, 1] = -w[:, 1]
    out[:, 2] = w[:, 2]
    return out


def refract(w, cos_theta_t, eta_ti):
    """Refract about the shading normal; ``cos_theta_t``/``eta_ti`` from :func:`fresnel_dielectric`."""
    e = np.asarray(eta_ti)
    out = np.empty(np.broadcast_shapes(w.shape), dtype=np.result_type(w, cos_theta_t, e))
    out[:, 0] = -e * w[:, 0]
    out[:, 1] = -e * w[:, 1]
    out[:, 2] = cos_theta_t
    return out


def square_to_cosine_hemisphere(u):
    """Cosine-weighted hemisphere sample (Malley's method over the concentric disk)."""
    px, py = mf.square_to_uniform_disk_concentric(u)
    z = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
    return np.stack([px, py, z], axis=-1)


# ----------------------------------------------------------------------------------------------
# helpers


def _dtype(*arrays):
    return np.result_type(*[np.asarray(a).dtype for a in arrays], np.float32)


def _groups(kind):
    """[(kind, selector)]: selector is slice(None) when every point has the same kind."""
    if len(kind) == 0:
        return []
    k0 = kind[0]
    if np.all(kind == k0):
        return [(int(k0), slice(None))]
    return [(int(k), np.nonzero(kind == k)[0]) for k in np.unique(kind)]


def _flip_mask(sp, wi):
    """Twosided points seen from the back (non-transmissive kinds only)."""
    return sp.twosided & (wi[:, 2] < 0) & ~np.isin(sp.kind, TRANSMISSIVE_KINDS)


def _flipz(w, mask):
    if not mask.any():
        return w
    w = w.copy()
    w[mask, 2] = -w[mask, 2]
    return w


def _finite(x):
    return np.where(np.isfinite(x), x, 0.0).astype(x.dtype, copy=False)


def _rough_tables(sp, with_reflectance=False):
    """Roughplastic tables for the points of ``sp``: ``(tables (G, 64), rows (n,) or None,
    fdr_int (n,))``, plus the coat reflectance tables (G, 64) when ``with_reflectance``."""
    n = len(sp)
    a = np.maximum(sp.alpha.astype(np.float64), 1e-4)
    e = sp.eta.astype(np.float64)
    b = sp.beckmann.astype(bool)
    if n == 0 or (np.all(a == a[0]) and np.all(e == e[0]) and np.all(b == b[0])):
        if n == 0:
            ones = np.ones((1, mf.ROUGH_TRANSMITTANCE_RES))
            return (ones, None, np.zeros(0)) + ((ones,) if with_reflectance else ())
        t, r, rr = mf.rough_plastic_tables(a[0], e[0], b[0])
        res = (t[None, :], None, np.full(n, r))
        return res + ((rr[None, :],) if with_reflectance else ())
    # Distinct (alpha, eta, beckmann) triples via 1-D uniques (a row-wise np.unique sorts
    # structured rows: ~10x slower, and this runs for every rough-plastic evaluation).
    ua_, ia = np.unique(a, return_inverse=True)
    ue_, ie = np.unique(e, return_inverse=True)
    code = (ia.ravel().astype(np.int64) * len(ue_) + ie.ravel()) * 2 + b.astype(np.int64)
    ucode, inv = np.unique(code, return_inverse=True)
    uniq = [(ua_[c // 2 // len(ue_)], ue_[c // 2 % len(ue_)], c % 2) for c in ucode.tolist()]
    tabs, rints, refl = [], [], []
    for ua, ue, ub in uniq:
        t, r, rr = mf.rough_plastic_tables(ua, ue, bool(ub))
        tabs.append(t)
        rints.append(r)
        refl.append(rr)
    inv = inv.ravel()
    res = (np.stack(tabs), inv, np.asarray(rints)[inv])
    return res + ((np.stack(refl),) if with_reflectance else ())


def coat_transmittance(sp: SurfacePoints) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rough plastics' coat transmittance tables t(cos θ) for a compiled evaluation:
    ``(tables (G, R) float64, row (n,) int64, t_avg (n,))`` with t_avg the cosine-weighted mean
    (as :func:`albedo` uses), so the diffuse layer per unit albedo is cos/π · t(cos)/t_avg."""
    tabs, rows, _ = _rough_tables(sp)
    tabs = np.ascontiguousarray(tabs, dtype=np.float64)
    rows = np.zeros(len(sp), np.int64) if rows is None else np.asarray(rows, np.int64)
    return tabs, rows, _cosine_mean(tabs)[rows]


def _cosine_mean(tabs):
    """Cosine-weighted mean over the hemisphere of tables sampled at linspace(0, 1, R): 2∫t(μ)μdμ."""
    mu = np.linspace(0.0, 1.0, tabs.shape[1])
    return 2.0 * np.mean(tabs * mu, axis=1)


def _cos_hemisphere_pdf(w):
    return INV_PI * w[:, 2]


# ----------------------------------------------------------------------------------------------
# per-kind evaluation (inputs already twosided-flipped; ``sp`` already the kind's subset)


def _eval_diffuse(sp, wi, wo):
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(ok[:, None], sp.diffuse * (INV_PI * wo[:, 2])[:, None], 0.0)


def _eval_roughconductor(sp, wi, wo):
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    h = wi + wo
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        d = mf.D(h, sp.alpha, sp.beckmann)
        g = mf.G(wi, wo, h, sp.alpha, sp.beckmann)
        val = d * g / (4.0 * ci)
    F = fresnel_conductor(np.sum(wi * h, axis=-1), sp.cond_eta, sp.cond_k)
    res = (F * sp.specular) * val[:, None]
    return np.where((ok & (d != 0))[:, None], res, 0.0)


def _eval_coat_lobe(sp, wi, wo):
    """(Added with ROUGHPLASTIC_LOBE, after the move: the oracle of the new kind.) A rough
    plastic's coat reflection alone: the rough conductor's microfacet term with the
    dielectric Fresnel factor."""
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    h = wi + wo
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        d = mf.D(h, sp.alpha, sp.beckmann)
        g = mf.G(wi, wo, h, sp.alpha, sp.beckmann)
        val = d * g / (4.0 * ci)
        F = fresnel_dielectric(np.sum(wi * h, axis=-1), sp.eta)[0]
    res = sp.specular * (F * val)[:, None]
    return np.where((ok & (d != 0))[:, None], res, 0.0)


def _pdf_roughconductor(sp, wi, wo):
    ci, co = wi[:, 2], wo[:, 2]
    h = wi + wo
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        ok = (ci > 0) & (co > 0) & (np.sum(wi * h, -1) > 0) & (np.sum(wo * h, -1) > 0)
        p = mf.D(h, sp.alpha, sp.beckmann) * mf.smith_g1(wi, h, sp.alpha, sp.beckmann) / (4.0 * ci)
    return np.where(ok, p, 0.0)


def _plastic_probs(f_i, sw):
    ps = f_i * sw
    pd = (1.0 - f_i) * (1.0 - sw)
    tot = ps + pd
    with np.errstate(invalid="ignore", divide="ignore"):
        ps = np.where(tot > 0, ps / tot, 0.0)
    return ps, 1.0 - ps


def _plastic_diffuse_coef(sp, fdr_int):
    diff = sp.diffuse
    denom = 1.0 - np.where(sp.nonlinear[:, None], diff * fdr_int[:, None], fdr_int[:, None])
    return diff / denom


def _eval_plastic(sp, wi, wo):
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    eta = sp.eta
    f_i = fresnel_dielectric(ci, eta)[0]
    f_o = fresnel_dielectric(co, eta)[0]
    fdr_int = np.asarray(fresnel_diffuse_reflectance(1.0 / eta.astype(np.float64)), dtype=ci.dtype)
    diff = _plastic_diffuse_coef(sp, fdr_int)
    s = INV_PI * co / (eta * eta) * (1.0 - f_i) * (1.0 - f_o)
    return np.where(ok[:, None], diff * s[:, None], 0.0)


def _pdf_plastic(sp, wi, wo):
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    f_i = fresnel_dielectric(ci, sp.eta)[0]
    _, pd = _plastic_probs(f_i, sp.sampling_weight())
    return np.where(ok, _cos_hemisphere_pdf(wo) * pd, 0.0)


def _layer_term(sp, co, t_i, tabs, rows, fdr_int):
    """A rough plastic's diffuse-layer value × cos θ_o, given the coat transmittance t_i toward
    the incident side (no masking of invalid directions)."""
    t_o = mf.lerp_gather(tabs, rows, np.clip(co, 0, 1))
    diff = _plastic_diffuse_coef(sp, fdr_int)
    s = INV_PI / (sp.eta * sp.eta) * co * t_i * t_o
    return diff * s[:, None]


def _roughplastic_diffuse(sp, wi, wo):
    """The diffuse-layer term of a rough plastic alone (ROUGHPLASTIC_DIFFUSE), with its cos θ_o."""
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    tabs, rows, fdr_int = _rough_tables(sp)
    dt = ci.dtype
    tabs = tabs.astype(dt, copy=False)
    t_i = mf.lerp_gather(tabs, rows, np.clip(ci, 0, 1))
    return np.where(ok[:, None], _finite(_layer_term(sp, co, t_i, tabs, rows, fdr_int.astype(dt, copy=False))), 0.0)


def _roughplastic_parts(sp, wi, wo, want_eval=True, want_pdf=True):
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co > 0)
    tabs, rows, fdr_int = _rough_tables(sp)
    dt = ci.dtype
    tabs = tabs.astype(dt, copy=False)
    fdr_int = fdr_int.astype(dt, copy=False)
    t_i = mf.lerp_gather(tabs, rows, np.clip(ci, 0, 1))
    sw = sp.sampling_weight()
    ps = (1.0 - t_i) * sw
    pd = t_i * (1.0 - sw)
    with np.errstate(invalid="ignore", divide="ignore"):
        ps = np.where(ps + pd > 0, ps / (ps + pd), 0.0)
    pd = 1.0 - ps
    h = wi + wo
    with np.errstate(invalid="ignore", divide="ignore"):
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        d = mf.D(h, sp.alpha, sp.beckmann)
        g1i = mf.smith_g1(wi, h, sp.alpha, sp.beckmann)
    val = pdf = None
    if want_pdf:
        with np.errstate(invalid="ignore", divide="ignore"):
            pdf = ps * (d * g1i / (4.0 * ci)) + pd * _cos_hemisphere_pdf(wo)
        pdf = np.where(ok, _finite(pdf), 0.0)
    if want_eval:
        eta = sp.eta
        with np.errstate(invalid="ignore", divide="ignore"):
            F = fresnel_dielectric(np.sum(wi * h, axis=-1), eta)[0]
            g = g1i * mf.smith_g1(wo, h, sp.alpha, sp.beckmann)
            spec = F * d * g / (4.0 * ci)
        val = sp.specular * spec[:, None] + _layer_term(sp, co, t_i, tabs, rows, fdr_int)
        val = np.where(ok[:, None], _finite(val), 0.0)
    return val, pdf


def _eval_kind(k, sp, wi, wo):
    if k == DIFFUSE:
        return _eval_diffuse(sp, wi, wo)
    if k == ROUGHCONDUCTOR:
        return _eval_roughconductor(sp, wi, wo)
    if k == PLASTIC:
        return _eval_plastic(sp, wi, wo)
    if k == ROUGHPLASTIC:
        return _roughplastic_parts(sp, wi, wo, want_pdf=False)[0]
    if k == ROUGHPLASTIC_DIFFUSE:
        return _roughplastic_diffuse(sp, wi, wo)
    if k == ROUGHPLASTIC_LOBE:
        return _eval_coat_lobe(sp, wi, wo)
    return None  # delta kinds and NULL: 0


def _pdf_kind(k, sp, wi, wo):
    if k in (DIFFUSE, ROUGHPLASTIC_DIFFUSE):
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(ok, _cos_hemisphere_pdf(wo), 0.0)
    if k in (ROUGHCONDUCTOR, ROUGHPLASTIC_LOBE):
        return _pdf_roughconductor(sp, wi, wo)
    if k == PLASTIC:
        return _pdf_plastic(sp, wi, wo)
    if k == ROUGHPLASTIC:
        return _roughplastic_parts(sp, wi, wo, want_eval=False)[1]
    return None


# ----------------------------------------------------------------------------------------------
# public API


def eval(sp: SurfacePoints, wi: np.ndarray, wo: np.ndarray, mode: str = "radiance") -> np.ndarray:  # noqa: A001
    """f(wi, wo) |cos theta_o| for the non-delta components; (N, 3).

    ``mode`` is accepted for symmetry: none of the non-delta lobes here is non-symmetric."""
    dt = _dtype(wi, wo)
    wi = np.asarray(wi, dt)
    wo = np.asarray(wo, dt)
    out = np.zeros((len(wi), 3), dt)
    flip = _flip_mask(sp, wi)
    wi = _flipz(wi, flip)
    wo = _flipz(wo, flip)
    for k, sel in _groups(sp.kind):
        sub = sp if isinstance(sel, slice) else sp.subset(sel)
        r = _eval_kind(k, sub, wi[sel], wo[sel])
        if r is not None:
            out[sel] = _finite(r)
    return out


def pdf(sp: SurfacePoints, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Solid-angle density with which :func:`sample` draws ``wo`` through a non-delta component
    (component selection included, so it integrates to the non-delta share); (N,)."""
    dt = _dtype(wi, wo)
    wi = np.asarray(wi, dt)
    wo = np.asarray(wo, dt)
    out = np.zeros(len(wi), dt)
    flip = _flip_mask(sp, wi)
    wi = _flipz(wi, flip)
    wo = _flipz(wo, flip)
    for k, sel in _groups(sp.kind):
        sub = sp if isinstance(sel, slice) else sp.subset(sel)
        r = _pdf_kind(k, sub, wi[sel], wo[sel])
        if r is not None:
            out[sel] = _finite(r)
    return out


def _rough_dielectric(sp, wi, u2, mode):
    """(Added with ROUGHDIELECTRIC, after the move: the oracle of the new kind.) A rough
    dielectric crossed at one microfacet normal drawn from those visible from wi turned
    outside: (reflected wo, F G1(wo) specular, refracted wo, (1 - F) G1(wo) transmittance
    (x eta_ti^2 in radiance mode), F); a side the crossing cannot reach weighs 0."""
    s = np.where(wi[:, 2] >= 0, 1.0, -1.0).astype(wi.dtype)
    m, _pm = mf.sample_visible(wi * s[:, None], u2, sp.alpha, sp.beckmann)
    c = np.sum(wi * m, axis=-1)
    r, cos_t, _eta_it, eta_ti = fresnel_dielectric(c, sp.eta)
    r_wo = reflect_m(wi, m)
    t_wo = (c * eta_ti + cos_t)[:, None] * m - eta_ti[:, None] * wi
    ok = (wi[:, 2] != 0) & (c != 0)
    gr = np.where(ok & (r_wo[:, 2] * wi[:, 2] > 0), mf.smith_g1(r_wo, m, sp.alpha, sp.beckmann), 0.0) * r
    gt = np.where(ok & (t_wo[:, 2] * wi[:, 2] < 0), mf.smith_g1(t_wo, m, sp.alpha, sp.beckmann), 0.0) * (1.0 - r)
    if mode == "radiance":
        gt = gt * eta_ti * eta_ti
    return r_wo, sp.specular * gr[:, None], t_wo, sp.transmittance * gt[:, None], r


def _sample_kind(k, sp, wi, u1, u2, mode):
    n = len(wi)
    dt = wi.dtype
    wo = np.zeros((n, 3), dt)
    wo[:, 2] = 1.0
    weight = np.zeros((n, 3), dt)
    p = np.zeros(n, dt)
    delta = np.zeros(n, bool)
    ci = wi[:, 2]
    if k == DIFFUSE:
        wo = square_to_cosine_hemisphere(u2).astype(dt, copy=False)
        ok = (ci > 0) & (wo[:, 2] > 0)
        p = np.where(ok, _cos_hemisphere_pdf(wo), 0.0)
        weight = np.where(ok[:, None], sp.diffuse, 0.0)
    elif k == ROUGHPLASTIC_DIFFUSE:
        wo = square_to_cosine_hemisphere(u2).astype(dt, copy=False)
        ok = (ci > 0) & (wo[:, 2] > 0)
        p = np.where(ok, _cos_hemisphere_pdf(wo), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            weight = np.where((ok & (p > 0))[:, None], _roughplastic_diffuse(sp, wi, wo) / p[:, None], 0.0)
    elif k == CONDUCTOR:
        ok = ci > 0
        wo = reflect(wi)
        F = fresnel_conductor(ci, sp.cond_eta, sp.cond_k)
        weight = np.where(ok[:, None], F * sp.specular, 0.0)
        p = np.where(ok, 1.0, 0.0)
        delta = ok
    elif k in (ROUGHCONDUCTOR, ROUGHPLASTIC_LOBE):
        ok = ci > 0
        m, pm = mf.sample_visible(wi, u2, sp.alpha, sp.beckmann)
        wo = reflect_m(wi, m)
        dwm = np.sum(wo * m, axis=-1)
        ok &= (pm != 0) & (wo[:, 2] > 0) & (np.sum(wi * m, axis=-1) > 1e-9)  # as the kernel: wi·m ~0 is ill-posed
        with np.errstate(invalid="ignore", divide="ignore"):
            p = pm / (4.0 * dwm)
        g = mf.smith_g1(wo, m, sp.alpha, sp.beckmann)
        if k == ROUGHCONDUCTOR:
            F = fresnel_conductor(np.sum(wi * m, axis=-1), sp.cond_eta, sp.cond_k)
        else:  # the coat lobe alone (ROUGHPLASTIC_LOBE)
            F = fresnel_dielectric(np.sum(wi * m, axis=-1), sp.eta)[0][:, None]
        weight = np.where(ok[:, None], F * sp.specular * g[:, None], 0.0)
        p = np.where(ok, p, 0.0)
    elif k == DIELECTRIC:
        r, cos_t, eta_it, eta_ti = fresnel_dielectric(ci, sp.eta)
        sel_r = u1 <= r
        wo = np.where(sel_r[:, None], reflect(wi), refract(wi, cos_t, eta_ti))
        tw = sp.transmittance * ((eta_ti * eta_ti)[:, None] if mode == "radiance" else 1.0)
        weight = np.where(sel_r[:, None], sp.specular, tw)
        p = np.where(sel_r, r, 1.0 - r)
        ok = p > 0
        weight = np.where(ok[:, None], weight, 0.0)
        delta = ok
    elif k == ROUGHDIELECTRIC:
        r_wo, r_w, t_wo, t_w, r = _rough_dielectric(sp, wi, u2, mode)
        sel_r = u1 <= r
        wo = np.where(sel_r[:, None], r_wo, t_wo)
        p = np.where(sel_r, r, 1.0 - r)
        ok = p > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            weight = np.where(ok[:, None], np.where(sel_r[:, None], r_w, t_w) / p[:, None], 0.0)
        delta = ok
    elif k == THINDIELECTRIC:
        r = _thin_r(ci, sp.eta)
        sel_r = u1 <= r
        wo = np.where(sel_r[:, None], reflect(wi), -wi)
        weight = np.where(sel_r[:, None], sp.specular, sp.transmittance)
        p = np.where(sel_r, r, 1.0 - r)
        ok = p > 0
        weight = np.where(ok[:, None], weight, 0.0)
        delta = ok
    elif k == PLASTIC:
        ok = ci > 0
        f_i = fresnel_dielectric(ci, sp.eta)[0]
        ps, pd = _plastic_probs(f_i, sp.sampling_weight())
        sel_s = ok & (u1 < ps)
        wo_d = square_to_cosine_hemisphere(u2).astype(dt, copy=False)
        wo = np.where(sel_s[:, None], reflect(wi), wo_d)
        ev = _eval_plastic(sp, wi, wo_d)
        pdf_d = pd * _cos_hemisphere_pdf(wo_d)
        with np.errstate(invalid="ignore", divide="ignore"):
            w_d = ev / pdf_d[:, None]
            w_s = sp.specular * (f_i / ps)[:, None]
        ok_d = ok & ~sel_s & (pdf_d > 0)
        weight = np.where(sel_s[:, None], w_s, np.where(ok_d[:, None], w_d, 0.0))
        p = np.where(sel_s, ps, np.where(ok_d, pdf_d, 0.0))
        delta = sel_s
    elif k == ROUGHPLASTIC:
        ok = ci > 0
        tabs, rows, _ = _rough_tables(sp)
        t_i = mf.lerp_gather(tabs.astype(dt, copy=False), rows, np.clip(ci, 0, 1))
        sw = sp.sampling_weight()
        ps = (1.0 - t_i) * sw
        pd = t_i * (1.0 - sw)
        with np.errstate(invalid="ignore", divide="ignore"):
            ps = np.where(ps + pd > 0, ps / (ps + pd), 0.0)
        sel_s = u1 < ps
        wo = square_to_cosine_hemisphere(u2).astype(dt, copy=False)
        if sel_s.any():
            ss = np.nonzero(sel_s)[0]
            sub = sp.subset(ss)
            m, _ = mf.sample_visible(wi[ss], u2[ss], sub.alpha, sub.beckmann)
            wo[ss] = reflect_m(wi[ss], m)
        val, p = _roughplastic_parts(sp, wi, wo)
        ok &= p > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            weight = np.where(ok[:, None], val / p[:, None], 0.0)
        p = np.where(ok, p, 0.0)
    # NULL: black, never samples
    return wo, _finite(weight), _finite(p), delta


def sample(sp: SurfacePoints, wi: np.ndarray, u1: np.ndarray, u2: np.ndarray, mode: str = "radiance"):
    """Importance-sample ``wo`` given ``wi``; ``u1`` (N,) picks the component, ``u2`` (N, 2).

    Returns ``(wo (N,3), weight (N,3), pdf (N,), delta (N,) bool)``. Non-delta samples:
    weight = eval/pdf, pdf the solid-angle density (== :func:`pdf`). Delta samples: weight the
    delta weight (Mitsuba's, i.e. value / lobe probability), pdf the discrete lobe probability.
    Failed samples (and NULL) have weight 0, pdf 0, delta False.
    """
    dt = _dtype(wi)
    wi = np.asarray(wi, dt)
    u1 = np.asarray(u1, dt).ravel()
    u2 = np.asarray(u2, dt).reshape(-1, 2)
    n = len(wi)
    wo = np.zeros((n, 3), dt)
    weight = np.zeros((n, 3), dt)
    p = np.zeros(n, dt)
    delta = np.zeros(n, bool)
    flip = _flip_mask(sp, wi)
    wi = _flipz(wi, flip)
    for k, sel in _groups(sp.kind):
        sub = sp if isinstance(sel, slice) else sp.subset(sel)
        r = _sample_kind(k, sub, wi[sel], u1[sel], u2[sel], mode)
        wo[sel], weight[sel], p[sel], delta[sel] = r
    wo = _flipz(wo, flip)
    return wo, weight, p, delta


def sample_lobe(sp: SurfacePoints, wi: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample only the glossy lobe of rough conductors and plastics (the paper's split of an
    eye path per BSDF component): ``(wo (N, 3), weight (N, 3))`` with weight = lobe value ×
    cos / lobe pdf, a smooth plastic's the coat's mirror reflection with weight F × specular;
    the diffuse layer of a plastic is left to ROUGHPLASTIC_DIFFUSE. Other kinds give weight 0."""
    dt = _dtype(wi)
    wi = np.asarray(wi, dt)
    u2 = np.asarray(u2, dt).reshape(-1, 2)
    n = len(wi)
    wo = np.zeros((n, 3), dt)
    wo[:, 2] = 1.0
    weight = np.zeros((n, 3), dt)
    flip = _flip_mask(sp, wi)
    wif = _flipz(wi, flip)
    for k, sel in _groups(sp.kind):
        sub = sp if isinstance(sel, slice) else sp.subset(sel)
        w = wif[sel]
        if k == ROUGHCONDUCTOR:
            o, wt, _p, _d = _sample_kind(k, sub, w, np.zeros(len(w), dt), u2[sel], "radiance")
            wo[sel], weight[sel] = o, wt
        elif k in (ROUGHPLASTIC, ROUGHPLASTIC_LOBE):
            ok = w[:, 2] > 0
            m, _ = mf.sample_visible(w, u2[sel], sub.alpha, sub.beckmann)
            o = reflect_m(w, m)
            with np.errstate(invalid="ignore", divide="ignore"):
                F = fresnel_dielectric(np.sum(w * m, axis=-1), sub.eta)[0]
                g1o = mf.smith_g1(o, m, sub.alpha, sub.beckmann)
            ok &= o[:, 2] > 0
            wo[sel] = o
            weight[sel] = np.where(ok[:, None], _finite(sub.specular * (F * g1o)[:, None]), 0.0)
        elif k == PLASTIC:
            ok = w[:, 2] > 0
            F = fresnel_dielectric(np.where(ok, w[:, 2], 1.0), sub.eta)[0]
            wo[sel] = np.where(ok[:, None], w * np.array([-1.0, -1.0, 1.0]), wo[sel])
            weight[sel] = np.where(ok[:, None], sub.specular * F[:, None], 0.0)
    return _flipz(wo, flip), _finite(weight)


def _thin_r(cos_i, eta):
    r = fresnel_dielectric(np.abs(cos_i), eta)[0]
    return r * 2.0 / (1.0 + r)  # R + TRT + TR^3T + ...


def specular_components(sp: SurfacePoints, wi: np.ndarray, mode: str = "radiance", u2=None):
    """Deterministic split of an eye path at delta surfaces.

    Returns ``[(wo, weight, valid), (wo, weight, valid)]``: entry 0 the delta reflection, entry 1
    the delta transmission (see the module docstring for which kinds have which). Weights carry
    the Fresnel factor and the specular textures (no lobe-selection division); the dielectric
    transmission is scaled by eta_ti^2 in radiance mode, as Mitsuba does.
    """
    dt = _dtype(wi)
    wi = np.asarray(wi, dt)
    n = len(wi)
    flip = _flip_mask(sp, wi)
    wif = _flipz(wi, flip)
    ci = wif[:, 2]
    kind = sp.kind
    r_wo = _flipz(reflect(wif), flip)
    r_w = np.zeros((n, 3), dt)
    t_wo = -wi.copy()
    t_w = np.zeros((n, 3), dt)

    m = kind == CONDUCTOR
    if m.any():
        s = sp.subset(m)
        F = fresnel_conductor(ci[m], s.cond_eta, s.cond_k)
        r_w[m] = np.where((ci[m] > 0)[:, None], F * s.specular, 0.0)
    m = kind == PLASTIC
    if m.any():
        s = sp.subset(m)
        f = fresnel_dielectric(ci[m], s.eta)[0]
        r_w[m] = np.where((ci[m] > 0)[:, None], f[:, None] * s.specular, 0.0)
    m = kind == DIELECTRIC
    if m.any():
        s = sp.subset(m)
        r, cos_t, _eta_it, eta_ti = fresnel_dielectric(ci[m], s.eta)
        r_w[m] = r[:, None] * s.specular
        scale = (eta_ti * eta_ti)[:, None] if mode == "radiance" else 1.0
        t_w[m] = ((1.0 - r)[:, None] * s.transmittance) * scale
        t_wo[m] = refract(wi[m], cos_t, eta_ti)
    m = kind == ROUGHDIELECTRIC
    if m.any():
        u = np.full((n, 2), 0.5) if u2 is None else np.asarray(u2, np.float64).reshape(-1, 2)
        r_wo[m], r_w[m], t_wo[m], t_w[m], _r = _rough_dielectric(sp.subset(m), wi[m], u[m], mode)
    m = kind == THINDIELECTRIC
    if m.any():
        s = sp.subset(m)
        r = _thin_r(ci[m], s.eta)
        r_w[m] = r[:, None] * s.specular
        t_w[m] = (1.0 - r)[:, None] * s.transmittance
    r_w = _finite(r_w)
    t_w = _finite(t_w)
    r_valid = np.any(r_w > 0, axis=-1)
    t_valid = np.any(t_w > 0, axis=-1)
    return [(r_wo, r_w, r_valid), (t_wo, t_w, t_valid)]


def albedo(sp: SurfacePoints, wi: np.ndarray) -> np.ndarray:
    """Smooth per-point reflectance estimate (N, 3) used to demodulate radiance.

    diffuse: diffuse reflectance; conductors: Fresnel at normal incidence x specular; plastics:
    the diffuse layer's directional albedo (diffuse/(1-Fdr_int) x inv_eta^2 x T_in x mean T_out)
    + the coat's directional reflectance x specular; dielectrics: R0 x specular + (1-R0) x transmittance;
    NULL: 0. Evaluated at |cos theta_i| (clamped away from 0), so it stays > 0 on back faces and at
    grazing angles wherever the material has any nonzero reflectance.
    """
    dt = _dtype(wi)
    wi = np.asarray(wi, dt)
    n = len(wi)
    out = np.zeros((n, 3), dt)
    ci = np.clip(np.abs(wi[:, 2]), 0.05, 1.0).astype(dt, copy=False)
    for k, sel in _groups(sp.kind):
        s = sp if isinstance(sel, slice) else sp.subset(sel)
        c = ci[sel]
        if k == DIFFUSE:
            out[sel] = s.diffuse
        elif k in (CONDUCTOR, ROUGHCONDUCTOR):
            out[sel] = fresnel_conductor(np.ones_like(c), s.cond_eta, s.cond_k) * s.specular
        elif k in (DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC):
            r0 = fresnel_dielectric(np.ones_like(c), s.eta)[0][:, None]
            out[sel] = r0 * s.specular + (1.0 - r0) * s.transmittance
        elif k == PLASTIC:
            eta = s.eta.astype(np.float64)
            f_i = fresnel_dielectric(c, s.eta)[0]
            fdr_int = np.asarray(fresnel_diffuse_reflectance(1.0 / eta), dt)
            fdr_ext = np.asarray(fresnel_diffuse_reflectance(eta), dt)
            diff = _plastic_diffuse_coef(s, fdr_int)
            dscale = (1.0 - f_i) * (1.0 - fdr_ext) / (s.eta * s.eta)
            out[sel] = diff * dscale[:, None] + f_i[:, None] * s.specular
        elif k in (ROUGHPLASTIC, ROUGHPLASTIC_DIFFUSE):
            tabs, rows, fdr_int, refl = _rough_tables(s, with_reflectance=True)
            t_i = mf.lerp_gather(tabs.astype(dt), rows, c)
            r_i = mf.lerp_gather(refl.astype(dt), rows, c)
            t_avg = _cosine_mean(tabs).astype(dt)  # cosine-weighted mean of t_o
            t_avg = t_avg[0] if rows is None else t_avg[rows]
            diff = _plastic_diffuse_coef(s, fdr_int.astype(dt))
            dscale = t_i * t_avg / (s.eta * s.eta)
            out[sel] = diff * dscale[:, None]
            if k == ROUGHPLASTIC:
                out[sel] += r_i[:, None] * s.specular
        elif k == ROUGHPLASTIC_LOBE:
            _tabs, rows, _fdr, refl = _rough_tables(s, with_reflectance=True)
            out[sel] = mf.lerp_gather(refl.astype(dt), rows, c)[:, None] * s.specular
    return _finite(out)
