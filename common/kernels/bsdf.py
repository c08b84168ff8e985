"""The BSDFs of common.bsdf as compiled scalar kernels: one point at a time, float64.

Every function reads the point's parameters from the packed tuple ``P`` built by
common.bsdf.pack (order and dtypes fixed; n points, G coat tables of R samples)::

    P = (kind int8[n], diffuse f64[n,3], specular f64[n,3], transm f64[n,3], alpha f64[n],
         eta f64[n], cond_eta f64[n,3], cond_k f64[n,3], beck bool[n], nonlin bool[n],
         twos bool[n], spec_weight f64[n], rtabs f64[G,R], rrefl f64[G,R], rrow int64[n],
         fdr_int f64[n], tavg f64[n])

``rtabs``/``rrefl``: rough plastics' coat transmittance / reflectance tables over
cos θ = linspace(0, 1, R); ``rrow`` the point's table row (row 0, all-ones transmittance, for
points that are not rough plastics); ``fdr_int`` the internal diffuse Fresnel reflectance (of
the rough coat's table, or of a smooth plastic's eta; 0 elsewhere); ``tavg`` the
cosine-weighted mean of the point's transmittance table.

Conventions as common.bsdf: local shading frame (z = normal), wi toward the viewer and wo
toward the light, both away from the surface; values include |cos θ_o|; a twosided
non-transmissive point seen from below is evaluated mirrored (z flipped); non-finite results
become 0.

The Fresnel and microfacet math the kinds share lives here too, not in sibling modules:
numba's on-disk cache keys a kernel on its own file only, so a change to a helper in another
file would leave these kernels running the old helper from the cache.
"""
from __future__ import annotations

import math

from numba import njit

from igi.common.lights import LUMINANCE_WEIGHTS
from igi.common.scene import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    PLASTIC,
    ROUGHCONDUCTOR,
    ROUGHDIELECTRIC,
    ROUGHDIELECTRIC_R,
    ROUGHDIELECTRIC_T,
    ROUGHPLASTIC,
    ROUGHPLASTIC_DIFFUSE,
    ROUGHPLASTIC_LOBE,
    THINDIELECTRIC,
)

from .texture import texel

_WR, _WG, _WB = LUMINANCE_WEIGHTS  # (frozen into the kernels as constants)

INV_PI = 1.0 / math.pi
INV_SQRT_PI = 1.0 / math.sqrt(math.pi)
TWO_OVER_SQRT_PI = 2.0 / math.sqrt(math.pi)
EPS4 = 4.0 * 2.220446049250313e-16  # 4 × float64 machine epsilon

# No reference counting (_nrt=False): the kernels only read arrays their caller keeps alive,
# and counting the references of P's arrays on every call cost 5-10x the BSDF math itself.
_KERNEL = {"cache": True, "nogil": True, "error_model": "numpy", "_nrt": False}
# Functions of P are inlined (inline="always", numba IR): a call passing the 17 arrays of P
# by value costs more than most evaluations. Callers in other compiled code inline them too.


# ----------------------------------------------------------------------------------------------
# Fresnel (as common.fresnel, one value at a time)


@njit(**_KERNEL)
def max0(x: float) -> float:
    """np.maximum(x, 0): NaN stays NaN (Python's max would drop it)."""
    return 0.0 if x < 0.0 else x


@njit(**_KERNEL)
def fresnel_dielectric(cos_theta_i: float, eta: float) -> tuple:
    """``(R, cos_theta_t, eta_it, eta_ti)`` as common.fresnel.fresnel_dielectric for one point."""
    outside = cos_theta_i >= 0.0
    rcp_eta = 1.0 / eta
    eta_it = eta if outside else rcp_eta
    eta_ti = rcp_eta if outside else eta
    cos_t_sqr = 1.0 - (1.0 - cos_theta_i * cos_theta_i) * (eta_ti * eta_ti)
    ci = abs(cos_theta_i)
    ct = math.sqrt(max0(cos_t_sqr))
    a_s = (ci - eta_it * ct) / (ci + eta_it * ct)
    a_p = (ct - eta_it * ci) / (ct + eta_it * ci)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    if eta == 1.0:  # index-matched
        r = 0.0
    elif ci == 0.0:
        r = 1.0
    if cos_t_sqr <= 0.0:  # total internal reflection (also overrides the index-matched 0)
        r = 1.0
    cos_t = -ct if cos_theta_i >= 0.0 else ct
    return r, cos_t, eta_it, eta_ti


@njit(**_KERNEL)
def fresnel_conductor(c: float, eta: float, k: float) -> float:
    """Unpolarized reflectance of a conductor (one colour channel) at cos θ_i = ``c``;
    ``eta = k = 0`` (and any non-finite result) is the perfect mirror, R = 1."""
    c2 = c * c
    s2 = 1.0 - c2
    s4 = s2 * s2
    temp1 = eta * eta - k * k - s2
    a2pb2 = math.sqrt(max0(temp1 * temp1 + 4.0 * k * k * eta * eta))
    a = math.sqrt(max0(0.5 * (a2pb2 + temp1)))
    term1 = a2pb2 + c2
    term2 = 2.0 * c * a
    r_s = (term1 - term2) / (term1 + term2)
    term3 = a2pb2 * c2 + s4
    term4 = term2 * s2
    r_p = r_s * (term3 - term4) / (term3 + term4)
    r = 0.5 * (r_s + r_p)
    if (eta == 0.0 and k == 0.0) or not math.isfinite(r):
        return 1.0
    return max0(r)  # eta = 1, k = 0 cancels to ~-1e-17: a reflectance is never negative


@njit(**_KERNEL)
def fresnel_diffuse_reflectance(eta: float) -> float:
    """Fdr, Mitsuba's fits (Egan & Hilgeman for eta < 1, d'Eon & Irving otherwise)."""
    if eta < 1.0:
        return -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    ie = 1.0 / eta
    ie2 = ie * ie
    return (0.919317 - 3.4793 * ie + 6.75335 * ie2 - 7.80989 * ie2 * ie
            + 4.98554 * ie2 * ie2 - 1.36881 * ie2 * ie2 * ie)


# ----------------------------------------------------------------------------------------------
# microfacet distributions and warps (as common.microfacet, one value at a time)


