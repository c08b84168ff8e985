"""Caustics of indirect light, L D S+ D E: what surfaces reflect onto a point through a mirror or
glass chain (the lensed image of a lit room in a glass ball, a lit floor seen in a mirror by a
wall).

VPLs cannot carry it (a shadow ray through glass is blocked) and caustic photons start only at
emitters. The end point's continuation ray (worker.shading.trace_bsdf_rays, already traced for
BSDF-direct lighting) that hits a mirror or glass surface is followed along its chain, one
sampled delta component per bounce, to the first non-specular surface y; the light y reflects
back (the VPL set and the emitter samples at y, with y's own BSDF ray: worker.final_gather,
which shades them with the compensation's near points) is the sample. Emission at the chain's
end is left to the caustic photons (L S+ D E); the environment seen through the chain is added
here (shadow rays of the environment samples are blocked by the glass) — less an environment
map's peak (a sun) where caustic photons carry it (worker.caustics, ``sky_map``).
No other estimator covers these paths, so no MIS weight is needed. The chain's end y follows
chains of its own the same way (worker.final_gather.lensed_levels: light that crossed glass
twice between diffuse bounces, as under a water surface).
"""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.kernels import environment_map as env_kernels
from igi.common.lights import LightSampler
from igi.common.scene import SPECULAR_KINDS, Scene, kind_in

from .arrivals import Arrivals
from .kernels import specular_chain as sc
from .shading import BSDFRays, EndPoints, delta_bounce


def lensed_arrivals(scene: Scene, geom: Geometry, lights: LightSampler, end: EndPoints, rays: BSDFRays,
                    max_depth: int, specular_depth: int, rng: np.random.Generator,
                    sky_map: tuple | None = None) -> tuple[np.ndarray, Arrivals | None]:
    """The end points' mirror/glass chains followed: ((E, 3) the radiance of the environment
    seen through them, toward the end points; the chains' ends y, each to be gathered for its
    end point with the chain's throughput: worker.final_gather, with the caustic photons there,
    so a caustic seen through the chain is included — L S+ D S+ D E: the bright focus under a
    glass ball imaged by the ball onto the ceiling). None: no chain ends on a surface. ``sky_map``:
    the map's kernels' tables the chains see (None: LightSampler.env_tables; the map less its peak
    where caustic photons carry the peak: worker.caustics)."""
    e = len(end)
    out = np.zeros((e, 3))
    hits = rays.hits
    if e == 0 or len(rays.rows) == 0 or specular_depth <= 0:
        return out, None
    kinds = bsdf.material_kinds(scene.materials)  # (NULL at the last row: no material)
    mat = np.where(hits.material >= 0, hits.material, len(scene.materials))
    first = np.flatnonzero(hits.valid & ~rays.delta & kind_in(kinds, SPECULAR_KINDS)[mat])
    if max_depth >= 0:  # x -> mirror/glass -> something: at least the environment at segment + 2
        first = first[end.segments[rays.rows[first]] + 2 <= max_depth]
    if len(first) == 0:
        return out, None
    rows = rays.rows[first]
    thr = rays.weight[first]
    d = rays.direction[first]
    pos, ns, ng = hits.position[first], hits.ns[first], hits.ng[first]
    mat_i, uv = hits.material[first], hits.uv[first]
    seg = end.segments[rows].astype(np.int64) + 1  # segments once the ray reached the surface
    env = lights.environment()
    chain = (rows, thr, d, pos, ns, ng, mat_i, uv, seg)
    sky_map = lights.env_tables if sky_map is None else sky_map
    ends = _compiled_chains(scene, geom, *chain, specular_depth, max_depth, rng, env, sky_map, out)
    if ends is None:
        ends = _numpy_chains(scene, geom, kinds, *chain, specular_depth, max_depth, rng, lights, sky_map, out)
    if not ends:
        return out, None
    # each row's chain ends once (here or as a miss above): its rows are unique
    rows, thr, seg, d, p, n_s, n_g, m, uv, t = ends[0] if len(ends) == 1 else (np.concatenate(c) for c in zip(*ends))
    return out, Arrivals(p, n_s, n_g, m, uv, t, d, seg, rows, thr, np.zeros(len(rows), np.int64))


