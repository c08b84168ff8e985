"""The discontinuity buffer of the paper's §4.3.

Irradiance is piecewise smooth, so each pixel averages the irradiance of the neighbours in
a window around it whose depth and normal agree with its own; the result is multiplied by
the pixel's own reflectance afterwards, so texture stays sharp while the noise of the
interleaved VPL/photon sets (§4.2) is averaged out. With a window equal to the interleave
size n every set appears once in a smooth region, and the structured noise disappears.

A split glossy coat's lobe (``TileBuffers.lobe``: one sampled ray per pixel, design note 3) is
filtered beside the irradiance with the same neighbours, among those that have a lobe, and added
after the compose: not over the reflectance, which a dark or textured layer makes a poor divisor.

Windows: an odd window w uses offsets -(w//2) .. w//2 (centred). An even window w (an even
interleave n) uses offsets -(w//2) .. w//2 - 1: an n x n block that holds every interleave
set exactly once, at the price of a half-pixel shift of the filter footprint.

The per-pixel work is a compiled kernel (``master.kernels.discontinuity``), fused with the
compose on the master's frame path (``FrameAssembler``); row stripes run on
``master.parallel``'s threads. The numpy formulation it replaced is kept as a test oracle
(tests/support/oracle_master.py); both give the same image bit for bit.
"""
from __future__ import annotations

import numpy as np

from igi.master.kernels.discontinuity import filter_rows

# Pixels per parallel stripe: enough work per hand-off to the pool, several per thread.
STRIPE_PIXELS = 32768


def resolve_window(filter_window: int, interleave: int) -> int:
    """The window the filter uses: the parameter, or the interleave size when it is -1."""
    w = interleave if filter_window == -1 else filter_window
    if w < 1:
        raise ValueError(f"filter window must be >= 1 (or -1 for the interleave size), got {filter_window}")
    return int(w)


def window_offsets(window: int) -> range:
    """Offsets along one axis: -(w//2) .. w//2 for odd w, -(w//2) .. w//2 - 1 for even w."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    return range(-(window // 2), window - window // 2)


def filter_irradiance(irradiance: np.ndarray, depth: np.ndarray, normal: np.ndarray,
                      window: int, depth_threshold: float, normal_threshold: float) -> np.ndarray:
    """Average irradiance over geometrically continuous neighbours.

    irradiance (H, W, 3), depth (H, W) (inf or NaN = miss), normal (H, W, 3).
    A neighbour j of centre c counts when |depth_j - depth_c| <= depth_threshold * depth_c
    and dot(normal_j, normal_c) >= normal_threshold; the centre always counts. Miss pixels
    keep their irradiance. Returns (H, W, 3) float32.

    Row strips run in parallel on ``master.parallel``'s threads; the result does not depend
    on the thread count.
    """
    irr = np.asarray(irradiance, dtype=np.float32)
    H, W = irr.shape[:2]
    if irr.shape != (H, W, 3) or np.shape(depth) != (H, W) or np.shape(normal) != (H, W, 3):
        raise ValueError(f"shapes must be (H,W,3), (H,W), (H,W,3); got {irr.shape}, "
                         f"{np.shape(depth)}, {np.shape(normal)}")
    offs = window_offsets(window)
    if window == 1 or H == 0 or W == 0:
        return irr.copy()
    d = np.ascontiguousarray(depth, dtype=np.float32)
    planar = lambda a: np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 0, 1))
    ip, npl = planar(irr), planar(normal)
    out = np.empty((3, H, W), np.float32)
    lo, hi = -offs[0], offs[-1]
    run_stripes(H, W, lambda y0, y1: filter_rows(ip, npl, d, y0, y1, lo, hi, float(depth_threshold),
                                                 float(normal_threshold), out))
    return np.ascontiguousarray(out.transpose(1, 2, 0))


def run_stripes(H: int, W: int, fn) -> None:
    """``fn(y0, y1)`` over row stripes of an H x W frame, on ``master.parallel``'s threads (the
    kernels are ``nogil``; stripes write disjoint rows, so results do not depend on threads)."""
    from . import parallel

    rows = max(1, min(-(-STRIPE_PIXELS // max(W, 1)), -(-H // (2 * parallel.threads()))))
    parallel.pmap(lambda y0: fn(y0, min(H, y0 + rows)), range(0, H, rows))


def compose(reflectance: np.ndarray, filtered_irradiance: np.ndarray,
            unfiltered: np.ndarray) -> np.ndarray:
    """Final radiance: the pixel's own reflectance times filtered irradiance, plus the part
    that must not be blurred (emitters seen directly, specular-chain emission)."""
    return (np.asarray(reflectance, np.float32) * np.asarray(filtered_irradiance, np.float32)
            + np.asarray(unfiltered, np.float32))
