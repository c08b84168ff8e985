"""Caustic photons C_k (Wald et al. 2002 §4.1) in a hashed grid.

Photons leave each emitter only toward the scene's mirror and glass objects: a target is
chosen uniformly among the bounding spheres, the direction uniformly inside the cone that
sphere subtends, and the photon is weighted by the mixture pdf over all cones that contain
its direction (overlapping targets are counted once; Jarosz 2002 §3). So the estimate of
every caustic path that starts inside some cone is unbiased. Photons follow mirror/glass
bounces and are stored at the first non-specular hit after at least one specular bounce.

Distant lights shoot too (a sun focused by glass, seen in a mirror, through a window pane):
a directional light, and the peak of an environment map — its texels brighter than SKY_PEAK ×
the map's mean (common.environment_map), direction drawn from that peak. Their photons are
parallel rays through a point drawn on the disk a target's sphere casts across the light's
direction, weighted by the mixture of all targets' disks; they start outside the scene, so
whatever shades a target shades them. The mirror/glass chains that find the sky from a surface
(worker.indirect_caustics) then see the map without that peak: each path is counted once.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.lights import LightSampler, luminance, spot_falloff, uniform_sphere
from igi.common.params import PHOTON_BOOST_MAX, boosted_photon_bound
from igi.common.scene import AREA, CONSTANT, DIRECTIONAL, NULL, POINT, SPECULAR_KINDS, SPOT, Scene, kind_in
from igi.common.sobol_stream import SobolStream, stream_seed
from igi.common.sobol_stream import rng as make_rng
from igi.common.specular import specular_targets

from .hash_grid import HashGrid
from .kernels import light_paths, photon_aim, photon_estimate
from .light_paths import continue_paths, incident_ratios, roulette_numbers, set_key

PHOTON_STREAM = "caustic photons"
EMIT_DIMS = 5  # 2 position (distant: the map's direction), 1 target, 2 direction in the cone (distant: on the disk)
BOUNCE_DIMS = 3
QUASI_BOUNCES = 2  # bounces with Sobol numbers; past them each number costs what it is used for


@dataclass
class PhotonSet:
    position: np.ndarray  # (N, 3)
    power: np.ndarray  # (N, 3) flux
    direction: np.ndarray  # (N, 3) towards where the photon came from
    normal: np.ndarray  # (N, 3) surface normal where stored
    depth: np.ndarray  # (N,) light-path segments from the emitter to the stored hit
    radius: float
    grid: HashGrid | None
    shot: int = 0

    def __len__(self) -> int:
        return len(self.position)

    @cached_property
    def reach(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the photons' bounding box grown by the radius — only end points inside it
        can find a photon (worked out once per set: a set serves every tile of its k)."""
        return self.position.min(axis=0) - self.radius, self.position.max(axis=0) + self.radius


def default_radius(diagonal: float, fraction: float) -> float:
    return (fraction if fraction > 0 else 0.005) * diagonal


def _empty(radius: float) -> PhotonSet:
    z = np.zeros((0, 3))
    return PhotonSet(z, z, z, z, np.zeros(0, np.int32), radius, None)


MIN_PHOTON_SHARE = 0.01  # a light's photons at least this share of photons_per_light (>= 1)
PILOT_PHOTONS = 2000  # caustic_share: photons a light at least (a share within ~2% on one set)


def shooting_lights(scene: Scene, lights: LightSampler) -> list[int]:
    """The emitters caustic photons leave: area, point, spot and directional lights with power,
    and an environment map with a peak (common.environment_map.SKY_PEAK; a constant sky has none)."""
    return [ei for ei, e in enumerate(scene.emitters)
            if (e.kind in (AREA, POINT, SPOT, DIRECTIONAL) and lights.powers[ei] > 0)
            or (e.kind == CONSTANT and e.image is not None and sky_peak(lights) is not None)]


def sky_peak(lights: LightSampler):
    """The environment map's peak that photons carry (common.environment_map.EnvironmentMap), or None."""
    return lights.sky_parts()[1]


