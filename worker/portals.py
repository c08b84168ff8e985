"""Light walks from the sky that start where light can enter: portals found from the view.

Instant radiosity starts a walk from an environment emitter (constant, or a map: then from its
bright directions) on a disk around the whole scene (common.lights.emit_rays). In a room lit
through windows almost every such walk misses the building or hits its outside, so the few VPLs
inside carry huge flux (grey-white-room: of 36 walks a set, 22 VPLs, 17% of them where the camera sees).

The openings are found from the view: rays from camera points that leave the scene (the
environment guide's escaped rays, worker.env_guide) pass through them. Along each escaped ray
an enclosure test (do rays in 14 fixed directions hit something?) finds where the ray leaves
the enclosed space: the aperture point. The aperture points, grouped by the side they face
(the escaped ray's dominant axis), are boxed, and boxes that overlap merge: one portal box
per opening (or per wall whose openings the view cannot tell apart).

A portal walk picks an escaped ray's direction bin (the sky directions the view sees lit), a
direction ω uniformly inside it, and a start point uniformly in the box's projection along ω,
so its line passes through the opening. Walks are drawn from the defensive mixture

    p(ω, line) = ε · p_disk(ω, line) + (1 - ε) · Σ_g P(g, bin ω) / Ω_bin · [line meets box_g] / A_g(ω)

(densities per steradian and unit area across the ray; A_g(ω) is the box's projected area)
and carry the flux L / (p · pmf): unbiased for every path, since the disk term covers every
ray that can reach the scene (Bitterli et al. 2015 sample an environment through portals for
direct light; this is the same idea for instant radiosity's light walks, with the portals found
from the geometry the view sees through). The portals depend on the view only: built once per
view from a pilot's camera points, the same on every worker.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from igi.common.environment_map import EnvironmentMap
from igi.common.geometry import Geometry
from igi.common.lights import EmittedRays, LightSampler, frame_from, uniform_sphere

from .env_guide import BINS_PHI, BINS_Z, _bin

DISK_SHARE = 0.5  # ε: walks drawn as plain instant radiosity would (defensive mixture)
MARGIN = 0.01  # a portal box grows by this fraction of the bounding-sphere diameter on each side
DISK_DISTANCE = 1.01  # walks start on a plane 1.01 bounding radii from the centre (emit_rays)
ENCLOSED = 0.55  # inside: this share of its probe rays hit something (outside a wall: ~5 of 14)
STEPS = 12  # doublings of the step along an escaped ray (from 1/1000 of the diameter)
BISECT = 5  # halvings of the aperture's bracket

# Probe directions of the enclosure test: the 6 axes and the 8 cube diagonals.
_PROBES = np.concatenate([np.eye(3), -np.eye(3),
                          np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3)])


@dataclass(frozen=True)
class Portals:
    """Boxes around the openings through which the view sees the sky, and the direction bins
    (environment guide bins) of the escaped rays per box."""

    emitter: int  # the environment emitter whose walks start here
    centre: np.ndarray  # (3,) the bounding sphere of emit_rays' disk
    radius: float
    lo: np.ndarray  # (G, 3) box corners
    hi: np.ndarray
    choice: np.ndarray  # (G, BINS) P(box g, direction bin b)
    cdf: np.ndarray  # (G * BINS,) cumulative of choice, row-major
    # the sky's environment map (common.environment_map), if it is one: the disk's directions are
    # drawn from it (where it is bright) instead of uniformly
    sky_map: EnvironmentMap | None = None

    def __len__(self) -> int:
        return len(self.lo)

    # -- the mixture --------------------------------------------------------------------------
    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ω, origin) for uniforms u (n, 5): u0 picks disk or portal (and the box and bin), u1..2
        the point across the ray, u3..4 the direction. ω points to the sky; the origin lies on the
        plane 1.01 bounding radii from the centre towards ω (outside the scene)."""
        w = uniform_sphere(u[:, 3:5]) if self.sky_map is None else self.sky_map.sample(u[:, 3:5])[0]
        rr = self.radius * np.sqrt(u[:, 1])
        phi = 2 * np.pi * u[:, 2]
        s_ax, t_ax = frame_from(w)
        off = s_ax * (rr * np.cos(phi))[:, None] + t_ax * (rr * np.sin(phi))[:, None]
        portal = np.nonzero(u[:, 0] >= DISK_SHARE)[0]
        if len(portal) and len(self):
            a = (u[portal, 0] - DISK_SHARE) / (1 - DISK_SHARE)
            c = np.minimum(np.searchsorted(self.cdf, a * self.cdf[-1], side="right"), len(self.cdf) - 1)
            g, b = c // (BINS_Z * BINS_PHI), c % (BINS_Z * BINS_PHI)
            z = -1 + 2 * (b // BINS_PHI + u[portal, 3]) / BINS_Z  # uniform inside the bin
            ph = 2 * np.pi * (b % BINS_PHI + u[portal, 4]) / BINS_PHI
            rz = np.sqrt(np.maximum(0.0, 1 - z * z))
            wp = np.stack([rz * np.cos(ph), rz * np.sin(ph), z], axis=1)
            w[portal] = wp
            y = _box_face_point(self.lo[g], self.hi[g], wp, u[portal, 1], u[portal, 2]) - self.centre
            off[portal] = y - wp * np.einsum("ij,ij->i", y, wp)[:, None]
        return w, self.centre + off + w * (DISK_DISTANCE * self.radius)

    def pdf(self, w: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """p(ω, line) per steradian and unit area across the ray, for the rays from ``origin``
        along -ω (the density depends on the line only)."""
        rel = origin - self.centre
        off = rel - w * np.einsum("ij,ij->i", rel, w)[:, None]
        on_disk = np.einsum("ij,ij->i", off, off) <= self.radius ** 2 * (1 + 1e-9)
        if self.sky_map is None:
            p = DISK_SHARE * on_disk / (4 * np.pi * np.pi * self.radius ** 2)
        else:
            p = DISK_SHARE * on_disk * self.sky_map.pdf(w) / (np.pi * self.radius ** 2)
        if len(self) == 0:
            return p
        b = _bin(w)
        bin_solid = 4 * np.pi / (BINS_Z * BINS_PHI)
        total = self.cdf[-1]
        for g in range(len(self)):
            pg = self.choice[g, b] / total
            meets = _meets_box(origin, -w, self.lo[g], self.hi[g])
            area = _projected_area(self.lo[g], self.hi[g], w)
            p += (1 - DISK_SHARE) * np.where(meets & (pg > 0), pg / (bin_solid * np.maximum(area, 1e-300)), 0.0)
        return p


def find_portals(geom: Geometry, lights: LightSampler, emitter: int, origin: np.ndarray,
                 direction: np.ndarray) -> Portals | None:
    """Portal boxes from escaped rays (origins, unit directions towards the sky); None when no
    escaped ray leaves an enclosed space (an open scene: the disk serves)."""
    if len(origin) == 0:
        return None
    diameter = 2 * float(lights.radius)
    t_in = np.zeros(len(origin))
    t_out = np.full(len(origin), np.nan)
    inside_from_start = _enclosed(geom, origin, diameter)
    step = 1e-3 * diameter
    for _ in range(STEPS):  # first step out of the enclosure, by doubling
        todo = np.nonzero(inside_from_start & np.isnan(t_out))[0]
        if len(todo) == 0:
            break
        t = np.maximum(t_in[todo] * 2, step)
        inside = _enclosed(geom, origin[todo] + direction[todo] * t[:, None], diameter)
        t_in[todo[inside]] = t[inside]
        t_out[todo[~inside]] = t[~inside]
    found = np.nonzero(np.isfinite(t_out))[0]
    if len(found) == 0:
        return None
    lo_t, hi_t = t_in[found], t_out[found]
    for _ in range(BISECT):
        mid = 0.5 * (lo_t + hi_t)
        inside = _enclosed(geom, origin[found] + direction[found] * mid[:, None], diameter)
        lo_t = np.where(inside, mid, lo_t)
        hi_t = np.where(inside, hi_t, mid)
    d = direction[found]
    aperture = origin[found] + d * (0.5 * (lo_t + hi_t))[:, None]
    axis = np.argmax(np.abs(d), axis=1)  # the side an opening faces: the ray's dominant axis and sign
    side = axis * 2 + (d[np.arange(len(d)), axis] > 0)
    groups = np.unique(side)
    m = MARGIN * diameter
    lo = [aperture[side == s].min(axis=0) - m for s in groups]
    hi = [aperture[side == s].max(axis=0) + m for s in groups]
    owner = _merge_overlapping(lo, hi)  # one box per opening: sides that share a window merge
    box = owner[np.searchsorted(groups, side)]
    ids = np.unique(box)
    lo = np.array([aperture[box == b].min(axis=0) - m for b in ids])
    hi = np.array([aperture[box == b].max(axis=0) + m for b in ids])
    nb = BINS_Z * BINS_PHI
    choice = np.zeros((len(ids), nb))
    np.add.at(choice, (np.searchsorted(ids, box), _bin(d)), 1.0)
    choice /= choice.sum()
    return Portals(emitter, np.asarray(lights.center, np.float64), float(lights.radius), lo, hi, choice,
                   np.cumsum(choice.ravel()), lights.env_map)


def portal_walks(rays: EmittedRays, u: np.ndarray, lights: LightSampler, portals: Portals) -> None:
    """Redraw, in place, the rays of ``rays`` (from ``lights.emit_rays(u)``) that leave the
    portals' environment emitter: origin and direction from the mixture, flux L / (p · pmf)."""
    rows = np.nonzero(rays.emitter == portals.emitter)[0]
    if len(rows) == 0:
        return
    cdf = lights.cdf
    lo = cdf[portals.emitter - 1] if portals.emitter > 0 else 0.0
    width = max(cdf[portals.emitter] - lo, 1e-300)
    uu = np.array(u[rows, :5], np.float64)
    # the emitter choice's fraction inside this emitter's interval: still uniform, stratified
    uu[:, 0] = np.clip((uu[:, 0] * cdf[-1] - lo) / width, 0.0, np.nextafter(1.0, 0.0))
    w, s = portals.sample(uu)
    p = portals.pdf(w, s)
    radiance = lights.environment_radiance(w)
    pmf = max(float(lights.pmf[portals.emitter]), 1e-300)
    rays.origin[rows] = s
    rays.direction[rows] = -w
    rays.normal[rows] = -w
    rays.flux[rows] = radiance / (np.maximum(p, 1e-300) * pmf)[:, None]


# -- geometry helpers ---------------------------------------------------------------------------
def _merge_overlapping(lo: list, hi: list) -> np.ndarray:
    """Label per box such that boxes that overlap (directly or through others) share a label."""
    n = len(lo)
    label = np.arange(n)
    lo, hi = [np.array(v) for v in lo], [np.array(v) for v in hi]
    changed = True
    while changed:
        changed = False
        for i in range(n):
            for j in range(i + 1, n):
                if label[i] != label[j] and np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i]):
                    label[label == label[j]] = label[i]
                    lo[i] = lo[j] = np.minimum(lo[i], lo[j])
                    hi[i] = hi[j] = np.maximum(hi[i], hi[j])
                    changed = True
    return label


