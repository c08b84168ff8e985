"""Path regularization of glossy VPLs (Kaplanyan & Dachsbacher 2013), energy kept.

A VPL on a smooth glossy surface sends its light into a narrow lobe: the pixels it hits get a
spike of ~1/(π α²) times what a Lambertian VPL would give them (the clamp bounds only the 1/d²
term), one firefly per set that frames cannot average away quickly. Widening the lobe to
``vpl_lobe_alpha`` blurs its direction; the bound shrinks as frames accumulate, so the estimate
stays consistent.

A single-scattering microfacet lobe at α 0.5 reflects less than at α 0.01 (GGX masking and
shadowing: ~10-30% toward the normal, up to 60% of a plastic coat's light at grazing incidence).
Left alone, that loss is not a blur but missing light: a smooth floor or a stair tread passes on
less of what reaches it (modern-hall's walls 5% dark after 4 frames). :func:`regularization_gain`
gives the widened lobe the directional albedo of the original one, from per-material tables of the
lobe's albedo over the incident angle.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from threading import Lock

import numpy as np

from igi.common import bsdf
from igi.common.scene import ROUGHCONDUCTOR, ROUGHPLASTIC, reflecting

from .kernels import regularization_gain as kg

MU_BINS = 32  # incident-angle cosines tabulated per lobe
LOBE_SAMPLES = 256  # quasi-Monte Carlo points per tabulated cosine
_MU = (np.arange(MU_BINS) + 0.5) / MU_BINS
_TABLES: OrderedDict[tuple[bytes, float], np.ndarray] = OrderedDict()
_MAX_TABLES = 256
_LOCK = Lock()
_KEY_WEIGHTS = np.random.default_rng(0x10BE).uniform(1.0, 2.0, 11)  # _lobe_keys' 10 columns + α -> one float
ALBEDO_MIN_COS = 0.05  # bsdf.albedo's smallest cosine (common.kernels.bsdf.albedo)
# Bounds of the gain: above 4 a widened lobe would spike again at grazing light (a bound of 2
# measured the same noise and more bias in modern-hall); below 1 where widening a Beckmann lobe
# adds a little energy at grazing incidence.
GAIN_MIN, GAIN_MAX = 0.5, 4.0


def regularized_senders(surface: bsdf.SurfacePoints, lobe_alpha: float) -> bsdf.SurfacePoints:
    """The BSDFs ``surface`` with every microfacet lobe at least ``lobe_alpha`` rough (the same
    object when nothing is smoother). A plastic keeps its coat's Fresnel tables (``coat_row``), so
    its diffuse layer is unchanged. Smooth *receivers* need nothing: they are split at the first
    hit."""
    glossy = (surface.kind == ROUGHCONDUCTOR) | (surface.kind == ROUGHPLASTIC)
    if lobe_alpha <= 0 or not np.any(glossy & (surface.alpha < lobe_alpha)):
        return surface
    alpha = np.where(glossy, np.maximum(surface.alpha, lobe_alpha), surface.alpha).astype(surface.alpha.dtype)
    return surface.replaced(alpha=alpha)


def _lobe_albedo(point: bsdf.SurfacePoints, alpha: float) -> np.ndarray:
    """(MU_BINS, 3) albedo of the glossy lobe alone of one point (unit specular reflectance) at
    roughness ``alpha``, for incidence cosines _MU."""
    u = bsdf.albedo_points(LOBE_SAMPLES)[:, 1:]
    n = MU_BINS * LOBE_SAMPLES
    sp = replace(point.subset(np.zeros(n, np.int64)), alpha=np.full(n, alpha, point.alpha.dtype),
                 specular=np.ones((n, 3)))
    _wo, w = bsdf.sample_lobe(sp, mu_dirs(np.repeat(_MU, LOBE_SAMPLES)), np.tile(u, (MU_BINS, 1)))
    return w.reshape(MU_BINS, LOBE_SAMPLES, 3).mean(axis=1)


def _lobe_keys(sp: bsdf.SurfacePoints) -> np.ndarray:
    """(N, 10) what a lobe's albedo depends on besides its roughness and specular factor."""
    return np.column_stack([sp.kind.astype(np.float64), sp.alpha.astype(np.float32).astype(np.float64),
                            sp.eta, sp.cond_eta, sp.cond_k, sp.beckmann.astype(np.float64)])


def _table(sp: bsdf.SurfacePoints, key: np.ndarray, row: int, alpha: float) -> np.ndarray:
    """The lobe albedo table of lobe ``key`` (first seen at ``row`` of ``sp``) at roughness
    ``alpha``: one per lobe and roughness (the original's is reused while the bound shrinks)."""
    k = (key.tobytes(), float(alpha))
    with _LOCK:
        hit = _TABLES.get(k)
        if hit is not None:
            _TABLES.move_to_end(k)
            return hit
    value = _lobe_albedo(sp.subset(np.array([row])), alpha)  # outside the lock: threads may race, alike
    with _LOCK:
        _TABLES[k] = value
        while len(_TABLES) > _MAX_TABLES:
            _TABLES.popitem(last=False)
    return value