def shooting_powers(scene: Scene, lights: LightSampler, shooting: Sequence[int]) -> np.ndarray:
    """The shooting lights' powers (luminance) as photons share them: LightSampler.powers, and
    for a map the power of its peak only, as a directional light's, through the scene's disk."""
    p = np.array(lights.powers[list(shooting)], np.float64)
    for i, ei in enumerate(shooting):
        if scene.emitters[ei].kind == CONSTANT:
            p[i] = np.pi * lights.radius ** 2 * 4 * np.pi * float(luminance(sky_peak(lights).mean))
    return p


def caustic_share(scene: Scene, geom: Geometry, lights: LightSampler, photons_per_light: int, max_bounces: int,
                  targets: tuple | None = None) -> float:
    """The share of the shooting lights' flux (luminance) that a pilot photon set (seed 0,
    block 0, at least PILOT_PHOTONS photons a light) stores as caustics: deterministic, so
    every worker finds the same share (as every worker builds the same VPL sets: given the
    same ray answers). 0 without specular surfaces or shooting lights."""
    shooting = shooting_lights(scene, lights)
    total = float(shooting_powers(scene, lights, shooting).sum()) if shooting else 0.0
    if photons_per_light <= 0 or total <= 0:
        return 0.0
    pilot = build_photon_set(scene, geom, lights, 0, 0, max(photons_per_light, PILOT_PHOTONS),
                             default_radius(geom.diagonal, -1.0), max_bounces, targets=targets)
    return float(luminance(pilot.power.sum(axis=0))) / total if len(pilot) else 0.0


VIEW_SHARE_RADIUS = 0.02  # the view share's gather radius (of the diagonal): 4x the default, a smooth sum
VIEW_SHARE_POINTS = 1024  # camera points the view share sums over


def distant_lights(scene: Scene, lights: LightSampler) -> list[int]:
    """The shooting lights that are distant: directional lights and a map's peak."""
    return [ei for ei in shooting_lights(scene, lights) if scene.emitters[ei].kind in (DIRECTIONAL, CONSTANT)]


def distant_view_share(scene: Scene, geom: Geometry, lights: LightSampler, points, photons_per_light: int,
                       max_bounces: int, targets: tuple | None = None) -> float:
    """The share of the distant lights' light on the view's surfaces that arrives as caustics:
    over camera end points ``points`` (worker.shading.EndPoints, the view's camera pool), the
    irradiance of a pilot photon set of the distant lights only (seed 0, block 0) over it plus
    their direct irradiance (a shadow ray each; a map's peak: one direction drawn per point).
    A sun's flux through the scene's disk mostly lands outside what the camera sees (a room's
    roof and outer walls), so :func:`caustic_share`'s flux ratio is no measure of a room lit by
    a sun through its window panes — where that light is all caustic, and its photons are the
    image. 0 without distant shooting lights or points (deterministic: every worker agrees)."""
    distant = distant_lights(scene, lights)
    if not distant or len(points) == 0 or photons_per_light <= 0:
        return 0.0
    radius = VIEW_SHARE_RADIUS * geom.diagonal
    pilot = build_photon_sets(scene, geom, lights, 0, [0], max(photons_per_light, PILOT_PHOTONS), radius,
                              max_bounces, targets=targets, only=distant)[0]
    side = np.where(points.wi[:, 2] >= 0, 1.0, -1.0)[:, None]
    n = points.ns * side  # the normal on the side the eye sees
    caustic = 0.0
    if pilot.grid is not None:
        pi, qi = pilot.grid.query(points.position)
        facing = np.einsum("ij,ij->i", pilot.direction[pi], n[qi]) > 0
        caustic = float(luminance(pilot.power[pi[facing]]).sum()) / (np.pi * radius * radius)
    direct = 0.0
    u = make_rng(0, 0, "view share").random((len(points), 2))
    for ei in distant:
        e = scene.emitters[ei]
        if e.kind == DIRECTIONAL:
            to_sun = np.broadcast_to(-e.direction / np.linalg.norm(e.direction), n.shape)
            irradiance = np.full(len(points), float(luminance(e.irradiance)))
        else:
            to_sun, p = sky_peak(lights).sample(u)
            irradiance = luminance(sky_peak(lights).radiance(to_sun)) / np.where(p > 0, p, np.inf)
        cos = np.einsum("ij,ij->i", n, to_sun)
        lit = np.flatnonzero(cos > 0)
        if len(lit) == 0:
            continue
        o = geom.offset(points.position[lit], points.ng[lit] * side[lit], to_sun[lit])
        seen = ~geom.occluded(o, np.ascontiguousarray(to_sun[lit]), np.full(len(lit), np.inf))
        direct += float((irradiance[lit] * cos[lit] * seen).sum())
    total = caustic + direct
    return caustic / total if total > 0 else 0.0