def _enclosed(geom: Geometry, p: np.ndarray, reach: float) -> np.ndarray:
    """(n,) bool: at least ENCLOSED of the probe rays from p hit something within ``reach``."""
    n, k = len(p), len(_PROBES)
    o = np.repeat(p, k, axis=0)
    d = np.tile(_PROBES, (n, 1))
    hit = geom.intersect(o, d, tmax=reach).valid.reshape(n, k)
    return hit.mean(axis=1) >= ENCLOSED


def _projected_area(lo: np.ndarray, hi: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Area of the box's shadow on a plane perpendicular to the unit directions w (n, 3)."""
    e = hi - lo
    return np.abs(w[:, 0]) * e[1] * e[2] + np.abs(w[:, 1]) * e[0] * e[2] + np.abs(w[:, 2]) * e[0] * e[1]


def _box_face_point(lo: np.ndarray, hi: np.ndarray, w: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Points uniform in the box's projection along w (n, 3): on the faces that face w, each
    chosen by its projected area (every line through a convex box enters by one such face)."""
    lo, hi = np.broadcast_to(lo, w.shape), np.broadcast_to(hi, w.shape)
    e = hi - lo
    face = np.abs(w) * np.stack([e[:, 1] * e[:, 2], e[:, 0] * e[:, 2], e[:, 0] * e[:, 1]], axis=1)
    c = np.cumsum(face, axis=1)
    x = u1 * c[:, 2]
    a = np.minimum((x[:, None] >= c).sum(axis=1), 2)
    prev = np.where(a > 0, np.take_along_axis(c, np.maximum(a - 1, 0)[:, None], 1)[:, 0], 0.0)
    v = np.clip((x - prev) / np.maximum(np.take_along_axis(face, a[:, None], 1)[:, 0], 1e-300), 0.0, 1.0)
    p = np.empty(w.shape)
    rows = np.arange(len(w))
    # the face's own axis: at the side w points to; the other two from (v, u2)
    b1, b2 = (a + 1) % 3, (a + 2) % 3
    p[rows, a] = np.where(w[rows, a] > 0, hi[rows, a], lo[rows, a])
    p[rows, b1] = lo[rows, b1] + e[rows, b1] * v
    p[rows, b2] = lo[rows, b2] + e[rows, b2] * u2
    return p


def _meets_box(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: the line o + t d (any t) passes through the box (slab test)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo - o) * inv
        t1 = (hi - o) * inv
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    return near <= far
