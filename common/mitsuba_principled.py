"""Mitsuba's ``principled`` BSDF (Burley 2012, 2015) as one of igi's BSDF kinds.

igi has no Disney BSDF kernel; a principled material — what Blender's exporter writes for every
surface — becomes the kind nearest to its main lobes, so that its reflectance and its
highlights keep their size and colour instead of falling back to grey diffuse:

- the heaviest of Mitsuba's lobe weights picks the kind: metallic m, transmission (1 - m) spec_trans,
  dielectric (1 - m)(1 - spec_trans);
- transmission: a rough dielectric of GGX α = roughness² and its η (below α 1e-3 a smooth one),
  transmittance √base_color (as Mitsuba weighs its transmission lobe);
- metal: a rough conductor of GGX α = roughness², its specular colour base_color under a Fresnel
  of 1 (Mitsuba's Schlick Fresnel from base_color whitens only at grazing);
- dielectric: a rough plastic of GGX α = roughness² and η, the principled specular lobe's own (a
  dielectric Fresnel of η on GGX), over a diffuse layer whose reflectance is scaled so that its
  mean albedo is the principled diffuse lobe's (Burley's Schlick-weighted diffuse and
  retro-reflection, no coat to pass through), but never above 1 at any incidence; below α 1e-3 a
  smooth plastic;
- ``principledthin`` (a sheet, two-sided): transmission a thin dielectric passing base_color, else
  a two-sided diffuse surface of the diffuse lobe's mean albedo.

Sheen, clearcoat, anisotropy, specular tint, flatness and diffuse transmission are dropped, a
textured roughness, metallic or spec_trans taken at its mean, values outside [0, 1] clamped, a
metallic or spec_trans between 0 and 1 rounded: each with a warning naming what was
approximated."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .mitsuba_doc import Node, Props
from .scene import (DIELECTRIC, DIFFUSE, PLASTIC, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC, THINDIELECTRIC,
                    Material, Texture)

# the smallest GGX α Mitsuba's principled lobe takes (calc_dist_params clamps roughness² to it)
MIN_ALPHA = 1e-3
_DROPPED = ("sheen", "sheen_tint", "clearcoat", "clearcoat_gloss", "anisotropic", "spec_tint", "flatness", "diff_trans")
_RATES = ("diffuse_reflectance_sampling_rate", "main_specular_sampling_rate", "clearcoat_sampling_rate",
          "specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate",
          "diffuse_transmittance_sampling_rate")


def principled_eta(specular: float) -> float:
    """Mitsuba's η from ``specular`` (its F0 is 0.08 × specular)."""
    return 2.0 / (1.0 - math.sqrt(0.08 * specular)) - 1.0


def principled_diffuse_albedo(roughness: float, n: int = 48) -> float:
    """The principled diffuse lobe's albedo per unit base colour, averaged over incidence by
    cos θ_i: ∫∫ (f_diff + f_retro) cos θ_o / π dω_o 2 cos θ_i dcos θ_i, with Burley's
    f_diff = (1 - F_i/2)(1 - F_o/2), f_retro = R_r (F_o + F_i + F_o F_i (R_r - 1)),
    R_r = 2 roughness cos² θ_d, F = (1 - cos)^5 (midpoint quadrature)."""
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) * (np.pi / n)
    mi, mo, ph = np.meshgrid(mu, mu, phi, indexing="ij")
    si, so = np.sqrt(1 - mi * mi), np.sqrt(1 - mo * mo)
    wi = np.stack([si, np.zeros_like(si), mi], -1)
    wo = np.stack([so * np.cos(ph), so * np.sin(ph), mo], -1)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    cos_d = np.sum(h * wo, -1)
    fi, fo = (1 - mi) ** 5, (1 - mo) ** 5
    rr = 2.0 * roughness * cos_d ** 2
    f = (1 - 0.5 * fi) * (1 - 0.5 * fo) + rr * (fo + fi + fo * fi * (rr - 1))
    per_wi = (f * mo / np.pi).sum(axis=(1, 2)) * (1.0 / n) * (np.pi / n)
    return float(np.sum(per_wi * 2 * mu) / n)


def plastic_layer_albedo(mat: Material) -> tuple[float, float]:
    """The albedo of ``mat``'s diffuse layer per unit of its diffuse reflectance — what its coat
    lets in and out (common.bsdf): ``(mean over incidence weighted by cos θ_i, largest over
    incidence)``."""
    from . import bsdf  # (common.bsdf reads the scene module this loader's callers build from)

    unit = dataclasses.replace(mat, diffuse=Texture.constant(1.0))
    n = 16
    mu = (np.arange(n) + 0.5) / n
    sp = bsdf.gather([unit], np.zeros(n, np.int64), None)
    sp = bsdf.split_layer(sp, np.ones(n, bool))
    wi = np.stack([np.sqrt(1 - mu * mu), np.zeros(n), mu], -1)
    a = bsdf.directional_albedo(sp, wi, 1024)[:, 1]
    return float(np.sum(a * 2 * mu) / n), float(a.max())


def _scalar(p: Props, name: str, default: float, approximated: list[str], lo: float = 0.0,
            hi: float = 1.0) -> float:
    """A float parameter that Mitsuba also takes as a texture (a texture: its mean), clamped to
    [lo, hi]; what was approximated is noted."""
    if not p.has(name):
        return default
    node = p.named[name]
    if node.tag in ("float", "integer"):
        v = float(p.float(name))
    else:
        tex = p.texture(name, default)
        if not tex.is_constant:
            approximated.append(f"textured {name} as its mean")
        v = float(np.mean(tex.mean()))
    if not lo <= v <= hi:
        approximated.append(f"{name} {v:g} clamped to [{lo:g}, {hi:g}]")
        v = min(max(v, lo), hi)
    return v


