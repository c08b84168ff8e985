"""Emitters: choosing one by power, sampling points on it, and emitting light rays from it.

Area emitters are triangle meshes with one-sided uniform radiance (front = the surface normal,
as Mitsuba's ``area``); point, spot (Mitsuba's linear-in-angle falloff between beam_width and
cutoff_angle), directional and constant (uniform environment) lights are handled analytically.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .environment_map import SKY_PEAK, EnvironmentMap, environment_map, no_map
from .geometry import Geometry, rows3
from .kernels import bounding_spheres, shading_frame
from .luminance import LUMINANCE_WEIGHTS, luminance  # noqa: F401 - re-exported: the callers' name for them
from .scene import AREA, CONSTANT, DIRECTIONAL, POINT, SPOT, Scene

# Kinds of point-light records (VPLs and emitter samples), see worker/vpl.py.
UNIFORM_SHARE = 0.3  # part of the emitter choice made uniformly rather than by power

VPL_SURFACE = 0  # a light-walk vertex: radiates Φ · f(y, ω_in, ·)·cos
VPL_AREA = 1  # a point on an area emitter: radiates P · max(cos θ_y, 0)
VPL_POINT = 2  # isotropic point light: intensity I
VPL_SPOT = 3  # spot light: I · falloff(angle to axis)
VPL_DIRECTIONAL = 4  # light from infinity along -direction: irradiance E (also the environment)


def frame_from(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents (s, t) for unit normals n (N, 3), Duff et al. 2017."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return s, t


def to_world(local: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N, 3) local directions of the shading frames of unit normals n (N, 3), in world space."""
    local, n = rows3(local, n)
    out = np.empty(local.shape)
    shading_frame.to_world_many(local, n, out)
    return out


def to_local(w: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N, 3) world directions w in the shading frames of unit normals n (N, 3)."""
    w, n = rows3(w, n)
    out = np.empty(w.shape)
    shading_frame.to_local_many(w, n, out)
    return out


def rays_meet_spheres(o: np.ndarray, d: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(N,) bool: the ray o + t d (unit d, t > 0) passes through some sphere (centres, radii)."""
    out = np.empty(len(o), bool)
    bounding_spheres.any_hit(np.ascontiguousarray(o, np.float64), np.ascontiguousarray(d, np.float64),
                             np.ascontiguousarray(centres, np.float64),
                             np.ascontiguousarray(np.asarray(radii) ** 2, np.float64), out)
    return out


def cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    r = np.sqrt(u[:, 0])
    phi = 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u[:, 0]))], axis=1)


def uniform_sphere(u: np.ndarray) -> np.ndarray:
    z = 1 - 2 * u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def spot_falloff(cos_theta: np.ndarray, cutoff_deg: float, beam_deg: float) -> np.ndarray:
    """Mitsuba 3's spot falloff: 1 inside the beam, linear in angle down to 0 at the cutoff."""
    cutoff = np.radians(cutoff_deg)
    beam = np.radians(min(beam_deg, cutoff_deg))
    ang = np.arccos(np.clip(cos_theta, -1, 1))
    width = max(cutoff - beam, 1e-12)
    val = np.where(ang <= beam, 1.0, (cutoff - ang) / width)
    return np.where(cos_theta > np.cos(cutoff), np.clip(val, 0, 1), 0.0)


@dataclass
class PointSamples:
    """Point-light records sampled on the emitters (direct light) — see VPL_* kinds."""

    kind: np.ndarray  # (N,) int8
    position: np.ndarray  # (N, 3)
    normal: np.ndarray  # (N, 3) area: surface normal; spot/directional: light direction
    power: np.ndarray  # (N, 3) P (area), I (point/spot), E (directional)
    emitter: np.ndarray  # (N,) int32
    pdf: np.ndarray  # (N,) area pdf (area lights), solid-angle pdf (environment), 0 for delta lights