def widened_lobes(surface: bsdf.SurfacePoints, regularized: bsdf.SurfacePoints, wi: np.ndarray) -> tuple | None:
    """What :func:`regularization_gain` reads per widened point, or None where no lobe was
    widened: (rows of ``surface`` widened, their points, their cosine (as bsdf.albedo evaluates
    it), the lobe tables (G, MU_BINS, 6) at the original roughness (channels 0-2) and the widened
    one (3-5), each row's table)."""
    rows = np.nonzero(regularized.alpha != surface.alpha)[0]
    if len(rows) == 0:
        return None
    orig = surface if len(rows) == len(surface) else surface.subset(rows)
    alpha = regularized.alpha[rows]
    # the cosine bsdf.albedo evaluates at, so the lobe tables and the total albedo agree
    mu = np.clip(np.abs(np.asarray(wi, dtype=np.float64)[rows, 2]), ALBEDO_MIN_COS, 1.0)
    keys = _lobe_keys(orig)
    combos = np.column_stack([keys, alpha.astype(np.float64)])
    # one lobe per material, as a rule: group rows by a 1-D projection of their keys (a sort of
    # floats, not np.unique over rows), each group's first row stands for it
    _, first, inverse = np.unique(combos @ _KEY_WEIGHTS, return_index=True, return_inverse=True)
    tables = np.stack([np.concatenate([_table(orig, keys[r0], int(r0), float(orig.alpha[r0])),
                                       _table(orig, keys[r0], int(r0), float(alpha[r0]))], axis=1) for r0 in first])
    return rows, orig, mu, tables, inverse.reshape(-1)


def regularization_gain(surface: bsdf.SurfacePoints, regularized: bsdf.SurfacePoints,
                        wi: np.ndarray) -> np.ndarray:
    """(N, 3) factor that gives the widened BSDFs ``regularized`` (:func:`regularized_senders` of
    ``surface``) the directional albedo of the originals at ``wi`` (local; a VPL's incident
    direction, or by reciprocity the direction a receiver reflects toward): original albedo /
    (original albedo - what widening the lobe loses). 1 where the lobe was not widened; within
    [GAIN_MIN, GAIN_MAX]. The per-point arithmetic is one compiled pass
    (kernels.regularization_gain)."""
    gain = np.ones((len(surface), 3))
    widened = widened_lobes(surface, regularized, wi)
    if widened is None:
        return gain
    rows, orig, mu, tables, group = widened
    # A conductor is all lobe; a plastic's smooth albedo estimate is its diffuse layer plus its
    # coat's single-scattering reflectance at the original roughness (the coat tables, which the
    # widened lobe keeps): the original's total directional albedo.
    conductor = np.ascontiguousarray(orig.kind == ROUGHCONDUCTOR)
    albedo = np.ascontiguousarray(bsdf.albedo(orig, mu_dirs(mu)), np.float64)
    kg.gains(np.ascontiguousarray(tables, np.float64), np.ascontiguousarray(group, np.int64), mu,
             np.ascontiguousarray(orig.specular, np.float64), conductor, albedo, MU_BINS, GAIN_MIN, GAIN_MAX,
             rows, gain)
    return gain


def mu_dirs(mu: np.ndarray) -> np.ndarray:
    """(N, 3) local directions at cosines ``mu`` (in the xz plane: the lobes are isotropic)."""
    mu = np.clip(mu, 0.0, 1.0)
    return np.stack([np.sqrt(1 - mu * mu), np.zeros(len(mu)), mu], axis=1)


_SENDER_ROWS: dict = {}
_SENDER_LOCK = Lock()


def sender_rows(materials: list, lobe_alpha: float) -> tuple:
    """(P, reflects) per material row (NULL at row len(materials)): the materials' packed
    parameters as senders (lobes regularized at ``lobe_alpha``, as they are at 0; a bitmap
    texture's value at uv 0) and whether they reflect (not mirror/glass, not NULL, not black): the rows the
    final gather's level finder and the light walks read. Kept for the last few (materials,
    lobe_alpha): the bound moves with every accumulated frame."""
    key = (tuple(id(m) for m in materials), float(lobe_alpha))
    hit = _SENDER_ROWS.get(key)
    if hit is None:
        sp = regularized_senders(bsdf.gather(materials, np.arange(len(materials) + 1), None), lobe_alpha)
        P, _rows = bsdf.packed_rows(sp)
        rows = (P, reflecting(materials, sp.kind, np.arange(len(materials) + 1)))
        hit = (tuple(materials), rows)  # the materials held: their ids stay theirs
        with _SENDER_LOCK:  # render threads share the cache
            while len(_SENDER_ROWS) >= 8:
                _SENDER_ROWS.pop(next(iter(_SENDER_ROWS)))
            _SENDER_ROWS[key] = hit
    return hit[1]