def _compiled_chains(scene, geom, rows, thr, d, pos, ns, ng, mat_i, _uv, seg, specular_depth, max_depth, rng,
                     env, sky_map, out) -> list[tuple] | None:
    """The chains of :func:`lensed_arrivals` followed in one compiled call
    (kernels.specular_chain.follow_chains: the same draws, rays and ends as its numpy loop),
    their ends as that loop lists them (one entry, or none); None where the loop must run instead: rays that must
    pass through Geometry.intersect (a benchmark timing or recording them), or a mirror/glass
    material with a texture (its points' parameters are looked up per point)."""
    terms = geom.closest_terms()
    tables = bsdf.chain_materials(scene.materials) if terms is not None else None
    if tables is None:
        return None
    P, _kind, specular = tables[:3]
    n = len(rows)
    m = len(scene.materials)
    prow = np.where((mat_i >= 0) & (mat_i < m), mat_i, m).astype(np.int64)
    ends = (np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)),
            np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int32), np.empty((n, 2)), np.empty(n))
    c = np.ascontiguousarray
    _center, eps, ulps = geom.offset_terms()
    done, traced = sc.follow_chains(P, specular, rng, terms, c(rows, np.int64), c(pos, np.float64), c(ns, np.float64),
                                    c(ng, np.float64), c(d, np.float64), c(thr, np.float64), c(seg, np.int64), prow,
                                    int(specular_depth), int(max_depth), eps, ulps, c(env, np.float64), sky_map,
                                    out, ends)
    geom.counters["intersect_rays"] += traced
    return [tuple(a[:done] for a in ends)] if done else []


def _numpy_chains(scene, geom, kinds, rows, thr, d, pos, ns, ng, mat_i, uv, seg, specular_depth, max_depth, rng,
                  lights, sky_map, out) -> list[tuple]:
    """The chains of :func:`lensed_arrivals` followed bounce by bounce in numpy (where
    :func:`_compiled_chains` cannot): the sky along misses added to ``out``, the chain ends
    listed per bounce (rows, throughput, segments, direction, position, ns, ng, material, uv, t)."""
    ends: list[tuple] = []
    for _ in range(specular_depth):
        src, thr, seg, d, origin = delta_bounce(scene.materials, geom, np.arange(len(rows)), pos, ns, ng, d, thr, seg,
                                                mat_i, uv, max_depth, rng)
        rows = rows[src]
        if len(rows) == 0:
            break
        h = geom.intersect(origin, d)
        miss = np.nonzero(~h.valid)[0]
        if len(miss) and np.any(lights.environment() > 0):
            np.add.at(out, rows[miss], thr[miss] * _sky_radiance(lights, sky_map, d[miss]))
        hit = np.nonzero(h.valid)[0]
        spec = kind_in(kinds[h.material[hit]], SPECULAR_KINDS)
        y = hit[~spec]
        if len(y):  # the chain's end: gathered once for all bounces below
            ends.append((rows[y], thr[y], seg[y], d[y], h.position[y], h.ns[y], h.ng[y], h.material[y],
                         h.uv[y], h.t[y]))
        c = hit[spec]  # still on the chain
        rows, thr, seg, d = rows[c], thr[c], seg[c], d[c]
        pos, ns, ng, mat_i, uv = h.position[c], h.ns[c], h.ng[c], h.material[c], h.uv[c]
        if len(rows) == 0:
            break
    return ends


def _sky_radiance(lights: LightSampler, sky_map: tuple, d: np.ndarray) -> np.ndarray:
    """The radiance a chain sees leaving along ``d``: the constant sky, or the map of ``sky_map``."""
    if sky_map is lights.env_tables or lights.env_map is None:
        return lights.environment_radiance(d)
    out = np.empty((len(d), 3))
    env_kernels.radiance_many(sky_map, np.ascontiguousarray(d, np.float64), out)
    return out