def boosted_photons(photons_per_light: int, share: float, reference: float) -> int:
    """Photons per light per set for a scene whose caustics take ``share`` of the lights' flux:
    photons_per_light × (share / reference)², rounded to a step of √2, between 1× and
    PHOTON_BOOST_MAX× (and at most the parameter's bound). A caustic's relative noise goes as
    its share² over the photon count, so a scene with twice the reference share needs four
    times the photons to be as smooth as one at the reference; a scene at or below it keeps
    the count (``reference`` 0: always). The steps keep a pilot's last digits from changing the
    count (and with it every photon of a set: its Sobol rows)."""
    if reference <= 0 or share <= reference:
        return photons_per_light
    boost = min(2.0 ** (round(2.0 * np.log2((share / reference) ** 2)) / 2.0), PHOTON_BOOST_MAX)
    return min(int(round(photons_per_light * boost)), boosted_photon_bound(photons_per_light))


def photon_counts(powers: np.ndarray, photons_per_light: int) -> np.ndarray:
    """Photons per set of each shooting light: photons_per_light × the lights' effective number
    (ΣΦ)²/ΣΦ², shared in proportion to power, at least MIN_PHOTON_SHARE of photons_per_light
    (and 1) each. Equal lights get photons_per_light each, as the paper's count per light; a
    hall of 4 panels and 9 dim lamps shoots ~1800, not 6500 of which 4500 carried 0.1% of the
    power (each light's photons count 1/its own number: unbiased for any split)."""
    p = np.asarray(powers, np.float64)
    eff = p.sum() ** 2 / max(float((p * p).sum()), 1e-300)
    share = photons_per_light * eff * p / p.sum()
    floor = max(1.0, np.ceil(MIN_PHOTON_SHARE * photons_per_light))
    return np.maximum(np.rint(share), floor).astype(np.int64)


def build_photon_set(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, k: int,
                     photons_per_light: int, radius: float, max_bounces: int,
                     aim: bool = True, targets: tuple | None = None) -> PhotonSet:
    """The caustic photon set C_k for frame seed ``seed``.

    ``aim=False`` emits photons over the light's whole emission distribution instead of the
    target cones (same expectation, many photons wasted): the check that aiming is unbiased.
    ``targets``: the mirror/glass bounding spheres (common.specular.specular_targets), if known.
    """
    return build_photon_sets(scene, geom, lights, seed, [k], photons_per_light, radius, max_bounces, aim,
                             targets)[0]