def load_principled(loader, node: Node, p: Props, name: str, thin: bool = False) -> Material:
    """The Material standing for the principled BSDF at ``node`` (module docstring);
    ``principledthin`` (``thin``): a thin sheet, two-sided: transmissive, a thin dielectric passing
    base_color; else a diffuse surface of the principled diffuse lobe's mean albedo (its coat
    reflection is weighted by spec_trans: none)."""
    approximated: list[str] = []
    base = p.texture("base_color", 0.5)
    roughness = _scalar(p, "roughness", 0.5, approximated)
    metallic = 0.0 if thin else _scalar(p, "metallic", 0.0, approximated)
    spec_trans = _scalar(p, "spec_trans", 0.0, approximated)
    if p.has("eta") and p.has("specular"):
        raise loader.error(node, f"<bsdf type='{p.type}'> takes 'eta' or 'specular', not both")
    if p.has("eta"):
        eta = p.ior("eta", 1.5)
    else:
        specular = float(p.float("specular", 0.5))
        if not 0.0 <= specular < 12.5:  # F0 = 0.08 × specular must stay below 1
            raise loader.error(p.named["specular"], f"principled 'specular' {specular:g} must be in [0, 12.5)")
        eta = principled_eta(specular)
    if eta < 1.001:  # (an interface into a thinner medium: igi's plastics and glass take η > 1)
        approximated.append(f"eta {eta:g} raised to 1.001")
        eta = 1.001
    for k in _DROPPED:
        if p.has(k):
            v = _scalar(p, k, 0.0, approximated, hi=np.inf)
            if v > 0:
                approximated.append(f"{k} {v:g} dropped")
    for k in _RATES:
        p.get(k)
    alpha = max(roughness * roughness, MIN_ALPHA)
    # Mitsuba weighs its lobes metal m, transmission (1 - m) spec_trans, dielectric (1 - m)(1 - spec_trans):
    # the heaviest stands for all
    weights = {"metal": metallic, "glass": (1 - metallic) * spec_trans,
               "plastic": (1 - metallic) * (1 - spec_trans)}
    lobe = max(weights, key=weights.get)
    if lobe == "glass":
        rough = not thin and alpha > MIN_ALPHA
        kind = "thin dielectric" if thin else "rough dielectric" if rough else "smooth dielectric"
        # (Mitsuba's thin sheet passes base_color; the solid its square root, at entry and exit)
        passed = base if thin else _texture_map(base, lambda c: np.sqrt(np.maximum(c, 0.0)))
        mat = Material(name=name, kind=THINDIELECTRIC if thin else ROUGHDIELECTRIC if rough else DIELECTRIC,
                       int_ior=eta, ext_ior=1.0, specular=Texture.constant(1.0),
                       specular_transmittance=passed, alpha=alpha, distribution="ggx")
        if thin and roughness > 0.1:
            approximated.append(f"rough transmission (roughness {roughness:g}) as smooth")
    elif lobe == "metal":
        kind = "rough conductor"
        mat = Material(name=name, kind=ROUGHCONDUCTOR, specular=base, alpha=alpha, distribution="ggx",
                       eta=np.zeros(3), k=np.zeros(3))
    elif thin:
        kind = "two-sided diffuse"
        albedo = principled_diffuse_albedo(roughness)
        mat = Material(name=name, kind=DIFFUSE, diffuse=_texture_map(base, lambda c: c * albedo), twosided=True)
    else:
        smooth = alpha <= MIN_ALPHA
        kind = "smooth plastic" if smooth else "rough plastic"
        mat = Material(name=name, kind=PLASTIC if smooth else ROUGHPLASTIC, specular=Texture.constant(1.0),
                       alpha=alpha, distribution="ggx", int_ior=eta, ext_ior=1.0)
        mean, peak = plastic_layer_albedo(mat)
        scale = principled_diffuse_albedo(roughness) / mean
        # A rough coat lets little through at grazing angles: the mean matched, a white layer would
        # reflect more than it receives straight on (1.3 at roughness 1). It stops at 1 there.
        brightest = float(np.max(base.rgb)) if base.is_constant else float(np.percentile(base.image.max(-1), 99))
        cap = 1.0 / (peak * max(brightest, 1e-6))
        if scale > cap:
            approximated.append(f"diffuse {cap / scale:.2f} of the principled lobe's (rough coat)")
            scale = cap
        mat.diffuse = _texture_map(base, lambda c: c * scale)
    rounded = [f"{k} {v:g}" for k, v in (("metallic", metallic), ("spec_trans", spec_trans)) if 0.0 < v < 1.0]
    if rounded:
        approximated.append(", ".join(rounded) + " rounded")
    loader.warn(node, f"bsdf '{p.type}' is approximated", f"as a {kind}"
                + (f" ({'; '.join(approximated)})" if approximated else ""))
    p.finish()
    return mat


def _texture_map(t: Texture, f) -> Texture:
    """``t`` with ``f`` applied to its colour, or to its bitmap's texels (kept float32)."""
    if t.is_constant:
        return dataclasses.replace(t, rgb=np.asarray(f(t.rgb), np.float64))
    return dataclasses.replace(t, image=np.asarray(f(t.image), np.float32))
