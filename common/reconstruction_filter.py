"""Mitsuba's image reconstruction filters (``<rfilter>`` inside a film) as where a pixel's eye
rays go: filter importance sampling (Ernst, Stamminger, Greiner 2006).

Mitsuba samples film positions uniformly and splats each onto the pixels within the filter's
radius, weighted by f(dx) f(dy) and normalized by the weights' sum; a pixel's expected value is
the filter-weighted mean of the radiance around it. igi draws each pixel's sub-pixel offsets
from the normalized filter itself (one inverse-CDF table per axis: the filters are separable),
so a pixel's mean over accumulated frames is that same weighted mean, with each frame's one
ray per pixel and no splatting: tiles, interleaving and the discontinuity buffer stay per pixel.
Like Mitsuba's film (``sample_border`` false), no sample leaves the film: a pixel within the
radius of an edge draws from its filter cut at the edge, renormalized.

Negative lobes (``mitchell``, ``catmullrom``, ``lanczos``) would need signed sample weights
through every buffer: those filters are sampled by their positive part (the loader warns).
``box`` of radius 0.5 draws the jitter unchanged (bit for bit as without a filter).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .scene import SceneError

# name -> the parameters' meaning and defaults (Mitsuba 3.9)
KINDS = {
    "box": ("radius", 0.5),  # (radius in pixels; Mitsuba's box is always 0.5, a wider one is igi's)
    "tent": ("radius", 1.0),
    "gaussian": ("stddev", 0.5),  # radius 4 stddev
    "mitchell": ("B, C", (1 / 3, 1 / 3)),  # radius 2
    "catmullrom": ("", None),  # Mitchell-Netravali with B = 0, C = 1/2
    "lanczos": ("lobes", 3),  # radius = lobes
}
DEFAULT = ("gaussian", (0.5, 0.0))  # Mitsuba's hdrfilm without an rfilter
TABLE_SIZE = 1024  # inverse-CDF entries per axis (offsets interpolated between them)


def validate(kind: str, params: tuple[float, float]) -> None:
    """SceneError unless ``kind`` is a known filter with parameters it can be drawn from."""
    if kind not in KINDS:
        raise SceneError(f"unknown reconstruction filter {kind!r} (known: {', '.join(KINDS)})")
    a, b = (float(x) for x in params)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise SceneError(f"reconstruction filter {kind!r}: parameters {params} are not finite")
    if kind in ("box", "tent", "gaussian") and not 1e-3 <= a <= 16:
        raise SceneError(f"reconstruction filter {kind!r}: {KINDS[kind][0]} {a} must be in [0.001, 16] pixels")
    if kind == "lanczos" and not (a == int(a) and 1 <= a <= 16):
        raise SceneError(f"reconstruction filter 'lanczos': lobes {a} must be a whole number in 1..16")
    if kind == "mitchell" and not (abs(a) <= 100 and abs(b) <= 100):
        raise SceneError(f"reconstruction filter 'mitchell': B {a} and C {b} must lie in [-100, 100]")
    if not _positive_part(kind, (a, b))[1][-1] > 0:
        raise SceneError(f"reconstruction filter {kind!r} {params}: no positive weight to draw pixels' rays from")


def has_negative_lobes(kind: str, params: tuple[float, float]) -> bool:
    """Whether the filter weighs some offsets negatively (those igi does not draw)."""
    r = radius(kind, params)
    return bool(evaluate(kind, params, np.linspace(0, r, 1025)).min() < -1e-12)


def radius(kind: str, params: tuple[float, float]) -> float:
    """The filter's support radius in pixels."""
    a = float(params[0])
    if kind in ("box", "tent"):
        return a
    if kind == "gaussian":
        return 4.0 * a
    if kind in ("mitchell", "catmullrom"):
        return 2.0
    return a  # lanczos: its lobes


def evaluate(kind: str, params: tuple[float, float], x: np.ndarray) -> np.ndarray:
    """Mitsuba's f(x) of the filter at offsets ``x`` (pixels) from the pixel's centre."""
    x = np.abs(np.asarray(x, np.float64))
    a, b = float(params[0]), float(params[1])
    r = radius(kind, params)
    if kind == "box":
        return np.where(x <= r, 1.0, 0.0)
    if kind == "tent":
        return np.maximum(0.0, 1.0 - x / r)
    if kind == "gaussian":
        alpha = -1.0 / (2.0 * a * a)
        return np.maximum(0.0, np.exp(alpha * x * x) - math.exp(alpha * r * r))
    if kind in ("mitchell", "catmullrom"):
        B, C = (a, b) if kind == "mitchell" else (0.0, 0.5)
        x2, x3 = x * x, x * x * x
        inner = (12 - 9 * B - 6 * C) * x3 + (-18 + 12 * B + 6 * C) * x2 + (6 - 2 * B)
        outer = (-B - 6 * C) * x3 + (6 * B + 30 * C) * x2 + (-12 * B - 48 * C) * x + (8 * B + 24 * C)
        return np.where(x < 1, inner, np.where(x < 2, outer, 0.0)) / 6.0
    # lanczos: sinc(x) sinc(x / lobes) inside the lobes
    return np.where(x < r, np.sinc(x) * np.sinc(x / r), 0.0)


@lru_cache(maxsize=16)
def tables(kind: str, params: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(x, cdf): the CDF of the filter's positive part at TABLE_SIZE + 1 offsets x over
    [-radius, radius] (trapezoids of a fine grid, piecewise linear between the table's points)."""
    validate(kind, params)
    fine, cdf = _positive_part(kind, params)
    x = np.linspace(fine[0], fine[-1], TABLE_SIZE + 1)
    return x, np.interp(x, fine, cdf / cdf[-1])


def _positive_part(kind: str, params: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(x, running integral of max(f, 0)) on a fine grid over the support (not normalized)."""
    r = radius(kind, params)
    fine = np.linspace(-r, r, 64 * TABLE_SIZE + 1)
    with np.errstate(over="ignore", invalid="ignore"):
        f = np.maximum(evaluate(kind, params, fine), 0.0)
    f = np.where(np.isfinite(f), f, 0.0)
    return fine, np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(fine))])


def is_identity(kind: str, params: tuple[float, float]) -> bool:
    """Whether the filter is the pixel's own box: the jitter is drawn as it is."""
    return kind == "box" and float(params[0]) == 0.5


def filtered_jitter(kind: str, params: tuple[float, float], jitter: np.ndarray, px: np.ndarray, py: np.ndarray,
                    width: int, height: int) -> np.ndarray:
    """Sub-pixel positions (N, 2) — offsets from the pixel's corner, as ``jitter`` — drawn from
    the filter by ``jitter`` in [0, 1)² ((2,) for all pixels, or (N, 2) per pixel (px, py)):
    each axis's number through the inverse CDF of the filter cut where it would leave the
    ``width`` x ``height`` film."""
    jit = np.broadcast_to(np.asarray(jitter, np.float64).reshape(-1, 2), (len(px), 2))
    if is_identity(kind, params):
        return np.ascontiguousarray(jit)
    x, cdf = tables(kind, params)
    out = np.empty((len(px), 2))
    for axis, (p, size) in enumerate(((px, width), (py, height))):
        centre = np.asarray(p, np.float64) + 0.5
        # the film spans offsets [-centre, size - centre] from this pixel's centre
        lo = np.interp(-centre, x, cdf, left=0.0, right=1.0)
        hi = np.interp(size - centre, x, cdf, left=0.0, right=1.0)
        u = lo + jit[:, axis] * (hi - lo)
        out[:, axis] = 0.5 + np.interp(u, cdf, x)
    return out