def build_photon_sets(scene: Scene, geom: Geometry, lights: LightSampler, seed: int, ks: Sequence[int],
                      photons_per_light: int, radius: float | Sequence[float], max_bounces: int,
                      aim: bool = True, targets: tuple | None = None,
                      only: Sequence[int] | None = None) -> list[PhotonSet]:
    """:func:`build_photon_set` of every block k of ``ks``, each as it is alone (every photon
    depends on its own stream row only), emitted and traced together: one Embree batch per
    bounce for all the sets. ``radius``: one for all sets, or one per set (the query radius
    shrinks along an accumulation: sets of several frames in one batch). ``only``: the shooting
    lights (emitter indices) to shoot from, None: all of them."""
    radii_of = np.broadcast_to(np.asarray(radius, np.float64), (len(ks),))
    centres, radii = targets if targets is not None else specular_targets(scene, geom)
    if photons_per_light <= 0 or len(radii) == 0 or not lights.has_light:
        return [_empty(float(r)) for r in radii_of]
    stream = SobolStream(stream_seed(seed, PHOTON_STREAM))
    # Quasi-random numbers for the first QUASI_BOUNCES bounces (into and out of a glass ball);
    # a chain's further bounces draw counter-based ones of its set's key as they happen.
    dims = EMIT_DIMS + BOUNCE_DIMS * min(max_bounces, QUASI_BOUNCES)
    # Each light's photons from its own rows of the stream; everything after is per photon,
    # so all lights are emitted in one pass (same values as light by light). Set k's rows are
    # chunk k of the frame's stream: a frame's sets together are one Sobol prefix.
    shooting = shooting_lights(scene, lights)
    if only is not None:
        keep = set(only)
        shooting = [ei for ei in shooting if ei in keep]
    if not shooting:
        return [_empty(float(r)) for r in radii_of]
    counts = photon_counts(shooting_powers(scene, lights, shooting), photons_per_light)
    per_set = int(counts.sum())
    u = np.concatenate([stream.padded(k, per_set, per_set, dims) for k in ks])
    base = stream_seed(seed, PHOTON_STREAM, "bounces")
    keys = np.repeat(np.array([set_key(base, k) for k in ks], np.uint64), per_set)
    nsets = len(ks)
    light = np.tile(np.repeat(np.arange(len(shooting)), counts), nsets)  # row -> shooting light
    em = np.asarray(shooting, np.int64)[light]
    shot = len(em)
    kind = np.array([e.kind for e in scene.emitters])[em]
    area = np.nonzero(kind == AREA)[0]
    pos = np.zeros((shot, 3))
    nrm = np.zeros((shot, 3))
    if len(area):
        pos[area], nrm[area] = lights._area_points(em[area], u[area, 0:2])
    rows_of = [np.nonzero(light == i)[0] for i in range(len(shooting))]
    for i, ei in enumerate(shooting):
        e = scene.emitters[ei]
        if e.kind in (POINT, SPOT):
            pos[rows_of[i]] = e.position
            nrm[rows_of[i]] = e.direction / np.linalg.norm(e.direction)
    if aim:  # direction, pdf, area emitters' flux and offset origins in one pass (local lights' rows)
        c = np.ascontiguousarray
        d, pdf, flux, o = np.zeros((shot, 3)), np.zeros(shot), np.zeros((shot, 3)), np.zeros((shot, 3))
        is_area = np.zeros(shot, bool)
        is_area[area] = True
        local = np.flatnonzero(np.isin(kind, (AREA, POINT, SPOT)))  # (a distant light's rows: below)
        whole = len(local) == shot
        rows = slice(None) if whole else local  # (all local: views, written in place)
        out = (d, pdf, flux, o) if whole else tuple(np.empty_like(a[local]) for a in (d, pdf, flux, o))
        if len(local):
            photon_aim.aimed_emission(pos[rows], nrm[rows], c(u[rows], np.float64), c(centres, np.float64),
                                      c(radii, np.float64), em[rows], is_area[rows], lights.area_radiance,
                                      c(lights.area_total, np.float64), *geom.offset_terms(), *out)
            if not whole:
                d[local], pdf[local], flux[local], o[local] = out
    else:
        d = uniform_sphere(u[:, 3:5])
        pdf = np.full(shot, 1 / (4 * np.pi))
        flux = np.zeros((shot, 3))
        o = pos.copy()
    if len(area) and not aim:
        cos_e = np.einsum("ij,ij->i", d[area], nrm[area])
        radiance = np.array([scene.emitters[i].radiance if scene.emitters[i].kind == AREA else np.zeros(3)
                             for i in range(len(scene.emitters))], np.float64)
        total = np.asarray(lights.area_total, np.float64)[em[area]]
        flux[area] = radiance[em[area]] * (np.maximum(cos_e, 0) * total / pdf[area])[:, None]
        o[area] = geom.offset(pos[area], nrm[area], d[area])
    for i, ei in enumerate(shooting):
        e = scene.emitters[ei]
        sel = rows_of[i]
        if e.kind == POINT:
            flux[sel] = e.intensity[None, :] / pdf[sel][:, None]
        elif e.kind == SPOT:
            fall = spot_falloff(np.einsum("ij,ij->i", d[sel], nrm[sel]), e.cutoff_angle, e.beam_width)
            flux[sel] = e.intensity[None, :] * (fall / pdf[sel])[:, None]
        elif e.kind in (DIRECTIONAL, CONSTANT):
            d[sel], o[sel], flux[sel] = _distant_emission(e, lights, u[sel], centres, radii, aim)
    flux /= counts[light][:, None]
    # All sets' and lights' photons in one trace (one Embree batch per bounce), then put back
    # per set in light order: the same photons, in the same order, as tracing light by light.
    traced = _trace_photons(scene, geom, o, d, flux, u, max_bounces, keys, per_set)
    out = []
    src = traced[5] if traced is not None else np.zeros(0, np.int64)
    order = np.lexsort((light[src], src // per_set))
    stops = np.cumsum(np.bincount(src // per_set, minlength=nsets))
    # put in set order once; each set's photons are then a slice (a view) of each array
    ordered = [a.take(order, axis=0) for a in traced[:5]] if traced is not None else []
    for i, r in enumerate(radii_of):
        r = float(r)
        s0, s1 = (int(stops[i - 1]) if i else 0), int(stops[i])
        if s1 == s0:
            empty = _empty(r)
            empty.shot = per_set
            out.append(empty)
            continue
        pos_s, pw, di, nr, dp = (a[s0:s1] for a in ordered)
        out.append(PhotonSet(pos_s, pw, di, nr, dp, r, HashGrid(pos_s, r), per_set))
    return out


def _distant_emission(e, lights: LightSampler, u: np.ndarray, centres: np.ndarray, radii: np.ndarray,
                      aim: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(direction, origin, flux) of a distant light's photons for their numbers ``u`` (n, EMIT_DIMS):
    travelling along the directional light, or from the map's peak (drawn from it by u[:, 0:2],
    radiance over pdf); aimed at the targets' shadow disks (kernels.photon_aim.distant_emission)
    or, unaimed, uniform on the scene's disk as light walks start (LightSampler.emit_rays); flux
    is irradiance over the point's area pdf (not yet divided by the light's photon count)."""
    n = len(u)
    if e.kind == DIRECTIONAL:
        d = np.broadcast_to(e.direction / np.linalg.norm(e.direction), (n, 3)).copy()
        irradiance = np.broadcast_to(np.asarray(e.irradiance, np.float64), (n, 3))
    else:
        peak = sky_peak(lights)
        sky, p = peak.sample(u[:, 0:2])
        d = -sky
        irradiance = peak.radiance(sky) / np.where(p > 0, p, np.inf)[:, None]
    if aim:
        o, area_pdf = np.empty((n, 3)), np.empty(n)
        photon_aim.distant_emission(d, np.ascontiguousarray(u, np.float64), np.ascontiguousarray(centres, np.float64),
                                    np.ascontiguousarray(radii, np.float64), np.asarray(lights.center, np.float64),
                                    float(lights.radius), o, area_pdf)
    else:
        o = lights.disk_origins(d, u[:, 3:5])
        area_pdf = np.full(n, 1.0 / (np.pi * lights.radius ** 2))
    return d, o, irradiance / np.where(area_pdf > 0, area_pdf, np.inf)[:, None]


def _trace_photons(scene, geom, o, d, flux, u, max_bounces, keys, per_set):
    """The photons from emission (o, d, flux) to where they are stored: (position, flux,
    direction, ns, depth, row), or None when none is. Bounce b reads u[row, EMIT_DIMS +
    BOUNCE_DIMS·b …] while u has them, then the counter-based numbers of (keys[row], row %
    per_set)."""
    compiled = _compiled_photons(scene, geom, o, d, flux, u, max_bounces, keys, per_set)
    if compiled is not None:
        return compiled
    quasi = (u.shape[1] - EMIT_DIMS) // BOUNCE_DIMS
    if quasi < max_bounces:  # the numbers the compiled tracer draws as it goes, as arrays
        u = np.concatenate([u, roulette_numbers(keys, per_set, quasi, max_bounces, BOUNCE_DIMS)[0]], axis=1)
    alive = np.nonzero(np.any(flux > 0, axis=1))[0]
    bounced = np.zeros(len(o), bool)
    out_p, out_w, out_d, out_n, out_dp, out_src = [], [], [], [], [], []
    o = np.array(o, np.float64, order="C")  # continue_paths updates o, d, flux in place
    d = np.array(d, np.float64, order="C")
    flux = np.array(flux, np.float64, order="C")
    for b in range(max_bounces + 1):
        if len(alive) == 0:
            break
        hits = geom.intersect(o[alive], d[alive])
        v = hits.valid
        alive = alive[v]
        if len(alive) == 0:
            break
        sp = bsdf.gather(scene.materials, hits.material[v], hits.uv[v])
        ns, ng, pos = hits.ns[v], hits.ng[v], hits.position[v]
        bumped = geom.bumped(hits.material[v])
        spec = kind_in(sp.kind, SPECULAR_KINDS)
        store = ~spec & bounced[alive] & (sp.kind != NULL)
        if store.any():
            s = np.nonzero(store)[0]
            out_p.append(pos[s])
            out_w.append(flux[alive[s]] * incident_ratios(-d[alive[s]], ns[s], ng[s], bumped[s])[:, None])
            out_d.append(-d[alive[s]])
            out_n.append(ns[s])
            out_dp.append(np.full(len(s), b + 1, np.int32))
            out_src.append(alive[s])
        # Only mirror/glass bounces continue: anything else is a caustic's end or not a caustic.
        si = np.nonzero(spec)[0]
        if b == max_bounces or len(si) == 0:
            break
        bounced[alive[si]] = True
        alive = continue_paths(sp, geom, si, alive, pos, ns, ng, d, o, flux, u, EMIT_DIMS + BOUNCE_DIMS * b,
                               bumped=bumped)
    if not out_p:
        return None
    return (np.concatenate(out_p), np.concatenate(out_w), np.concatenate(out_d),
            np.concatenate(out_n), np.concatenate(out_dp), np.concatenate(out_src))


def gather_photons(end, photons: PhotonSet, albedo: np.ndarray, max_depth: int) -> np.ndarray:
    """Caustic radiance at the end points per unit albedo (joins the filtered irradiance)."""
    e = len(end)
    out = np.zeros((e, 3))
    if e == 0 or photons.grid is None or len(photons) == 0:
        return out
    # Caustics are usually small: only end points inside the photons' bounding box (grown by
    # r) can find any, so the others skip the grid lookups.
    lo, hi = photons.reach
    p = end.position  # column by column: numpy's axis=1 all() costs several times more
    inside = (p[:, 0] >= lo[0]) & (p[:, 0] <= hi[0]) & (p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1]) & (
        p[:, 2] >= lo[2]) & (p[:, 2] <= hi[2])
    if end.direct_only is not None:
        inside &= ~end.direct_only  # a split lobe's light samples: emitters only
    near = np.nonzero(inside)[0]
    if len(near) == 0:
        return out
    pi_idx, qn = photons.grid.query(end.position[near])
    qi = near[qn]
    if len(pi_idx) == 0:
        return out
    # Photons arriving on the side the eye sees only (thin walls must not leak caustics
    # through), f alone (eval's |cos θ| divided out: flux is already per area).
    P, prow = bsdf.packed_rows(end.sp)
    a = np.ascontiguousarray
    photon_estimate.estimate(pi_idx, qi, a(photons.direction, np.float64), a(photons.depth, np.int64),
                             a(photons.power, np.float64), a(end.ns, np.float64), a(end.wi, np.float64),
                             a(end.segments, np.int64), int(max_depth), P, prow, a(albedo, np.float64),
                             float(np.pi * photons.radius ** 2), out)
    return out


def _compiled_photons(scene, geom, o, d, flux, u, max_bounces, keys, per_set):
    """:func:`_trace_photons` in one compiled call (kernels.light_paths.trace_photons: the same
    rays, bounces and stored photons as its loop; none stored: empty arrays), or None where the
    loop must run: rays that must pass through Geometry.intersect (a benchmark timing or
    recording them), or a mirror/glass material with a texture (common.bsdf.chain_materials)."""
    terms = geom.closest_terms()
    tables = bsdf.chain_materials(scene.materials) if terms is not None else None
    if tables is None:
        return None
    P, kind, specular = tables[:3]
    n = len(o)
    out = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int32),
           np.empty(n, np.int64))
    _center, eps, ulps = geom.offset_terms()
    # (copies: the kernel moves the photons along in place)
    stored, traced = light_paths.trace_photons(P, kind, specular, NULL, terms, np.array(o, np.float64, order="C"),
                                               np.array(d, np.float64, order="C"),
                                               np.array(flux, np.float64, order="C"),
                                               np.ascontiguousarray(u, np.float64), int(max_bounces), EMIT_DIMS,
                                               BOUNCE_DIMS, np.ascontiguousarray(keys, np.uint64),
                                               max(int(per_set), 1), eps, ulps, out)
    geom.counters["intersect_rays"] += traced
    return tuple(a[:stored] for a in out)
