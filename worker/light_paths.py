"""One bounce of the paths that leave the lights — the light walks behind the VPLs
(worker.vpl) and the caustic photons (worker.caustics) — through the compiled
worker.kernels.light_paths."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.kernels import shading_normals
from igi.common.kernels.splitmix import mix64

from .kernels import light_paths
from .regularization import sender_rows

_NO_SURVIVAL = np.zeros((0, 0))
_NO_KEYS = np.zeros(0, np.uint64)


def continue_paths(sp: bsdf.SurfacePoints, geom: Geometry, sel: np.ndarray, rows: np.ndarray, pos: np.ndarray,
                   ns: np.ndarray, ng: np.ndarray, d: np.ndarray, o: np.ndarray, flux: np.ndarray, u: np.ndarray,
                   col: int, survival: np.ndarray | None = None, bounce: int = 0,
                   bumped: np.ndarray | None = None) -> np.ndarray:
    """Hits ``sel`` (of the per-hit arrays ``sp``, ``pos``, ``ns``, ``ng``) of paths ``rows``
    continue: their BSDF sampled (importance mode) with u[path, col : col + 3], Russian roulette
    on ``survival[path, bounce]`` where given, the path's flux, direction ``d`` and origin ``o``
    (float64 (paths, 3), C order: updated in place) set for the next ray. Returns the paths of
    ``sel`` whose flux still carries light, in order. ``bumped`` (per hit; None: none): the hits
    whose normal a normal or bump map perturbed, where the flux takes the shading-normal
    correction (common.kernels.shading_normals)."""
    for a in (d, o, flux):
        if a.dtype != np.float64 or not a.flags.c_contiguous:
            raise ValueError("continue_paths updates d, o and flux in place: float64, C order")
    P, prow = bsdf.packed_rows(sp)
    out = np.empty(len(sel), np.int64)
    c = np.ascontiguousarray
    n = light_paths.continue_paths(P, prow, c(sel, np.int64), c(rows, np.int64), c(pos, np.float64),
                                   c(ns, np.float64), c(ng, np.float64),
                                   np.zeros(len(pos), np.bool_) if bumped is None else c(bumped, np.bool_),
                                   d, o, flux, c(u, np.float64), int(col),
                                   survival is not None, _NO_SURVIVAL if survival is None else c(survival, np.float64),
                                   int(bounce), *geom.offset_terms(), out)
    return out[:n]


def incident_ratios(w: np.ndarray, ns: np.ndarray, ng: np.ndarray, bumped: np.ndarray) -> np.ndarray:
    """|w·ns| / |w·ng| per row where ``bumped`` (1 elsewhere): what a light walk's or photon's
    flux arriving from w is scaled by where it is stored (common.kernels.shading_normals)."""
    c = np.ascontiguousarray
    out = np.empty(len(w))
    shading_normals.incident_ratios(c(w, np.float64), c(ns, np.float64), c(ng, np.float64), out)
    return np.where(bumped, out, 1.0)


def trace_walks(materials: list, geom: Geometry, o: np.ndarray, d: np.ndarray, flux: np.ndarray, u: np.ndarray,
                max_length: int, roulette_after: int | None, keys: np.ndarray | None, walks: int, dims_start: int,
                dims_per_bounce: int) -> tuple | None:
    """The vertices the light walks leave (worker.vpl._light_walks), in one compiled call
    (kernels.light_paths.trace_walks): (position, ns, ng, flux, depth, wi, material, uv, walk
    row), bounce by bounce; past u's bounces and for the roulette, the numbers of walk
    (keys[row], row % walks) (kernels.light_paths.walk_uniform). None where the walks must pass
    through Geometry.intersect (a benchmark timing or recording rays)."""
    terms = geom.closest_terms()
    if terms is None:
        return None
    P, reflects = sender_rows(materials, 0.0)  # the materials as they are: no lobe widened
    atlas = bsdf.texture_atlas(materials)
    n = len(o)
    if len(atlas[1]):  # a row of P per hit of a bounce for the texels of its own (the coat tables stay shared)
        P = tuple(f if i in (12, 13) else np.concatenate([f, np.empty((n,) + f.shape[1:], f.dtype)])
                  for i, f in enumerate(P))
    c = np.ascontiguousarray
    # room for 8 vertices a walk on average (walks of roulette end after ~3): past that, all of them
    for cap in dict.fromkeys((n * min(max(max_length, 1), 8), n * max(max_length, 1))):
        out = (np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty(cap, np.int32),
               np.empty((cap, 3)), np.empty(cap, np.int32), np.empty((cap, 2)), np.empty(cap, np.int64))
        oo, dd, ff = np.array(o, np.float64, order="C"), np.array(d, np.float64, order="C"), np.array(flux, np.float64,
                                                                                                      order="C")
        stored, traced = light_paths.trace_walks(P, reflects, atlas, terms, oo, dd, ff, c(u, np.float64),
                                                 int(max_length), -1 if roulette_after is None else int(roulette_after),
                                                 _NO_KEYS if keys is None else c(keys, np.uint64), max(int(walks), 1),
                                                 int(dims_start), int(dims_per_bounce), *geom.offset_terms()[1:], out)
        geom.counters["intersect_rays"] += traced
        if stored >= 0:
            return tuple(a[:stored] for a in out)
    raise AssertionError("trace_walks: room for every bounce of every walk was too small")  # pragma: no cover


def roulette_numbers(keys: np.ndarray, walks: int, first: int, length: int, dims_per_bounce: int) -> tuple:
    """(u, survival): the numbers :func:`trace_walks` draws past the walks' quasi-random ones,
    as arrays for the numpy loop — u's columns for bounces ``first`` … ``length`` - 1 and every
    bounce's survival uniform (kernels.light_paths.roulette_uniforms)."""
    n = len(keys)
    u = np.empty((n, dims_per_bounce * max(length - first, 0)))
    survival = np.empty((n, length))
    light_paths.roulette_uniforms(np.ascontiguousarray(keys, np.uint64), max(int(walks), 1), int(first),
                                  int(dims_per_bounce), u, survival)
    return u, survival


def set_key(base: int, k: int) -> int:
    """Set k's 64-bit key under a frame's ``base`` (splitmix64 of their sum): the key of the
    counter-based numbers its paths draw past their quasi-random ones
    (kernels.light_paths.walk_uniform) — one generator per batch, not one per set."""
    return int(mix64(np.uint64((base + 0x9E3779B97F4A7C15 * (k + 1)) & 0xFFFFFFFFFFFFFFFF)))

