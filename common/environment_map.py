"""Environment maps: Mitsuba 3's ``envmap`` emitter, a lat-long HDR image at infinity.

The sky a map describes is sampled where it is bright (importance sampling by its radiance
times solid angle, e.g. the sun) and read by direction wherever a ray leaves the scene. The
tables and their rules are in ``common.kernels.environment_map``; this module builds them from
an emitter (``Emitter.image``, ``Emitter.to_world``) and offers the numpy-facing calls.

A constant environment (``constant``) stays what it was — uniform directions, one radiance —
so its images do not change; :func:`environment_map` returns None for it.
"""
from __future__ import annotations

import numpy as np

from .kernels import environment_map as kern
from .luminance import luminance
from .scene import CONSTANT, Emitter, Scene, SceneError

_EMPTY = None  # the "no map" tuple, made once
# A map's radiance above this × its mean is its peak (a sun), which caustic photons carry through
# mirror/glass (worker.caustics); a chain from a surface that found it would be a firefly of that
# radiance over the chain's pdf. A sky's gradient and clouds (a few × the mean) stay with the chains.
SKY_PEAK = 16.0


class EnvironmentMap:
    """One map's tables (``ENV``, the kernels' tuple) and numpy calls on world directions."""

    def __init__(self, image: np.ndarray, to_world: np.ndarray | None = None):
        img = np.asarray(image, np.float64)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 3 or img.shape[1] < 2:
            raise SceneError(f"an environment map must be an RGB image of at least 2 x 3 pixels, got {img.shape}")
        if not np.isfinite(img).all():
            raise SceneError("the environment map holds non-finite values (NaN or inf)")
        img = np.maximum(img, 0.0)  # negative radiance (EXR round-off) emits nothing
        H, W = img.shape[:2]
        tex = np.concatenate([img, img[:, :1]], axis=1).astype(np.float32)  # periodic column
        R = np.eye(3) if to_world is None else np.array(np.asarray(to_world, np.float64)[:3, :3])  # own, writeable
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
            raise SceneError("an environment map's to_world must be a rotation")
        to_local = np.ascontiguousarray(R.T)
        sin_rows = np.sin(np.pi * np.arange(H) / (H - 1))
        sin_rows[[0, -1]] = 0.0
        # the density grid, as Mitsuba's warp: luminance x sin θ of the row, bilinear between texels
        lum = luminance(tex)
        grid = lum * sin_rows[:, None]
        if not grid.sum() > 0:  # a black map: sample by solid angle (nothing to find, pdfs stay valid)
            grid = np.broadcast_to(sin_rows[:, None], grid.shape).copy()
        patch = 0.25 * (grid[:-1, :-1] + grid[:-1, 1:] + grid[1:, :-1] + grid[1:, 1:])  # (H - 1, W) integrals
        total = patch.sum()
        row_w = patch.sum(axis=1)
        row_cdf = np.concatenate([[0.0], np.cumsum(row_w)]) / total
        row_cdf[-1] = 1.0
        col_cdf = np.zeros((H - 1, W + 1))
        col_cdf[:, 1:] = np.cumsum(patch, axis=1) / np.maximum(row_w, 1e-300)[:, None]
        col_cdf[:, -1] = 1.0
        # p_uv = bilinear(grid) / (total · du · dv); p_ω = p_uv / (2π² sin θ)
        density = grid / (total / (W * (H - 1))) / (2 * np.pi * np.pi)
        self.env = (tex, np.ascontiguousarray(to_local), np.ascontiguousarray(R), row_cdf, col_cdf,
                    np.ascontiguousarray(density), sin_rows)
        self.shape = (H, W)
        self.rotation = R
        # the solid-angle mean radiance of the map (what a constant sky of the same power emits)
        weights = solid_rows(H)
        self.mean = (img.mean(axis=1) * weights[:, None]).sum(axis=0) / weights.sum()

    def peak_split(self, ratio: float) -> tuple[EnvironmentMap, EnvironmentMap | None]:
        """The map as base + peak (texel by texel, so every lookup, bilinear included, sums to
        this map's): the base keeps each texel's radiance up to ``ratio`` × the map's mean
        luminance (its colour kept), the peak the rest — a sun, carried by caustic photons where
        mirror/glass chains would find it as fireflies (worker.caustics). Peak None: no texel
        above the bound (the base is then this map)."""
        image = np.asarray(self.image, np.float64)
        lum = luminance(image)
        bound = ratio * float(luminance(self.mean))
        over = lum > bound
        # The pole rows stay in the base: the sampling density vanishes on them (sin θ = 0) while
        # their bilinear radiance does not, so a peak there would be drawn with unbounded weights.
        over[[0, -1]] = False
        if not over.any() or not bound > 0:
            return self, None
        keep = np.where(over, bound / np.where(over, lum, 1.0), 1.0)
        base = image * keep[..., None]
        return EnvironmentMap(base, self.rotation), EnvironmentMap(image - base, self.rotation)

    @property
    def image(self) -> np.ndarray:
        """The map's texels (H, W, 3) float32, as its lookups read them (a view of its table)."""
        return self.env[0][:, :-1]

    def radiance(self, d: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) arriving from unit world directions ``d`` (N, 3)."""
        d = np.ascontiguousarray(d, np.float64).reshape(-1, 3)
        out = np.empty((len(d), 3))
        kern.radiance_many(self.env, d, out)
        return out

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (N,) of :meth:`sample` at unit world directions ``d``."""
        d = np.ascontiguousarray(d, np.float64).reshape(-1, 3)
        out = np.empty(len(d))
        kern.pdf_many(self.env, d, out)
        return out

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions (N, 3) towards the sky and their solid-angle pdfs (N,) for uniforms (N, 2)."""
        u = np.ascontiguousarray(u, np.float64).reshape(-1, 2)
        d, p = np.empty((len(u), 3)), np.empty(len(u))
        kern.sample_many(self.env, u, d, p)
        return d, p


def solid_rows(H: int) -> np.ndarray:
    """The solid angle weights (H,) of a lat-long image's pixel rows (rows at centre polar angles
    π (r + ½) / H, as an image's mean over the sphere weighs them)."""
    return np.sin((np.arange(H) + 0.5) / H * np.pi)


def no_map() -> tuple:
    """The kernels' tuple for "no map" (empty tables of the same types)."""
    global _EMPTY
    if _EMPTY is None:
        z2 = np.zeros((0, 0))
        _EMPTY = (np.zeros((0, 1, 3), np.float32), np.eye(3), np.eye(3), np.zeros(1), z2, z2, np.zeros(1))
    return _EMPTY


def emitter_map(e: Emitter) -> EnvironmentMap | None:
    """The map of an environment emitter with an image (built once per image and rotation), else None."""
    img = getattr(e, "image", None)
    if e.kind != CONSTANT or img is None:
        return None
    cached = e.__dict__.get("_environment_map")
    if cached is None or cached[0] is not img or cached[1] is not e.to_world:
        cached = (img, e.to_world, EnvironmentMap(img, e.to_world))
        e.__dict__["_environment_map"] = cached
    return cached[2]


def environment_map(scene: Scene) -> EnvironmentMap | None:
    """The scene's environment map, if its environment is one (at most one may be: Mitsuba's rule)."""
    maps = [m for m in (emitter_map(e) for e in scene.emitters) if m is not None]
    return maps[0] if maps else None