@dataclass
class EmittedRays:
    origin: np.ndarray
    direction: np.ndarray
    flux: np.ndarray  # (N, 3) power carried by each ray (already divided by the ray count)
    emitter: np.ndarray
    normal: np.ndarray  # surface normal at the origin (area), else the direction


class LightSampler:
    """Chooses emitters in proportion to their power and samples them."""

    def __init__(self, scene: Scene, geom: Geometry):
        self.scene = scene
        self.geom = geom
        lo, hi = geom.vertices.min(axis=0), geom.vertices.max(axis=0)
        self.center = 0.5 * (lo + hi)
        self.radius = 0.5 * float(np.linalg.norm(hi - lo)) or 1.0
        n = len(scene.emitters)
        self.powers = np.zeros(n)
        self.area_tris: list[np.ndarray] = []
        self.area_cdf: list[np.ndarray] = []
        self.area_total = np.zeros(n)
        for i, e in enumerate(scene.emitters):
            tris = np.zeros(0, np.int64)
            if e.kind == AREA:
                tris = np.nonzero(geom.emitter_of == i)[0]
                a = geom.area[tris]
                self.area_total[i] = a.sum()
                self.powers[i] = np.pi * self.area_total[i] * luminance(e.radiance)
            elif e.kind == POINT:
                self.powers[i] = 4 * np.pi * luminance(e.intensity)
            elif e.kind == SPOT:
                self.powers[i] = 2 * np.pi * (1 - np.cos(np.radians(e.cutoff_angle))) * luminance(e.intensity)
            elif e.kind == DIRECTIONAL:
                self.powers[i] = np.pi * self.radius ** 2 * luminance(e.irradiance)
            elif e.kind == CONSTANT:
                self.powers[i] = 4 * np.pi * np.pi * self.radius ** 2 * luminance(e.radiance)
            self.area_tris.append(tris)
            cdf = np.cumsum(geom.area[tris]) if len(tris) else np.zeros(0)
            self.area_cdf.append(cdf / cdf[-1] if len(cdf) and cdf[-1] > 0 else cdf)
        self.powers = np.where(np.isfinite(self.powers) & (self.powers > 0), self.powers, 0.0)
        total = self.powers.sum()
        self.pmf = self.powers / total if total > 0 else np.zeros(n)
        # Mix in a uniform share over the emitters that emit at all: choosing purely by power
        # makes a small, close, bright lamp a once-in-hundreds sample with a huge weight.
        lit = self.powers > 0
        if lit.sum() > 1:
            self.pmf = (1 - UNIFORM_SHARE) * self.pmf + UNIFORM_SHARE * lit / lit.sum()
        self.cdf = np.cumsum(self.pmf)
        # the sky as a map (Mitsuba's envmap; None: a constant sky, or none) and its kernels' tables
        self.env_map = environment_map(scene)
        self.env_tables = self.env_map.env if self.env_map is not None else no_map()
        self.env_index = next((i for i, e in enumerate(scene.emitters) if e.kind == CONSTANT), -1)

    def sky_parts(self, ratio: float = SKY_PEAK) -> tuple[tuple, EnvironmentMap | None]:
        """The map's kernels' tables without its peak (radiance above ``ratio`` × its mean: a sun),
        and that peak as a map of its own (EnvironmentMap.peak_split), once per ratio; no map or
        no peak: (env_tables, None)."""
        cache = self.__dict__.setdefault("_sky_parts", {})
        if ratio not in cache:
            if self.env_map is None:
                cache[ratio] = (self.env_tables, None)
            else:
                base, peak = self.env_map.peak_split(ratio)
                cache[ratio] = (base.env, peak)
        return cache[ratio]

    def emitter_spheres(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding spheres of the area emitters (centres, radii), computed once."""
        if not hasattr(self, "_spheres"):
            cs, rs = [], []
            for i, e in enumerate(self.scene.emitters):
                tris = self.area_tris[i]
                if e.kind != AREA or len(tris) == 0 or self.powers[i] <= 0:
                    continue
                v = self.geom.vertices[self.geom.faces[tris]].reshape(-1, 3)
                c = 0.5 * (v.min(axis=0) + v.max(axis=0))
                cs.append(c)
                rs.append(float(np.linalg.norm(v - c, axis=1).max()) * (1 + 1e-6) + 4 * self.geom.eps)
            self._spheres = (np.array(cs).reshape(-1, 3), np.array(rs))
        return self._spheres

    def may_reach_emitter(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """False where the ray (unit d) provably misses every area emitter and no environment
        light exists: such BSDF-sampled direct-light rays carry nothing and are not traced."""
        if np.any(self.environment() > 0):
            return np.ones(len(o), bool)
        c, r = self.emitter_spheres()
        if len(r) == 0:
            return np.zeros(len(o), bool)
        if len(r) > 64:
            return np.ones(len(o), bool)
        return rays_meet_spheres(o, d, c, r)

    @property
    def has_light(self) -> bool:
        return bool(self.pmf.sum() > 0)

    def choose(self, u: np.ndarray, cdf: np.ndarray | None = None) -> np.ndarray:
        """Emitters for uniforms ``u`` by the cumulative ``cdf`` (None: :attr:`cdf`, by power)."""
        cdf = self.cdf if cdf is None else cdf
        idx = np.searchsorted(cdf, u * cdf[-1], side="right")
        return np.minimum(idx, len(cdf) - 1)

    def _area_points(self, em: np.ndarray, u: np.ndarray):
        tri = np.zeros(len(em), np.int64)
        ur = np.zeros((len(em), 2))
        ur[:, 1] = u[:, 1]
        for i in np.unique(em):
            sel = em == i
            cdf = self.area_cdf[i]
            j = np.minimum(np.searchsorted(cdf, u[sel, 0], side="right"), len(cdf) - 1)
            # Reuse the fraction of u0 inside the chosen triangle's CDF interval: stays stratified.
            lo = np.where(j > 0, cdf[np.maximum(j - 1, 0)], 0.0)
            w = np.maximum(cdf[j] - lo, 1e-300)
            ur[sel, 0] = np.clip((u[sel, 0] - lo) / w, 0, 1 - 1e-12)
            tri[sel] = self.area_tris[i][j]
        pos, nrm, _ = self.geom.sample_triangles(tri, ur)  # all emitters' points in one call
        return pos, nrm

    def sample_points(self, u: np.ndarray, pmf: np.ndarray | None = None) -> PointSamples:
        """One point-light record per row of u (N, 3): emitter choice + position.

        ``pmf``: the emitter choice probabilities (None: :attr:`pmf`, by power); any pmf that is
        positive wherever an emitter can light something keeps the estimate unbiased.
        Power is divided by the choice probability but NOT by N (the caller averages).
        """
        pmf = self.pmf if pmf is None else pmf
        em = self.choose(u[:, 0], None if pmf is self.pmf else np.cumsum(pmf))
        s = self.points_on(em, u[:, 1:3])
        area = s.kind == VPL_AREA
        s.pdf[area] = pmf[em[area]] / np.maximum(self.area_total[em[area]], 1e-300)
        env = (s.pdf > 0) & ~area  # the environment's directions (delta lights have pdf 0)
        if self.env_map is None:
            s.pdf[env] = pmf[em[env]] / (4 * np.pi)
        else:
            s.pdf[env] = pmf[em[env]] * s.pdf[env]  # × the map's pdf of each direction
        s.power /= np.maximum(pmf[em], 1e-300)[:, None]
        return s

    def points_on(self, em: np.ndarray, u: np.ndarray) -> PointSamples:
        """A point-light record on each emitter ``em`` from (N, 2) uniforms: power and pdf
        (area or solid angle) as if that emitter had been chosen with probability 1."""
        n = len(u)
        kind = np.zeros(n, np.int8)
        pos = np.zeros((n, 3))
        nrm = np.zeros((n, 3))
        power = np.zeros((n, 3))
        pdf = np.zeros(n)
        for i in np.unique(em):
            e = self.scene.emitters[i]
            sel = np.nonzero(em == i)[0]
            if e.kind == AREA:
                p, nn = self._area_points(np.full(len(sel), i), u[sel, 0:2])
                pos[sel], nrm[sel] = p, nn
                kind[sel] = VPL_AREA
                power[sel] = e.radiance * self.area_total[i]
                pdf[sel] = 1.0 / max(self.area_total[i], 1e-300)
            elif e.kind in (POINT, SPOT):
                pos[sel] = e.position
                nrm[sel] = e.direction / np.linalg.norm(e.direction)
                kind[sel] = VPL_POINT if e.kind == POINT else VPL_SPOT
                power[sel] = e.intensity
            elif e.kind == DIRECTIONAL:
                nrm[sel] = e.direction / np.linalg.norm(e.direction)
                kind[sel] = VPL_DIRECTIONAL
                power[sel] = e.irradiance
            elif e.kind == CONSTANT and self.env_map is not None:
                # Light from a direction drawn from the map (where it is bright): E = L(ω) / p(ω).
                d, p = self.env_map.sample(u[sel, 0:2])
                nrm[sel] = -d
                kind[sel] = VPL_DIRECTIONAL
                power[sel] = self.env_map.radiance(d) / np.where(p > 0, p, np.inf)[:, None]
                pdf[sel] = p
            elif e.kind == CONSTANT:
                # Light arriving from a uniformly chosen direction: E = L·4π per sample.
                d = uniform_sphere(u[sel, 0:2])
                nrm[sel] = -d  # light travels along -d... i.e. comes from direction d
                kind[sel] = VPL_DIRECTIONAL
                power[sel] = e.radiance * 4 * np.pi
                pdf[sel] = 1.0 / (4 * np.pi)
        return PointSamples(kind, pos, nrm, power, np.asarray(em, np.int32), pdf)

    def area_pdf(self, emitter: np.ndarray, pmf: np.ndarray | None = None) -> np.ndarray:
        """Area pdf with which sample_points (choosing by ``pmf``, None: by power) picks a point
        on area emitter ``emitter``."""
        pmf = self.pmf if pmf is None else pmf
        out = np.zeros(len(emitter))
        ok = emitter >= 0
        e = emitter[ok]
        out[ok] = pmf[e] / np.maximum(self.area_total[e], 1e-300)
        return out

    def environment_pdf(self, pmf: np.ndarray | None = None) -> float:
        """Solid-angle pdf of one environment direction drawn by sample_points."""
        pmf = self.pmf if pmf is None else pmf
        tot = 0.0
        for i, e in enumerate(self.scene.emitters):
            if e.kind == CONSTANT:
                tot += pmf[i] / (4 * np.pi)
        return tot

    def environment_pdfs(self, d: np.ndarray, pmf: np.ndarray | None = None) -> np.ndarray | float:
        """Solid-angle pdf with which sample_points draws the sky along unit directions ``d``
        (N, 3): per direction for a map, :meth:`environment_pdf` (one number) for a constant sky."""
        if self.env_map is None:
            return self.environment_pdf(pmf)
        pmf = self.pmf if pmf is None else pmf
        return float(pmf[self.env_index]) * self.env_map.pdf(d)

    def environment_radiance(self, d: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) of rays leaving the scene along unit directions ``d`` (N, 3)."""
        if self.env_map is None:
            return np.broadcast_to(self.environment(), (len(d), 3))
        return self.env_map.radiance(d)

    def emit_rays(self, u: np.ndarray) -> EmittedRays:
        """Light rays for walks and photons from u (N, 5); flux is per ray, not divided by N."""
        n = len(u)
        em = self.choose(u[:, 0])
        o = np.zeros((n, 3))
        d = np.zeros((n, 3))
        nrm = np.zeros((n, 3))
        flux = np.zeros((n, 3))
        pmf = np.maximum(self.pmf[em], 1e-300)
        for i in np.unique(em):
            e = self.scene.emitters[i]
            sel = np.nonzero(em == i)[0]
            if e.kind == AREA:
                p, nn = self._area_points(np.full(len(sel), i), u[sel, 1:3])
                local = cosine_hemisphere(u[sel, 3:5])
                o[sel], nrm[sel] = p, nn
                d[sel] = to_world(local, nn)
                flux[sel] = e.radiance * np.pi * self.area_total[i]
            elif e.kind == POINT:
                o[sel] = e.position
                d[sel] = uniform_sphere(u[sel, 3:5])
                nrm[sel] = d[sel]
                flux[sel] = e.intensity * 4 * np.pi
            elif e.kind == SPOT:
                axis = e.direction / np.linalg.norm(e.direction)
                cos_max = np.cos(np.radians(e.cutoff_angle))
                cz = 1 - u[sel, 3] * (1 - cos_max)
                r = np.sqrt(np.maximum(0, 1 - cz * cz))
                phi = 2 * np.pi * u[sel, 4]
                local = np.stack([r * np.cos(phi), r * np.sin(phi), cz], axis=1)
                ax = np.broadcast_to(axis, (len(sel), 3)).copy()
                d[sel] = to_world(local, ax)
                o[sel] = e.position
                nrm[sel] = d[sel]
                fall = spot_falloff(cz, e.cutoff_angle, e.beam_width)
                flux[sel] = e.intensity * (2 * np.pi * (1 - cos_max)) * fall[:, None]
            elif e.kind in (DIRECTIONAL, CONSTANT):
                if e.kind == DIRECTIONAL:
                    dirs = np.broadcast_to(e.direction / np.linalg.norm(e.direction), (len(sel), 3)).copy()
                    scale = e.irradiance
                elif self.env_map is not None:  # from the map's bright directions: L(ω) / p(ω)
                    sky, p = self.env_map.sample(u[sel, 3:5])
                    dirs = -sky
                    scale = self.env_map.radiance(sky) / np.where(p > 0, p, np.inf)[:, None]
                else:
                    dirs = -uniform_sphere(u[sel, 3:5])
                    scale = e.radiance * 4 * np.pi
                o[sel] = self.disk_origins(dirs, u[sel, 1:3])
                d[sel] = dirs
                nrm[sel] = dirs
                flux[sel] = scale * np.pi * self.radius ** 2
        flux /= pmf[:, None]
        return EmittedRays(o, d, flux, em.astype(np.int32), nrm)

    def disk_origins(self, d: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Origins (N, 3) of parallel rays along unit ``d`` (N, 3) from a distant light: uniform
        (by ``u`` (N, 2)) on the disk of the bounding sphere's radius across d, just upstream of
        the sphere, facing the scene; their area pdf is 1 / (π radius²)."""
        rr = self.radius * np.sqrt(u[:, 0])
        phi = 2 * np.pi * u[:, 1]
        s, t = frame_from(d)
        return (self.center - d * self.radius * 1.01
                + s * (rr * np.cos(phi))[:, None] + t * (rr * np.sin(phi))[:, None])

    def emitted_radiance(self, emitter: np.ndarray, cos_front: np.ndarray) -> np.ndarray:
        """Radiance seen on area emitters (front side only)."""
        table = self.area_radiance
        ids = np.asarray(emitter)
        out = table.take(np.where((ids >= 0) & (ids < len(table) - 1), ids, len(table) - 1), axis=0)
        out[np.asarray(cos_front) <= 0] = 0
        return out

    @cached_property
    def area_radiance(self) -> np.ndarray:
        """(emitters + 1, 3): each area emitter's radiance, 0 for the others and the last row
        (no emitter): what :meth:`emitted_radiance` looks up (compiled callers read it)."""
        table = np.zeros((len(self.scene.emitters) + 1, 3))
        for i, e in enumerate(self.scene.emitters):
            if e.kind == AREA:
                table[i] = e.radiance
        return table

    def environment(self) -> np.ndarray:
        """Radiance of rays that leave the scene (sum of constant emitters)."""
        env = np.zeros(3)
        for e in self.scene.emitters:
            if e.kind == CONSTANT:
                env = env + e.radiance
        return env