@njit(**_KERNEL)
def clamp(x: float, lo: float, hi: float) -> float:
    """np.clip for one value: NaN stays NaN."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@njit(**_KERNEL)
def erfinv(y: float) -> float:
    """Inverse error function to float64 precision: Giles' single-precision polynomial (the one
    Mitsuba / Dr.Jit use) refined by Halley steps on erf. ±1 → ±inf, |y| > 1 or NaN → NaN
    (as scipy.special.erfinv)."""
    if not abs(y) < 1.0:
        if y == 1.0:
            return math.inf
        if y == -1.0:
            return -math.inf
        return math.nan
    w = -math.log((1.0 - y) * (1.0 + y))
    if w < 5.0:
        w = w - 2.5
        p = 2.81022636e-08
        p = 3.43273939e-07 + p * w
        p = -3.5233877e-06 + p * w
        p = -4.39150654e-06 + p * w
        p = 0.00021858087 + p * w
        p = -0.00125372503 + p * w
        p = -0.00417768164 + p * w
        p = 0.246640727 + p * w
        p = 1.50140941 + p * w
    else:
        w = math.sqrt(w) - 3.0
        p = -0.000200214257
        p = 0.000100950558 + p * w
        p = 0.00134934322 + p * w
        p = -0.00367342844 + p * w
        p = 0.00573950773 + p * w
        p = -0.0076224613 + p * w
        p = 0.00943887047 + p * w
        p = 1.00167406 + p * w
        p = 2.83297682 + p * w
    x = p * y
    # Halley steps on erf(x) = y (the residual through erfc near |y| = 1 keeps its digits).
    # Its error after a step is ~(x²+1)/3 · dx³: from the polynomial's ~1e-7 one step gives
    # float64 precision; only |y| within ~1e-7 of 1, beyond the polynomial's float32 range,
    # starts farther off and takes a few more.
    for _ in range(40):
        if y > 0.5:
            r = (1.0 - y) - math.erfc(x)
        elif y < -0.5:
            r = math.erfc(-x) - (1.0 + y)
        else:
            r = math.erf(x) - y
        d = TWO_OVER_SQRT_PI * math.exp(-x * x)  # erf'(x); erf''/erf' = -2x
        dx = r / (d + x * r)
        x = x - dx
        if not abs(dx) > 1e-6:
            break
    return x


@njit(**_KERNEL)
def concentric_disk(u0: float, u1: float) -> tuple:
    """Shirley-Chiu concentric square → disk map (Mitsuba's square_to_uniform_disk_concentric)."""
    x = 2.0 * u0 - 1.0
    y = 2.0 * u1 - 1.0
    q13 = abs(x) < abs(y)
    r = y if q13 else x
    rp = x if q13 else y
    phi = 0.25 * math.pi * rp / r
    if q13:
        phi = 0.5 * math.pi - phi
    if x == 0.0 and y == 0.0:
        phi = 0.0
    return r * math.cos(phi), r * math.sin(phi)


@njit(**_KERNEL)
def cosine_hemisphere(u0: float, u1: float) -> tuple:
    """Cosine-weighted hemisphere direction (Malley's method over the concentric disk)."""
    px, py = concentric_disk(u0, u1)
    return px, py, math.sqrt(max0(1.0 - px * px - py * py))


@njit(**_KERNEL)
def ndf(mx: float, my: float, mz: float, alpha: float, beckmann: bool) -> float:
    """Microfacet normal distribution D(m); 0 where D·m_z <= 1e-20."""
    a = 1e-4 if alpha < 1e-4 else alpha
    a2 = a * a
    cos2 = mz * mz
    xy2 = mx * mx + my * my
    if beckmann:
        res = math.exp(-xy2 / (a2 * cos2)) / (math.pi * a2 * cos2 * cos2)
    else:
        t = xy2 / a2 + cos2
        res = 1.0 / (math.pi * a2 * t * t)
    return res if res * mz > 1e-20 else 0.0


@njit(**_KERNEL)
def smith_g1(vx: float, vy: float, vz: float, mx: float, my: float, mz: float,
             alpha: float, beckmann: bool) -> float:
    """Smith's shadowing-masking for one direction (Mitsuba's rational Beckmann fit); 0 on the
    wrong side of m, NaN → 0."""
    a = 1e-4 if alpha < 1e-4 else alpha
    xy_alpha_2 = (a * a) * (vx * vx + vy * vy)
    tan_theta_alpha_2 = xy_alpha_2 / (vz * vz)
    if beckmann:
        ab = 1.0 / math.sqrt(tan_theta_alpha_2)
        ab2 = ab * ab
        res = 1.0 if ab >= 1.6 else (3.535 * ab + 2.181 * ab2) / (1.0 + 2.276 * ab + 2.577 * ab2)
    else:
        res = 2.0 / (1.0 + math.sqrt(1.0 + tan_theta_alpha_2))
    if xy_alpha_2 == 0.0:
        res = 1.0
    if (vx * mx + vy * my + vz * mz) * vz <= 0.0:
        res = 0.0
    return 0.0 if math.isnan(res) else res


@njit(**_KERNEL)
def _visible_11_ggx(cos_theta_i: float, u0: float, u1: float) -> tuple:
    px, py = concentric_disk(u0, u1)
    s = 0.5 * (1.0 + cos_theta_i)
    h = math.sqrt(max0(1.0 - px * px))
    py = h + (py - h) * s  # lerp(h, py, s)
    z = math.sqrt(max0(1.0 - px * px - py * py))
    sin_theta_i = math.sqrt(max0(1.0 - cos_theta_i * cos_theta_i))
    norm = 1.0 / (sin_theta_i * py + cos_theta_i * z)
    return (cos_theta_i * py - sin_theta_i * z) * norm, px * norm


@njit(**_KERNEL)
def _visible_11_beckmann(cos_theta_i: float, u0: float, u1: float) -> tuple:
    tan_theta_i = math.sqrt(max0(1.0 - cos_theta_i * cos_theta_i)) / cos_theta_i
    cot_theta_i = 1.0 / tan_theta_i
    maxval = math.erf(cot_theta_i)
    u0 = clamp(u0, 1e-6, 1.0 - 1e-6)
    u1 = clamp(u1, 1e-6, 1.0 - 1e-6)
    x = maxval - (maxval + 1.0) * math.erf(math.sqrt(-math.log(u0)))
    tail = 0.0 if tan_theta_i == 0.0 else INV_SQRT_PI * tan_theta_i * math.exp(-cot_theta_i * cot_theta_i)
    ux = u0 * (1.0 + maxval + tail)
    for _ in range(3):  # Newton on the CDF, parameterized in the erf() domain
        slope = erfinv(x)
        if tan_theta_i == 0.0:
            value = 1.0 + x - ux
            deriv = 1.0
        else:
            value = 1.0 + x + INV_SQRT_PI * tan_theta_i * math.exp(-slope * slope) - ux
            deriv = 1.0 - slope * tan_theta_i
        x = x - value / deriv
    return erfinv(x), erfinv(2.0 * u1 - 1.0)


@njit(**_KERNEL)
def sample_visible(wix: float, wiy: float, wiz: float, u0: float, u1: float,
                   alpha: float, beckmann: bool) -> tuple:
    """A microfacet normal m from the distribution of normals visible from wi (Heitz & d'Eon
    2014); a NaN component becomes 0, as the numpy version's nan_to_num."""
    a = 1e-4 if alpha < 1e-4 else alpha
    wpx = a * wix
    wpy = a * wiy
    wpz = wiz
    nrm = math.sqrt(wpx * wpx + wpy * wpy + wpz * wpz)
    wpx /= nrm
    wpy /= nrm
    wpz /= nrm
    r2 = wpx * wpx + wpy * wpy
    if r2 <= EPS4:
        cos_phi = 1.0
        sin_phi = 0.0
    else:
        inv = 1.0 / math.sqrt(r2)
        cos_phi = clamp(wpx * inv, -1.0, 1.0)
        sin_phi = clamp(wpy * inv, -1.0, 1.0)
    if beckmann:
        sx, sy = _visible_11_beckmann(wpz, u0, u1)
    else:
        sx, sy = _visible_11_ggx(wpz, u0, u1)
    tx = (cos_phi * sx - sin_phi * sy) * a
    ty = (sin_phi * sx + cos_phi * sy) * a
    nrm = math.sqrt(tx * tx + ty * ty + 1.0)
    mx = -tx / nrm
    my = -ty / nrm
    mz = 1.0 / nrm
    return (0.0 if math.isnan(mx) else mx), (0.0 if math.isnan(my) else my), (0.0 if math.isnan(mz) else mz)


@njit(**_KERNEL)
def pdf_visible(wix: float, wiy: float, wiz: float, mx: float, my: float, mz: float,
                alpha: float, beckmann: bool) -> float:
    """Density of :func:`sample_visible` over m: D(m) G1(wi, m) |wi·m| / wi_z; non-finite → 0."""
    p = (ndf(mx, my, mz, alpha, beckmann) * smith_g1(wix, wiy, wiz, mx, my, mz, alpha, beckmann)
         * abs(wix * mx + wiy * my + wiz * mz) / wiz)
    return p if math.isfinite(p) else 0.0


@njit(**_KERNEL)
def lerp_table(tables, row: int, x: float) -> float:
    """Mitsuba's ``lerp_gather``: linear interpolation in ``tables[row]`` sampled at
    linspace(0, 1, R); ``x`` is expected in [0, 1] (NaN gives NaN, never an out-of-range read)."""
    size = tables.shape[1]
    xs = x * (size - 1)
    idx = 0
    if xs >= size - 2:
        idx = size - 2
    elif xs > 0.0:
        idx = int(xs)
    v0 = tables[row, idx]
    v1 = tables[row, idx + 1]
    return v0 + (v1 - v0) * (xs - idx)


# ----------------------------------------------------------------------------------------------
# the BSDF kinds


@njit(**_KERNEL)
def _fin(x: float) -> float:
    return x if math.isfinite(x) else 0.0


@njit(**_KERNEL, inline="always")
def carries(r: float, g: float, b: float) -> bool:
    """An RGB weight that carries light: positive in some channel, finite in all (one row of
    common.bsdf.carrying)."""
    return (r > 0.0 or g > 0.0 or b > 0.0) and math.isfinite(r) and math.isfinite(g) and math.isfinite(b)


@njit(**_KERNEL, inline="always")
def _flipped(P, i: int, wiz: float) -> bool:
    """Twosided point seen from the back (transmissive kinds are two-sided by nature)."""
    k = P[0][i]
    return (P[10][i] and wiz < 0.0 and k != DIELECTRIC and k != THINDIELECTRIC and k != ROUGHDIELECTRIC
            and k != ROUGHDIELECTRIC_R and k != ROUGHDIELECTRIC_T)


@njit(**_KERNEL)
def _half(wix, wiy, wiz, wox, woy, woz) -> tuple:
    hx, hy, hz = wix + wox, wiy + woy, wiz + woz
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx / n, hy / n, hz / n


@njit(**_KERNEL, inline="always")
def _diffuse_coef(P, i: int, c: int) -> float:
    """A plastic's diffuse reflectance over 1 - internal reflection (nonlinear: per colour)."""
    d = P[1][i, c]
    f = P[15][i]
    return d / (1.0 - (d * f if P[9][i] else f))


@njit(**_KERNEL)
def _lobe_probability(spec_part: float, diffuse_part: float, sw: float) -> float:
    """Probability of sampling a plastic's specular lobe: sw × the coat's reflected share (F, or
    1 - t) against (1 - sw) × its transmitted share; 0 when both vanish."""
    ps = spec_part * sw
    pd = diffuse_part * (1.0 - sw)
    tot = ps + pd
    return ps / tot if tot > 0.0 else 0.0


@njit(**_KERNEL, inline="always")
def _coat_t(P, i: int, cos_theta: float) -> float:
    """A rough plastic's coat transmittance t(cos θ) (cos θ clamped to [0, 1])."""
    return lerp_table(P[12], P[14][i], clamp(cos_theta, 0.0, 1.0))


@njit(**_KERNEL, inline="always")
def _layer(P, i: int, t_i: float, co: float) -> tuple:
    """A rough plastic's diffuse layer × cos θ_o, given the coat transmittance t_i toward the
    incident side (no masking of invalid directions)."""
    t_o = lerp_table(P[12], P[14][i], clamp(co, 0.0, 1.0))
    eta = P[5][i]
    s = INV_PI / (eta * eta) * co * t_i * t_o
    return _diffuse_coef(P, i, 0) * s, _diffuse_coef(P, i, 1) * s, _diffuse_coef(P, i, 2) * s


@njit(**_KERNEL, inline="always")
def _rough_plastic(P, i: int, wix, wiy, wiz, wox, woy, woz) -> tuple:
    """(r, g, b, pdf) of the whole rough plastic: coat lobe + diffuse layer."""
    ci, co = wiz, woz
    if not (ci > 0.0 and co > 0.0):
        return 0.0, 0.0, 0.0, 0.0
    a = P[4][i]
    beck = P[8][i]
    t_i = _coat_t(P, i, ci)
    ps = _lobe_probability(1.0 - t_i, t_i, P[11][i])
    hx, hy, hz = _half(wix, wiy, wiz, wox, woy, woz)
    d = ndf(hx, hy, hz, a, beck)
    g1i = smith_g1(wix, wiy, wiz, hx, hy, hz, a, beck)
    pdf = ps * (d * g1i / (4.0 * ci)) + (1.0 - ps) * (INV_PI * co)
    f = fresnel_dielectric(wix * hx + wiy * hy + wiz * hz, P[5][i])[0]
    spec = f * d * (g1i * smith_g1(wox, woy, woz, hx, hy, hz, a, beck)) / (4.0 * ci)
    lr, lg, lb = _layer(P, i, t_i, co)
    s = P[2]
    return (_fin(s[i, 0] * spec + lr), _fin(s[i, 1] * spec + lg), _fin(s[i, 2] * spec + lb), _fin(pdf))


@njit(**_KERNEL, inline="always")
def _eval_pdf_kind(P, i: int, k: int, wix, wiy, wiz, wox, woy, woz) -> tuple:
    ci, co = wiz, woz
    if k == DIFFUSE or k == ROUGHPLASTIC_DIFFUSE:
        if not (ci > 0.0 and co > 0.0):
            return 0.0, 0.0, 0.0, 0.0
        p = INV_PI * co
        if k == DIFFUSE:
            d = P[1]
            return d[i, 0] * p, d[i, 1] * p, d[i, 2] * p, p
        lr, lg, lb = _layer(P, i, _coat_t(P, i, ci), co)
        return _fin(lr), _fin(lg), _fin(lb), p
    if k == ROUGHCONDUCTOR or k == ROUGHPLASTIC_LOBE:
        hx, hy, hz = _half(wix, wiy, wiz, wox, woy, woz)
        a = P[4][i]
        beck = P[8][i]
        d = ndf(hx, hy, hz, a, beck)
        g1i = smith_g1(wix, wiy, wiz, hx, hy, hz, a, beck)
        dwi = wix * hx + wiy * hy + wiz * hz
        p = 0.0
        if ci > 0.0 and co > 0.0 and dwi > 0.0 and (wox * hx + woy * hy + woz * hz) > 0.0:
            p = d * g1i / (4.0 * ci)
        if not (ci > 0.0 and co > 0.0 and d != 0.0):
            return 0.0, 0.0, 0.0, p
        val = d * (g1i * smith_g1(wox, woy, woz, hx, hy, hz, a, beck)) / (4.0 * ci)
        s, ce, ck = P[2], P[6], P[7]
        if k == ROUGHPLASTIC_LOBE:
            fv = fresnel_dielectric(dwi, P[5][i])[0] * val
            return s[i, 0] * fv, s[i, 1] * fv, s[i, 2] * fv, p
        return (fresnel_conductor(dwi, ce[i, 0], ck[i, 0]) * s[i, 0] * val,
                fresnel_conductor(dwi, ce[i, 1], ck[i, 1]) * s[i, 1] * val,
                fresnel_conductor(dwi, ce[i, 2], ck[i, 2]) * s[i, 2] * val, p)
    if k == PLASTIC:
        if not (ci > 0.0 and co > 0.0):
            return 0.0, 0.0, 0.0, 0.0
        eta = P[5][i]
        f_i = fresnel_dielectric(ci, eta)[0]
        f_o = fresnel_dielectric(co, eta)[0]
        s = INV_PI * co / (eta * eta) * (1.0 - f_i) * (1.0 - f_o)
        p = INV_PI * co * (1.0 - _lobe_probability(f_i, 1.0 - f_i, P[11][i]))
        return _diffuse_coef(P, i, 0) * s, _diffuse_coef(P, i, 1) * s, _diffuse_coef(P, i, 2) * s, p
    if k == ROUGHPLASTIC:
        return _rough_plastic(P, i, wix, wiy, wiz, wox, woy, woz)
    if k == ROUGHDIELECTRIC_R:
        return _rough_reflection(P, i, wix, wiy, wiz, wox, woy, woz)
    if k == ROUGHDIELECTRIC_T:
        return _rough_transmission(P, i, wix, wiy, wiz, wox, woy, woz)
    return 0.0, 0.0, 0.0, 0.0  # delta kinds and NULL


@njit(**_KERNEL, inline="always")
def _outward(hx, hy, hz) -> tuple:
    """``(ok, m)``: the (generalized) half vector h normalized and turned to the outside (z ≥ 0),
    as a rough dielectric's crossing draws its microfacet normals; ok False where h is 0 or NaN."""
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not hn > 0.0:
        return False, 0.0, 0.0, 1.0
    s = 1.0 if hz >= 0.0 else -1.0
    return True, s * hx / hn, s * hy / hn, s * hz / hn


@njit(**_KERNEL, inline="always")
def _rough_reflection(P, i: int, wix, wiy, wiz, wox, woy, woz) -> tuple:
    """``(f·|cos θ_o| rgb, pdf)`` of a rough dielectric's reflection from wi to wo on its side
    (outside or in), as :func:`_rough_dielectric` draws it: pdf the density of its reflected
    direction (the visible normals' density at the half vector m, over 4|wo·m|) and f·cos =
    pdf · F · G1(wo) · specular, the crossing's reflection weight (F = 1 past the critical angle)."""
    if not wiz * woz > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    ok, mx, my, mz = _outward(wix + wox, wiy + woy, wiz + woz)
    c = wix * mx + wiy * my + wiz * mz
    if not (ok and c * wiz > 1e-9):  # (m visible from wi; wi·m ~ 0: see _well_posed)
        return 0.0, 0.0, 0.0, 0.0
    a = P[4][i]
    beck = P[8][i]
    si = 1.0 if wiz >= 0.0 else -1.0
    p = pdf_visible(si * wix, si * wiy, si * wiz, mx, my, mz, a, beck) / (4.0 * abs(c))
    r = fresnel_dielectric(c, P[5][i])[0]
    w = p * r * smith_g1(wox, woy, woz, mx, my, mz, a, beck)
    sp = P[2]
    return _fin(w * sp[i, 0]), _fin(w * sp[i, 1]), _fin(w * sp[i, 2]), _fin(p)


@njit(**_KERNEL, inline="always")
def _rough_transmission(P, i: int, wix, wiy, wiz, wox, woy, woz) -> tuple:
    """``(f·|cos θ_o| rgb, pdf)`` of a rough dielectric's refraction from wi to wo on the other
    side, as :func:`_rough_dielectric` draws it: pdf the density of its refracted direction —
    the visible normals' density at the generalized half vector m ∝ wi + η_o/η_i · wo times
    the refraction's Jacobian η_o²|wo·m| / (η_i wi·m + η_o wo·m)² (Walter et al. 2007, eq. 17)
    — and f·cos = pdf · (1 − F) · G1(wo) · transmittance · η_ti²: the crossing's own
    transmission weight (radiance: eye paths are its only use), so that light samples taken
    through it and the crossing's traced ray are two estimators of one integral (MIS)."""
    if not wiz * woz < 0.0:
        return 0.0, 0.0, 0.0, 0.0
    a = P[4][i]
    beck = P[8][i]
    eta = P[5][i]
    eta_m = eta if wiz > 0.0 else 1.0 / eta  # η_o / η_i
    ok, mx, my, mz = _outward(wix + eta_m * wox, wiy + eta_m * woy, wiz + eta_m * woz)
    c = wix * mx + wiy * my + wiz * mz
    co = wox * mx + woy * my + woz * mz
    if not (ok and c * wiz > 0.0 and co * woz > 0.0):
        return 0.0, 0.0, 0.0, 0.0
    si = 1.0 if wiz >= 0.0 else -1.0
    den = c + eta_m * co
    p = pdf_visible(si * wix, si * wiy, si * wiz, mx, my, mz, a, beck) * eta_m * eta_m * abs(co) / (den * den)
    r, _cos_t, _eta_it, eta_ti = fresnel_dielectric(c, eta)
    w = p * (1.0 - r) * smith_g1(wox, woy, woz, mx, my, mz, a, beck) * eta_ti * eta_ti
    t = P[3]
    return _fin(w * t[i, 0]), _fin(w * t[i, 1]), _fin(w * t[i, 2]), _fin(p)


@njit(**_KERNEL, inline="always")
def glass_lobe_pdf(P, i: int, wix: float, wiy: float, wiz: float, wox: float, woy: float, woz: float) -> float:
    """pdf of wo through the lobe of rough glass row ``i`` of P that reaches it — its reflection
    (ROUGHDIELECTRIC_R) on wi's side, its refraction (ROUGHDIELECTRIC_T) on the other — as
    :func:`eval_pdf` of the row relabelled to that lobe (neither is mirrored for a twosided point)."""
    k = ROUGHDIELECTRIC_R if wiz * woz > 0.0 else ROUGHDIELECTRIC_T
    return _fin(_eval_pdf_kind(P, i, k, wix, wiy, wiz, wox, woy, woz)[3])


@njit(**_KERNEL, inline="always")
def eval_pdf(P, i: int, wix: float, wiy: float, wiz: float, wox: float, woy: float, woz: float) -> tuple:
    """``(r, g, b, pdf)``: f(wi, wo)|cos θ_o| of the non-delta components and the solid-angle
    density with which :func:`sample` draws wo through them (lobe selection included)."""
    if _flipped(P, i, wiz):
        wiz = -wiz
        woz = -woz
    r, g, b, p = _eval_pdf_kind(P, i, P[0][i], wix, wiy, wiz, wox, woy, woz)
    return _fin(r), _fin(g), _fin(b), _fin(p)


@njit(**_KERNEL, inline="always")
def _luminance(r: float, g: float, b: float) -> float:
    """Y of an RGB value."""
    return _WR * r + _WG * g + _WB * b


@njit(**_KERNEL, inline="always")
def _diffuse_luminance(P, i: int) -> float:
    """Y of a plastic's :func:`_diffuse_coef`."""
    return _luminance(_diffuse_coef(P, i, 0), _diffuse_coef(P, i, 1), _diffuse_coef(P, i, 2))


@njit(**_KERNEL, inline="always")
def lobe_shape(P, i: int, wix: float, wiy: float, wiz: float) -> tuple:
    """A cheap over-guess of the shape over wo of f(wi, wo)|cos θ_o| and of pdf(wi, wo) at a
    point seen from wi, for guesses that must be positive wherever f is (the shadow-ray
    roulette of worker.kernels.vpl_gather): ``(α², spec, diffuse, F0, pdf_spec, pdf_diffuse)``,

        f ≈ spec · F(cos θ_d) · Dn(h) + diffuse · cos θ_o,  pdf ≈ pdf_spec · Dn(h) + pdf_diffuse · cos θ_o,

    Dn the GGX distribution over its peak (a Beckmann lobe falls faster: GGX's tails over-guess
    it), F Schlick's from F0 (1: flat), Smith's G1 of wi at the lobe's centre (wo's, ≤ 1, left
    out); colours by their luminance. α² = 0 where a kind has no such shape (a flat guess)."""
    k = P[0][i]
    ci = abs(wiz)
    if not ci > 1e-4:
        ci = 1e-4
    if k == PLASTIC:
        eta = P[5][i]
        f_i = fresnel_dielectric(ci, eta)[0]
        dif = _diffuse_luminance(P, i) * INV_PI * (1.0 - f_i) / (eta * eta)
        return 1.0, 0.0, dif, 1.0, 0.0, INV_PI * (1.0 - _lobe_probability(f_i, 1.0 - f_i, P[11][i]))
    if not (k == ROUGHCONDUCTOR or k == ROUGHPLASTIC or k == ROUGHPLASTIC_LOBE):
        return 0.0, 0.0, 0.0, 1.0, 0.0, 0.0
    a = max(P[4][i], 1e-4)
    g1 = smith_g1(wix, wiy, ci, 0.0, 0.0, 1.0, a, P[8][i])
    peak = g1 / (4.0 * ci * math.pi * a * a)  # G1 · D(n) / (4 cos θ_i)
    s = P[2]
    spec = _luminance(s[i, 0], s[i, 1], s[i, 2]) * peak
    if k == ROUGHCONDUCTOR:
        return a * a, spec, 0.0, 1.0, peak, 0.0
    eta = P[5][i]
    f0 = (eta - 1.0) * (eta - 1.0) / ((eta + 1.0) * (eta + 1.0))
    if k == ROUGHPLASTIC_LOBE:
        return a * a, spec, 0.0, f0, peak, 0.0
    t_i = _coat_t(P, i, ci)
    ps = _lobe_probability(1.0 - t_i, t_i, P[11][i])
    dif = _diffuse_luminance(P, i) * INV_PI * t_i * _coat_t(P, i, 1.0) / (eta * eta)
    return a * a, spec, dif, f0, ps * peak, (1.0 - ps) * INV_PI


@njit(**_KERNEL, inline="always")
def _well_posed(wix, wiy, wiz, mx, my, mz) -> bool:
    """A reflection about m is usable: wi·m not ~0. There wo ≈ -wi (both on the horizon), the
    half vector eval/pdf recover from wi + wo cancels, and pdf(wi, wo) no longer equals the
    sampled density (hypothesis found wi_z ~ 1e-61); such samples carry ~nothing anyway."""
    return wix * mx + wiy * my + wiz * mz > 1e-9


@njit(**_KERNEL)
def _reflect_m(wix, wiy, wiz, mx, my, mz) -> tuple:
    d2 = 2.0 * (wix * mx + wiy * my + wiz * mz)
    return d2 * mx - wix, d2 * my - wiy, d2 * mz - wiz


@njit(**_KERNEL, inline="always")
def _rough_dielectric(P, i: int, wix, wiy, wiz, u2a, u2b, radiance: bool) -> tuple:
    """A rough dielectric crossed at one microfacet normal m, drawn with ``(u2a, u2b)`` from the
    normals visible from wi (turned to the outside first, as Mitsuba's roughdielectric samples):
    ``(reflected wo, weight F·G1(wo)·specular, refracted wo, weight (1 − F)·G1(wo)·transmittance,
    × eta_ti² when ``radiance``, F)``. Each weight is Mitsuba's sample weight of its lobe times
    the probability F or 1 − F with which its sampler picks that lobe, so over m the pair's sum
    is the whole BSDF's (Walter et al. 2007, with the separable Smith term). A side that the
    crossing cannot reach (a reflection through the surface, a refraction back out) weighs 0."""
    a = P[4][i]
    beck = P[8][i]
    s = 1.0 if wiz >= 0.0 else -1.0
    mx, my, mz = sample_visible(s * wix, s * wiy, s * wiz, u2a, u2b, a, beck)
    c = wix * mx + wiy * my + wiz * mz
    r, cos_t, _eta_it, eta_ti = fresnel_dielectric(c, P[5][i])
    rx, ry, rz = _reflect_m(wix, wiy, wiz, mx, my, mz)
    k = c * eta_ti + cos_t
    tx, ty, tz = k * mx - eta_ti * wix, k * my - eta_ti * wiy, k * mz - eta_ti * wiz
    ok = wiz != 0.0 and c != 0.0
    gr = smith_g1(rx, ry, rz, mx, my, mz, a, beck) if ok and rz * wiz > 0.0 else 0.0
    gt = smith_g1(tx, ty, tz, mx, my, mz, a, beck) if ok and tz * wiz < 0.0 else 0.0
    gt *= (1.0 - r) * (eta_ti * eta_ti if radiance else 1.0)
    gr *= r
    sp, tr = P[2], P[3]
    return (rx, ry, rz, sp[i, 0] * gr, sp[i, 1] * gr, sp[i, 2] * gr,
            tx, ty, tz, tr[i, 0] * gt, tr[i, 1] * gt, tr[i, 2] * gt, r)


@njit(**_KERNEL, inline="always")
def _sample_rough_conductor(P, i: int, wix, wiy, wiz, u2a, u2b) -> tuple:
    a = P[4][i]
    beck = P[8][i]
    mx, my, mz = sample_visible(wix, wiy, wiz, u2a, u2b, a, beck)
    pm = pdf_visible(wix, wiy, wiz, mx, my, mz, a, beck)
    wox, woy, woz = _reflect_m(wix, wiy, wiz, mx, my, mz)
    if not (wiz > 0.0 and pm != 0.0 and woz > 0.0 and _well_posed(wix, wiy, wiz, mx, my, mz)):
        return wox, woy, woz, 0.0, 0.0, 0.0, 0.0
    p = pm / (4.0 * (wox * mx + woy * my + woz * mz))
    g = smith_g1(wox, woy, woz, mx, my, mz, a, beck)
    c = wix * mx + wiy * my + wiz * mz
    s, ce, ck = P[2], P[6], P[7]
    return (wox, woy, woz, fresnel_conductor(c, ce[i, 0], ck[i, 0]) * s[i, 0] * g,
            fresnel_conductor(c, ce[i, 1], ck[i, 1]) * s[i, 1] * g,
            fresnel_conductor(c, ce[i, 2], ck[i, 2]) * s[i, 2] * g, p)


@njit(**_KERNEL, inline="always")
def _sample_coat_lobe(P, i: int, wix, wiy, wiz, u2a, u2b) -> tuple:
    """A rough plastic's coat lobe alone: visible-normal sample, weight F · G1(wo) · specular,
    the lobe's own solid-angle pdf (ROUGHPLASTIC_LOBE's pdf)."""
    a = P[4][i]
    beck = P[8][i]
    mx, my, mz = sample_visible(wix, wiy, wiz, u2a, u2b, a, beck)
    wox, woy, woz = _reflect_m(wix, wiy, wiz, mx, my, mz)
    pm = pdf_visible(wix, wiy, wiz, mx, my, mz, a, beck)
    if not (wiz > 0.0 and woz > 0.0 and pm != 0.0 and _well_posed(wix, wiy, wiz, mx, my, mz)):
        return wox, woy, woz, 0.0, 0.0, 0.0, 0.0
    f = fresnel_dielectric(wix * mx + wiy * my + wiz * mz, P[5][i])[0]
    fg = f * smith_g1(wox, woy, woz, mx, my, mz, a, beck)
    s = P[2]
    p = pm / (4.0 * (wox * mx + woy * my + woz * mz))
    return wox, woy, woz, s[i, 0] * fg, s[i, 1] * fg, s[i, 2] * fg, p


@njit(**_KERNEL)
def _thin_r(ci: float, eta: float) -> float:
    r = fresnel_dielectric(abs(ci), eta)[0]
    return r * 2.0 / (1.0 + r)  # R + TRT + TR^3T + ...


@njit(**_KERNEL, inline="always")
def _sample_kind(P, i: int, k: int, wix, wiy, wiz, u1, u2a, u2b, radiance: bool) -> tuple:
    """(wo, weight, pdf, delta) before the twosided flip of wo and the non-finite cleanup."""
    ci = wiz
    if k == DIFFUSE or k == ROUGHPLASTIC_DIFFUSE:
        wox, woy, woz = cosine_hemisphere(u2a, u2b)
        if not (ci > 0.0 and woz > 0.0):
            return wox, woy, woz, 0.0, 0.0, 0.0, 0.0, False
        p = INV_PI * woz
        if k == DIFFUSE:
            d = P[1]
            return wox, woy, woz, d[i, 0], d[i, 1], d[i, 2], p, False
        if not p > 0.0:
            return wox, woy, woz, 0.0, 0.0, 0.0, p, False
        lr, lg, lb = _layer(P, i, _coat_t(P, i, ci), woz)
        return wox, woy, woz, _fin(lr) / p, _fin(lg) / p, _fin(lb) / p, p, False
    if k == CONDUCTOR:
        if not ci > 0.0:
            return -wix, -wiy, wiz, 0.0, 0.0, 0.0, 0.0, False
        s, ce, ck = P[2], P[6], P[7]
        return (-wix, -wiy, wiz, fresnel_conductor(ci, ce[i, 0], ck[i, 0]) * s[i, 0],
                fresnel_conductor(ci, ce[i, 1], ck[i, 1]) * s[i, 1],
                fresnel_conductor(ci, ce[i, 2], ck[i, 2]) * s[i, 2], 1.0, True)
    if k == ROUGHCONDUCTOR:
        wox, woy, woz, wr, wg, wb, p = _sample_rough_conductor(P, i, wix, wiy, wiz, u2a, u2b)
        return wox, woy, woz, wr, wg, wb, p, False
    if k == ROUGHPLASTIC_LOBE:
        wox, woy, woz, wr, wg, wb, p = _sample_coat_lobe(P, i, wix, wiy, wiz, u2a, u2b)
        return wox, woy, woz, wr, wg, wb, p, False
    if k == ROUGHDIELECTRIC:
        res = _rough_dielectric(P, i, wix, wiy, wiz, u2a, u2b, radiance)
        r = res[12]
        at = 0 if u1 <= r else 6
        p = r if at == 0 else 1.0 - r
        if not p > 0.0:
            return res[at], res[at + 1], res[at + 2], 0.0, 0.0, 0.0, p, False
        return res[at], res[at + 1], res[at + 2], res[at + 3] / p, res[at + 4] / p, res[at + 5] / p, p, True
    if k == DIELECTRIC or k == THINDIELECTRIC:
        if k == DIELECTRIC:
            r, cos_t, _eta_it, eta_ti = fresnel_dielectric(ci, P[5][i])
        else:
            r = _thin_r(ci, P[5][i])
        if u1 <= r:
            p = r
            wox, woy, woz = -wix, -wiy, wiz
            tab = P[2]
            scale = 1.0
        else:
            p = 1.0 - r
            tab = P[3]
            if k == DIELECTRIC:
                wox, woy, woz = -eta_ti * wix, -eta_ti * wiy, cos_t
                scale = eta_ti * eta_ti if radiance else 1.0
            else:
                wox, woy, woz = -wix, -wiy, -wiz
                scale = 1.0
        if not p > 0.0:
            return wox, woy, woz, 0.0, 0.0, 0.0, p, False
        return wox, woy, woz, tab[i, 0] * scale, tab[i, 1] * scale, tab[i, 2] * scale, p, True
    if k == PLASTIC:
        f_i = fresnel_dielectric(ci, P[5][i])[0]
        ps = _lobe_probability(f_i, 1.0 - f_i, P[11][i])
        if ci > 0.0 and u1 < ps:
            s = P[2]
            w = f_i / ps
            return -wix, -wiy, wiz, s[i, 0] * w, s[i, 1] * w, s[i, 2] * w, ps, True
        wox, woy, woz = cosine_hemisphere(u2a, u2b)
        pdf_d = (1.0 - ps) * (INV_PI * woz)
        if not (ci > 0.0 and pdf_d > 0.0):
            return wox, woy, woz, 0.0, 0.0, 0.0, 0.0, False
        r, g, b, _p = _eval_pdf_kind(P, i, PLASTIC, wix, wiy, wiz, wox, woy, woz)
        return wox, woy, woz, r / pdf_d, g / pdf_d, b / pdf_d, pdf_d, False
    if k == ROUGHPLASTIC:
        t_i = _coat_t(P, i, ci)
        ps = _lobe_probability(1.0 - t_i, t_i, P[11][i])
        if u1 < ps:
            mx, my, mz = sample_visible(wix, wiy, wiz, u2a, u2b, P[4][i], P[8][i])
            wox, woy, woz = _reflect_m(wix, wiy, wiz, mx, my, mz)
        else:
            wox, woy, woz = cosine_hemisphere(u2a, u2b)
        r, g, b, p = _rough_plastic(P, i, wix, wiy, wiz, wox, woy, woz)
        if not (ci > 0.0 and p > 0.0):
            return wox, woy, woz, 0.0, 0.0, 0.0, 0.0, False
        return wox, woy, woz, r / p, g / p, b / p, p, False
    return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False  # NULL: black, never samples


@njit(**_KERNEL, inline="always")
def sample(P, i: int, wix: float, wiy: float, wiz: float, u1: float, u2a: float, u2b: float,
           radiance: bool) -> tuple:
    """``(wox, woy, woz, wr, wg, wb, pdf, delta)``: a direction drawn given wi (``u1`` picks the
    component, ``u2a, u2b`` the direction). Non-delta samples: weight = eval/pdf and the
    solid-angle pdf; delta samples: Mitsuba's delta weight and the lobe probability (dielectric
    transmission × eta_ti² when ``radiance``); failed samples: weight 0, pdf 0, not delta."""
    flip = _flipped(P, i, wiz)
    if flip:
        wiz = -wiz
    wox, woy, woz, wr, wg, wb, p, delta = _sample_kind(P, i, P[0][i], wix, wiy, wiz, u1, u2a, u2b, radiance)
    if flip:
        woz = -woz
    return wox, woy, woz, _fin(wr), _fin(wg), _fin(wb), _fin(p), delta


@njit(**_KERNEL, inline="always")
def sample_lobe(P, i: int, wix: float, wiy: float, wiz: float, u2a: float, u2b: float) -> tuple:
    """``(wox, woy, woz, wr, wg, wb)``: a direction from the glossy lobe alone of a rough
    conductor or rough plastic, weight = lobe value × cos / lobe pdf; of a smooth plastic its
    coat's mirror reflection, weight F × specular (a delta); other kinds weight 0."""
    flip = _flipped(P, i, wiz)
    if flip:
        wiz = -wiz
    k = P[0][i]
    wox, woy, woz, wr, wg, wb = 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
    if k == ROUGHCONDUCTOR:
        wox, woy, woz, wr, wg, wb, _p = _sample_rough_conductor(P, i, wix, wiy, wiz, u2a, u2b)
    elif k == ROUGHPLASTIC or k == ROUGHPLASTIC_LOBE:
        wox, woy, woz, wr, wg, wb, _p = _sample_coat_lobe(P, i, wix, wiy, wiz, u2a, u2b)
    elif k == PLASTIC and wiz > 0.0:
        f = fresnel_dielectric(wiz, P[5][i])[0]
        s = P[2]
        wox, woy, woz, wr, wg, wb = -wix, -wiy, wiz, f * s[i, 0], f * s[i, 1], f * s[i, 2]
    if flip:
        woz = -woz
    return wox, woy, woz, _fin(wr), _fin(wg), _fin(wb)


@njit(**_KERNEL, inline="always")
def albedo(P, i: int, wiz: float) -> tuple:
    """``(r, g, b)``: the smooth reflectance estimate of common.bsdf.albedo, at
    clamp(|cos θ_i|, 0.05, 1)."""
    k = P[0][i]
    c = clamp(abs(wiz), 0.05, 1.0)
    s, t = P[2], P[3]
    r = g = b = 0.0
    if k == DIFFUSE:
        d = P[1]
        r, g, b = d[i, 0], d[i, 1], d[i, 2]
    elif k == CONDUCTOR or k == ROUGHCONDUCTOR:
        ce, ck = P[6], P[7]
        r = fresnel_conductor(1.0, ce[i, 0], ck[i, 0]) * s[i, 0]
        g = fresnel_conductor(1.0, ce[i, 1], ck[i, 1]) * s[i, 1]
        b = fresnel_conductor(1.0, ce[i, 2], ck[i, 2]) * s[i, 2]
    elif k == DIELECTRIC or k == THINDIELECTRIC or k == ROUGHDIELECTRIC:
        r0 = fresnel_dielectric(1.0, P[5][i])[0]
        r = r0 * s[i, 0] + (1.0 - r0) * t[i, 0]
        g = r0 * s[i, 1] + (1.0 - r0) * t[i, 1]
        b = r0 * s[i, 2] + (1.0 - r0) * t[i, 2]
    elif k == ROUGHDIELECTRIC_R or k == ROUGHDIELECTRIC_T:  # (scales for the gather's demodulation)
        r0 = fresnel_dielectric(1.0, P[5][i])[0]
        tab = s if k == ROUGHDIELECTRIC_R else t
        f = r0 if k == ROUGHDIELECTRIC_R else 1.0 - r0
        r, g, b = f * tab[i, 0], f * tab[i, 1], f * tab[i, 2]
    elif k == PLASTIC:
        eta = P[5][i]
        f_i = fresnel_dielectric(c, eta)[0]
        dscale = (1.0 - f_i) * (1.0 - fresnel_diffuse_reflectance(eta)) / (eta * eta)
        r = _diffuse_coef(P, i, 0) * dscale + f_i * s[i, 0]
        g = _diffuse_coef(P, i, 1) * dscale + f_i * s[i, 1]
        b = _diffuse_coef(P, i, 2) * dscale + f_i * s[i, 2]
    elif k == ROUGHPLASTIC or k == ROUGHPLASTIC_DIFFUSE:
        eta = P[5][i]
        row = P[14][i]
        dscale = lerp_table(P[12], row, c) * P[16][i] / (eta * eta)
        r = _diffuse_coef(P, i, 0) * dscale
        g = _diffuse_coef(P, i, 1) * dscale
        b = _diffuse_coef(P, i, 2) * dscale
        if k == ROUGHPLASTIC:
            r_i = lerp_table(P[13], row, c)
            r += r_i * s[i, 0]
            g += r_i * s[i, 1]
            b += r_i * s[i, 2]
    elif k == ROUGHPLASTIC_LOBE:
        r_i = lerp_table(P[13], P[14][i], c)
        r, g, b = r_i * s[i, 0], r_i * s[i, 1], r_i * s[i, 2]
    return _fin(r), _fin(g), _fin(b)


@njit(**_KERNEL, inline="always")
def specular(P, i: int, wix: float, wiy: float, wiz: float, radiance: bool, u2a: float, u2b: float) -> tuple:
    """The deterministic delta split of common.bsdf.specular_components: ``(reflected wo xyz,
    reflection weight rgb, transmitted wo xyz, transmission weight rgb)``, weights with the
    Fresnel factor and no lobe-selection division; a rough dielectric split so at the
    microfacet normal ``(u2a, u2b)`` draws (:func:`_rough_dielectric`)."""
    k = P[0][i]
    if k == ROUGHDIELECTRIC:
        res = _rough_dielectric(P, i, wix, wiy, wiz, u2a, u2b, radiance)
        return (res[0], res[1], res[2], _fin(res[3]), _fin(res[4]), _fin(res[5]),
                res[6], res[7], res[8], _fin(res[9]), _fin(res[10]), _fin(res[11]))
    ci = -wiz if _flipped(P, i, wiz) else wiz
    s, t = P[2], P[3]
    rr = rg = rb = tr = tg = tb = 0.0
    twx, twy, twz = -wix, -wiy, -wiz
    if k == CONDUCTOR:
        if ci > 0.0:
            ce, ck = P[6], P[7]
            rr = fresnel_conductor(ci, ce[i, 0], ck[i, 0]) * s[i, 0]
            rg = fresnel_conductor(ci, ce[i, 1], ck[i, 1]) * s[i, 1]
            rb = fresnel_conductor(ci, ce[i, 2], ck[i, 2]) * s[i, 2]
    elif k == PLASTIC:
        if ci > 0.0:
            f = fresnel_dielectric(ci, P[5][i])[0]
            rr, rg, rb = f * s[i, 0], f * s[i, 1], f * s[i, 2]
    elif k == DIELECTRIC or k == THINDIELECTRIC:
        scale = 1.0
        if k == DIELECTRIC:
            r, cos_t, _eta_it, eta_ti = fresnel_dielectric(ci, P[5][i])
            twx, twy, twz = -eta_ti * wix, -eta_ti * wiy, cos_t
            if radiance:
                scale = eta_ti * eta_ti
        else:
            r = _thin_r(ci, P[5][i])
        rr, rg, rb = r * s[i, 0], r * s[i, 1], r * s[i, 2]
        tr = (1.0 - r) * t[i, 0] * scale
        tg = (1.0 - r) * t[i, 1] * scale
        tb = (1.0 - r) * t[i, 2] * scale
    return (-wix, -wiy, wiz, _fin(rr), _fin(rg), _fin(rb),
            twx, twy, twz, _fin(tr), _fin(tg), _fin(tb))


# ----------------------------------------------------------------------------------------------
# array loops (point i of P with row i of the direction arrays): the entry points Python calls,
# compiled on their own (not inlined: no compiled caller), the scalar functions inlined in them


@njit(**_KERNEL)
def eval_many(P, row, wi, wo, out_rgb, out_pdf) -> None:
    """out_rgb[i], out_pdf[i] = :func:`eval_pdf` of point i (row ``row[i]`` of P) at (wi[i], wo[i])."""
    for i in range(wi.shape[0]):
        r, g, b, p = eval_pdf(P, row[i], wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2])
        out_rgb[i, 0] = r
        out_rgb[i, 1] = g
        out_rgb[i, 2] = b
        out_pdf[i] = p


