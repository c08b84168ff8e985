"""The discontinuity buffer of the paper's §4.3.

Irradiance is piecewise smooth, so each pixel averages the irradiance of the neighbours in
a window around it whose depth and normal agree with its own; the result is multiplied by
the pixel's own reflectance afterwards, so texture stays sharp while the noise of the
interleaved VPL/photon sets (§4.2) is averaged out. With a window equal to the interleave
size n every set appears once in a smooth region, and the structured noise disappears.

Windows: an odd window w uses offsets -(w//2) .. w//2 (centred). An even window w (an even
interleave n) uses offsets -(w//2) .. w//2 - 1: an n x n block that holds every interleave
set exactly once, at the price of a half-pixel shift of the filter footprint.

Vectorized over pixels: the Python loops run over row strips (cache-sized) and the w*w - 1
window offsets, each a few float32 ufunc calls on shifted slices of flat padded planes.
"""
from __future__ import annotations

import numpy as np

# Pixels per row strip: ~16 float32 work arrays of this length stay within L2.
_STRIP_PIXELS = 8192


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
    """
    irr = np.asarray(irradiance, dtype=np.float32)
    H, W = irr.shape[:2]
    if irr.shape != (H, W, 3) or np.shape(depth) != (H, W) or np.shape(normal) != (H, W, 3):
        raise ValueError(f"shapes must be (H,W,3), (H,W), (H,W,3); got {irr.shape}, "
                         f"{np.shape(depth)}, {np.shape(normal)}")
    offs = window_offsets(window)
    if window == 1 or H == 0 or W == 0:
        return irr.copy()
    d = np.asarray(depth, dtype=np.float32)
    hit = np.isfinite(d)
    lo, hi = -offs[0], offs[-1]
    Wp = W + lo + hi  # padded row length
    Hp = H + lo + hi

    def pad(plane: np.ndarray, fill: float) -> np.ndarray:
        """Flat padded plane: a neighbour (oy, ox) is then a constant flat shift oy*Wp + ox."""
        out = np.full((Hp, Wp), fill, np.float32)
        out[lo:lo + H, lo:lo + W] = plane
        return out.ravel()

    # Depth NaN in the padding and at misses makes every comparison false: outside pixels
    # and misses never count as neighbours, with no extra mask per offset.
    dp = pad(np.where(hit, d, np.float32(np.nan)), np.nan)
    n = np.asarray(normal, dtype=np.float32)
    # Planar, flat, contiguous (3, Hp*Wp) planes: every per-offset operation is one ufunc
    # call over contiguous rows, the fastest numpy does (2-D strided views and ufunc where=
    # masks are several times slower).
    nps = np.stack([pad(n[..., c], 0.0) for c in range(3)])
    ips = np.stack([pad(irr[..., c], 0.0) for c in range(3)])
    centre = ips
    if not np.all(np.isfinite(irr)):
        # A non-finite neighbour would turn "value x 0" into NaN even when excluded, and one
        # firefly must not wipe out its window: neighbours read it as 0, it keeps its own.
        centre = ips.copy()
        ips[~np.isfinite(ips)] = 0.0
    t = np.float32(depth_threshold)
    nt = np.float32(normal_threshold)
    # Centre pixels occupy flat positions base .. base + L of every padded plane (the pad
    # columns between rows ride along and are dropped at the end).
    base = lo * Wp + lo
    L = (H - 1) * Wp + W
    out_planes = np.empty((3, L), np.float32)
    # Row strips keep the working arrays of one strip in cache across all offsets.
    strip = max(1, _STRIP_PIXELS // Wp) * Wp
    for s0 in range(0, L, strip):
        s1 = min(L, s0 + strip)
        m = s1 - s0
        c0 = base + s0
        dc = dp[c0:c0 + m]
        # |d_j - d_c| <= t d_c  <=>  d_c (1 - t) <= d_j <= d_c (1 + t) for d_c >= 0: two
        # comparisons against precomputed bounds instead of subtract, abs and multiply.
        dlo = dc * (1 - t)
        dhi = dc * (1 + t)
        nc = nps[:, c0:c0 + m]
        acc = centre[:, c0:c0 + m].copy()
        cnt = np.ones(m, np.float32)
        dot = np.empty(m, np.float32)
        tmp = np.empty((3, m), np.float32)
        ok = np.empty(m, bool)
        ok2 = np.empty(m, bool)
        for oy in offs:
            for ox in offs:
                if oy == 0 and ox == 0:
                    continue  # the centre always counts (already in acc and cnt)
                j0 = c0 + oy * Wp + ox
                sl = slice(j0, j0 + m)
                dj = dp[sl]
                np.greater_equal(dj, dlo, out=ok)
                np.less_equal(dj, dhi, out=ok2)
                ok &= ok2
                np.multiply(nps[:, sl], nc, out=tmp)
                np.add.reduce(tmp, axis=0, out=dot)
                np.greater_equal(dot, nt, out=ok2)
                ok &= ok2
                np.multiply(ips[:, sl], ok, out=tmp)
                acc += tmp
                cnt += ok
        np.divide(acc, cnt, out=out_planes[:, s0:s1])
    res = np.empty((H, W, 3), np.float32)
    for c in range(3):
        full = np.empty(H * Wp, np.float32)
        full[:L] = out_planes[c]
        res[..., c] = full.reshape(H, Wp)[:, :W]
    # Misses keep their input exactly (their NaN bounds already kept neighbours out).
    res[~hit] = irr[~hit]
    return res


def compose(reflectance: np.ndarray, filtered_irradiance: np.ndarray,
            unfiltered: np.ndarray) -> np.ndarray:
    """Final radiance: the pixel's own reflectance times filtered irradiance, plus the part
    that must not be blurred (emitters seen directly, specular-chain emission)."""
    return (np.asarray(reflectance, np.float32) * np.asarray(filtered_irradiance, np.float32)
            + np.asarray(unfiltered, np.float32))
