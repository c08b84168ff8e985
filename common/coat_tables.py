"""Process-wide registry of rough-plastic coat tables, stacked for the compiled BSDFs.

Each distinct (alpha, eta, distribution) of a rough plastic gets a row once, for the life of
the process: its coat transmittance t(μ) and reflectance tables over μ = linspace(0, 1, R)
(common.microfacet.rough_plastic_tables), the coat's internal diffuse reflectance and the
cosine-weighted mean of t. Row 0 is a harmless placeholder (t = 1, reflectance 0) for points
that are not rough plastics. Rows are never removed or renumbered, so a row computed once
(common.bsdf.gather keeps it per point) stays valid in every later snapshot.
"""
from __future__ import annotations

import threading

import numpy as np

from igi.common import microfacet as mf

_LOCK = threading.Lock()
_ROWS: dict[tuple, int] = {}
_R = mf.ROUGH_TRANSMITTANCE_RES


def cosine_mean(tabs: np.ndarray) -> np.ndarray:
    """Cosine-weighted hemisphere mean 2∫t(μ)μdμ of tables sampled at linspace(0, 1, R)."""
    mu = np.linspace(0.0, 1.0, tabs.shape[1])
    return 2.0 * np.mean(tabs * mu, axis=1)


def _placeholder() -> tuple:
    t = np.ones((1, _R))
    return t, np.zeros((1, _R)), np.zeros(1), cosine_mean(t)


# (transmittance (G, R), reflectance (G, R), fdr_int (G,), t_avg (G,)), replaced as a whole
_STATE: tuple = _placeholder()


def _key(alpha: float, eta: float, beckmann: bool) -> tuple:
    # the float32 key of mf.rough_plastic_tables: float32 point values and float64 material
    # values of the same coat share a row
    return float(np.float32(max(float(alpha), 1e-4))), float(np.float32(eta)), bool(beckmann)


def row(alpha: float, eta: float, beckmann: bool) -> int:
    """The registry row of one coat, computing its tables on first use."""
    key = _key(alpha, eta, beckmann)
    hit = _ROWS.get(key)
    if hit is not None:
        return hit
    t, r_int, refl = mf.rough_plastic_tables(*key)  # outside the lock: seconds on first use
    global _STATE
    with _LOCK:
        hit = _ROWS.get(key)
        if hit is not None:
            return hit
        tabs, rrefl, fdr, tavg = _STATE
        t = np.asarray(t, np.float64)[None]
        _STATE = (np.concatenate([tabs, t]), np.concatenate([rrefl, np.asarray(refl, np.float64)[None]]),
                  np.append(fdr, float(r_int)), np.append(tavg, cosine_mean(t)))
        _ROWS[key] = len(tabs)
        return len(tabs)


def rows(alpha: np.ndarray, eta: np.ndarray, beckmann: np.ndarray) -> np.ndarray:
    """Rows of n points (int64), one dictionary lookup per distinct coat."""
    a = np.asarray(alpha, np.float64).ravel()
    e = np.asarray(eta, np.float64).ravel()
    b = np.asarray(beckmann, bool).ravel()
    if len(a) == 0:
        return np.zeros(0, np.int64)
    if np.all(a == a[0]) and np.all(e == e[0]) and np.all(b == b[0]):
        return np.full(len(a), row(a[0], e[0], b[0]), np.int64)
    # distinct triples via 1-D uniques (a row-wise unique over structured rows is ~10x slower)
    ua, ia = np.unique(a, return_inverse=True)
    ue, ie = np.unique(e, return_inverse=True)
    code = (ia.ravel().astype(np.int64) * len(ue) + ie.ravel()) * 2 + b
    ucode, inv = np.unique(code, return_inverse=True)
    per = np.array([row(ua[c // 2 // len(ue)], ue[c // 2 % len(ue)], c % 2) for c in ucode.tolist()], np.int64)
    return per[inv.ravel()]


def tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The current stack: ``(transmittance (G, R), reflectance (G, R), fdr_int (G,), t_avg (G,))``
    float64, C-contiguous; any row handed out so far indexes it."""
    return _STATE