@njit(**_KERNEL)
def sample_many(P, row, wi, u1, u2, radiance, out_wo, out_w, out_pdf, out_delta) -> None:
    """Row i: :func:`sample` of point i (row ``row[i]`` of P) with (u1[i], u2[i])."""
    for i in range(wi.shape[0]):
        ox, oy, oz, wr, wg, wb, p, d = sample(P, row[i], wi[i, 0], wi[i, 1], wi[i, 2], u1[i], u2[i, 0], u2[i, 1],
                                              radiance)
        out_wo[i, 0] = ox
        out_wo[i, 1] = oy
        out_wo[i, 2] = oz
        out_w[i, 0] = wr
        out_w[i, 1] = wg
        out_w[i, 2] = wb
        out_pdf[i] = p
        out_delta[i] = d


@njit(**_KERNEL)
def sample_lobe_many(P, row, wi, u2, out_wo, out_w) -> None:
    """Row i: :func:`sample_lobe` of point i (row ``row[i]`` of P) with u2[i]."""
    for i in range(wi.shape[0]):
        ox, oy, oz, wr, wg, wb = sample_lobe(P, row[i], wi[i, 0], wi[i, 1], wi[i, 2], u2[i, 0], u2[i, 1])
        out_wo[i, 0] = ox
        out_wo[i, 1] = oy
        out_wo[i, 2] = oz
        out_w[i, 0] = wr
        out_w[i, 1] = wg
        out_w[i, 2] = wb


@njit(**_KERNEL)
def albedo_many(P, row, wi, out_rgb) -> None:
    """Row i: :func:`albedo` of point i (row ``row[i]`` of P) at wi[i]."""
    for i in range(wi.shape[0]):
        r, g, b = albedo(P, row[i], wi[i, 2])
        out_rgb[i, 0] = r
        out_rgb[i, 1] = g
        out_rgb[i, 2] = b


@njit(**_KERNEL)
def specular_many(P, row, wi, radiance, u2, r_wo, r_w, t_wo, t_w) -> None:
    """Row i: :func:`specular` of point i (row ``row[i]`` of P) at wi[i] (a rough dielectric's
    microfacet drawn with u2[i])."""
    for i in range(wi.shape[0]):
        res = specular(P, row[i], wi[i, 0], wi[i, 1], wi[i, 2], radiance, u2[i, 0], u2[i, 1])
        for c in range(3):
            r_wo[i, c] = res[c]
            r_w[i, c] = res[3 + c]
            t_wo[i, c] = res[6 + c]
            t_w[i, c] = res[9 + c]


@njit(**_KERNEL)
def coat_columns(kind, eta, rrow, reg_fdr, reg_tavg, out_fdr, out_tavg) -> int:
    """P's fdr_int and tavg columns: rough plastics read their coat row's values, smooth plastics
    get Fdr(1/eta), the rest 0 and the all-ones table's mean. Returns how many rough-plastic
    points have no table row yet (row 0), for the caller to look up."""
    missing = 0
    for i in range(kind.shape[0]):
        k = kind[i]
        row = rrow[i]
        out_tavg[i] = reg_tavg[row]
        out_fdr[i] = 0.0
        if k == ROUGHPLASTIC or k == ROUGHPLASTIC_DIFFUSE or k == ROUGHPLASTIC_LOBE:
            out_fdr[i] = reg_fdr[row]
            if row == 0:
                missing += 1
        elif k == PLASTIC:
            out_fdr[i] = fresnel_diffuse_reflectance(1.0 / eta[i])
    return missing


@njit(**_KERNEL, inline="always")
def copy_row(P, src, dst) -> None:
    """Row ``src`` of P's per-point arrays copied to row ``dst`` (the coat tables, shared, stay)."""
    P[0][dst] = P[0][src]
    for c in range(3):
        P[1][dst, c] = P[1][src, c]
        P[2][dst, c] = P[2][src, c]
        P[3][dst, c] = P[3][src, c]
        P[6][dst, c] = P[6][src, c]
        P[7][dst, c] = P[7][src, c]
    P[4][dst] = P[4][src]
    P[5][dst] = P[5][src]
    P[8][dst] = P[8][src]
    P[9][dst] = P[9][src]
    P[10][dst] = P[10][src]
    P[11][dst] = P[11][src]
    P[14][dst] = P[14][src]
    P[15][dst] = P[15][src]
    P[16][dst] = P[16][src]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def material_row(P, row, dst, atlas, u, v):
    """The row of P a point on material row ``row`` reads: the material's own, or on a
    material with bitmap textures (``atlas``: common.bsdf.texture_atlas) row ``dst`` (room past
    the materials' rows), made from the material's with its textures looked up at (u, v) as
    common.bsdf.gather looks them up."""
    pixels, tex, xform, nearest, mat_tex = atlas
    if mat_tex[row, 0] < 0 and mat_tex[row, 1] < 0 and mat_tex[row, 2] < 0:
        return row
    copy_row(P, row, dst)
    for c in range(3):
        ti = mat_tex[row, c]
        if ti < 0:
            continue
        r, g, b = texel(pixels, tex[ti, 0], tex[ti, 1], tex[ti, 2], u, v, xform[ti, 0], xform[ti, 1], xform[ti, 2],
                        xform[ti, 3], nearest[ti])
        if c == 0:
            P[1][dst, 0], P[1][dst, 1], P[1][dst, 2] = r, g, b
        elif c == 1:
            P[2][dst, 0], P[2][dst, 1], P[2][dst, 2] = r, g, b
        else:
            P[3][dst, 0], P[3][dst, 1], P[3][dst, 2] = r, g, b
    return dst


@njit(**_KERNEL)
def material_rows(P, rows, dst0, atlas, uv, out) -> None:
    """out[j] = :func:`material_row` of material row ``rows[j]`` at uv[j], a textured one made
    in row dst0 + j. ``out`` may be ``rows`` itself (row j is read before it is written)."""
    for j in range(rows.shape[0]):
        out[j] = material_row(P, rows[j], dst0 + j, atlas, uv[j, 0], uv[j, 1])
