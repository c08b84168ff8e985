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
    d = np.asarray(depth, dtype=np.float32)
    n = np.asarray(normal, dtype=np.float32)
    pad = window_pad(window)
    planes = FilterPlanes(H, W, pad)
    # Depth NaN in the padding and at misses makes every comparison false: outside pixels
    # and misses never count as neighbours, with no extra mask per offset.
    np.copyto(planes.interior(planes.dp), d)
    planes.dp_interior[~np.isfinite(d)] = np.nan
    for c in range(3):
        np.copyto(planes.interior(planes.nps[c]), n[..., c])
        np.copyto(planes.interior(planes.ips[c]), irr[..., c])
    out = planes.filter(offs, depth_threshold, normal_threshold)
    res = np.empty((H, W, 3), np.float32)
    for c in range(3):
        res[..., c] = out[c]
    return res


def window_pad(window: int) -> int:
    """Padding (pixels on every side) the filter's flat-shift trick needs for ``window``."""
    offs = window_offsets(window)
    return max(-offs[0], offs[-1])


class FilterPlanes:
    """The filter's working set: flat, padded, planar float32 planes of one frame.

    ``dp`` (Hp*Wp,) depth with NaN at misses and in the padding; ``nps`` (3, Hp*Wp) normals and
    ``ips`` (3, Hp*Wp) irradiance, zero in the padding; Hp = H + 2 pad, Wp = W + 2 pad. A
    neighbour (oy, ox) of a pixel is then the constant flat shift oy*Wp + ox. The master fills
    these straight from the wire (``FrameAssembler``); :func:`filter_irradiance` from (H, W, 3)
    arrays.
    """

    def __init__(self, H: int, W: int, pad: int, ips: np.ndarray | None = None):
        """``ips``: a (3, Hp*Wp) float32 array to use for the irradiance (e.g. part of a
        larger block the caller decodes into); its padding is zeroed here."""
        self.H, self.W, self.pad = H, W, pad
        self.Hp, self.Wp = H + 2 * pad, W + 2 * pad
        N = self.Hp * self.Wp
        self.dp = np.empty(N, np.float32)
        self.nps = np.empty((3, N), np.float32)
        self.ips = np.empty((3, N), np.float32) if ips is None else ips
        if self.ips.shape != (3, N) or self.ips.dtype != np.float32:
            raise ValueError(f"ips must be (3, {N}) float32, got {self.ips.shape} {self.ips.dtype}")
        # padding only: the interior is written by whoever fills the planes
        for plane, fill in ((self.dp[None], np.nan), (self.nps, 0.0), (self.ips, 0.0)):
            v = plane.reshape(len(plane), self.Hp, self.Wp)
            v[:, :pad] = fill
            v[:, pad + H:] = fill
            v[:, pad:pad + H, :pad] = fill
            v[:, pad:pad + H, pad + W:] = fill

    def interior(self, flat: np.ndarray) -> np.ndarray:
        """(H, W) view of the frame inside a flat padded plane."""
        p = self.pad
        return flat.reshape(self.Hp, self.Wp)[p:p + self.H, p:p + self.W]

    @property
    def dp_interior(self) -> np.ndarray:
        return self.interior(self.dp)

    def filter(self, offs: range, depth_threshold: float, normal_threshold: float,
               out: np.ndarray | None = None) -> np.ndarray:
        """Filtered irradiance as a (3, H, W) view (of ``out``: (3, H*Wp) float32 when given).
        Misses (NaN dp) keep their irradiance. Non-finite irradiance: neighbours read it as 0,
        the pixel keeps its own value (one firefly must not wipe out its window)."""
        from . import parallel

        H, W, Wp, pad = self.H, self.W, self.Wp, self.pad
        lo, hi = -offs[0], offs[-1]
        if max(lo, hi) > pad:
            raise ValueError(f"window offsets {lo}/{hi} exceed the padding {pad}")
        ips = self.ips
        centre = ips
        if not np.isfinite(ips).all():
            centre = ips.copy()
            ips[~np.isfinite(ips)] = 0.0
        self.centre = centre  # the irradiance as given (ips itself may now read 0 at fireflies)
        if out is None:
            out = np.empty((3, H * Wp), np.float32)
        t = np.float32(depth_threshold)
        nt = np.float32(normal_threshold)
        # Centre pixels occupy flat positions base .. base + L of every padded plane (the pad
        # columns between rows ride along and are dropped at the end).
        base = pad * Wp + pad
        L = (H - 1) * Wp + W
        # Row strips keep the working arrays of one strip in cache across all offsets; they
        # are independent (read-only inputs, disjoint outputs), so threads take them in turn.
        strip = max(1, _STRIP_PIXELS // Wp) * Wp
        shifts = [oy * Wp + ox for oy in offs for ox in offs if (oy, ox) != (0, 0)]
        dp, nps = self.dp, self.nps
        cnt_dtype = np.uint8 if len(shifts) < 255 else np.uint32

        # The normal test is symmetric (dot(n_c, n_j) == dot(n_j, n_c) bit for bit: products
        # commute, and both sum x, y, z in the same order), so a strip computes it once per
        # pair of opposite offsets: for +s over centres c0 - s .. c0 + m, and reads -s shifted.
        fwd = sorted({abs(s) for s in shifts})

        def run(s0: int) -> None:
            s1 = min(L, s0 + strip)
            m = s1 - s0
            c0 = base + s0
            dc = dp[c0:c0 + m]
            # |d_j - d_c| <= t d_c  <=>  d_c (1 - t) <= d_j <= d_c (1 + t) for d_c >= 0: two
            # comparisons against precomputed bounds instead of subtract, abs and multiply.
            dlo = dc * (1 - t)
            dhi = dc * (1 + t)
            okn = {}
            smax = fwd[-1]
            tmp = np.empty((3, m + smax), np.float32)
            dot = np.empty(m + smax, np.float32)
            for s in fwd:  # normal agreement of every pixel in c0 - s .. c0 + m with its +s neighbour
                e = m + s
                a0 = c0 - s
                t3 = tmp[:, :e]
                np.multiply(nps[:, a0 + s:a0 + s + e], nps[:, a0:a0 + e], out=t3)
                d = dot[:e]
                np.add(t3[0], t3[1], out=d)  # (x + y) + z: add.reduce's order
                d += t3[2]
                okn[s] = np.greater_equal(d, nt)
            acc = centre[:, c0:c0 + m].copy()
            cnt = np.zeros(m, cnt_dtype)  # neighbours counted, besides the centre
            okf = np.empty(m, np.float32)
            tmp = tmp[:, :m]
            ok = np.empty(m, bool)
            ok2 = np.empty(m, bool)
            for sh in shifts:
                j0 = c0 + sh
                sl = slice(j0, j0 + m)
                dj = dp[sl]
                np.greater_equal(dj, dlo, out=ok)
                np.less_equal(dj, dhi, out=ok2)
                ok &= ok2
                s = abs(sh)
                # +s: pair (c, c + s) sits at index c - (c0 - s); -s: pair (c - s, c) at c - s - (c0 - s)
                ok &= okn[s][s:s + m] if sh > 0 else okn[s][:m]
                cnt += ok.view(np.uint8)
                np.copyto(okf, ok)  # one bool -> float32 cast, then plain float products
                np.multiply(ips[:, sl], okf, out=tmp)
                acc += tmp
            cntf = cnt.astype(np.float32)
            cntf += np.float32(1.0)  # the centre: exact small integers, as summed before
            np.divide(acc, cntf, out=out[:, s0:s1])

        parallel.pmap(run, range(0, L, strip))
        res = out[:, :H * Wp].reshape(3, H, Wp)[:, :, :W]
        # Misses keep their input exactly (their NaN bounds already kept neighbours out).
        miss = np.isnan(self.dp_interior)
        if miss.any():
            for c in range(3):
                res[c][miss] = self.interior(centre[c])[miss]
        return res


def compose(reflectance: np.ndarray, filtered_irradiance: np.ndarray,
            unfiltered: np.ndarray) -> np.ndarray:
    """Final radiance: the pixel's own reflectance times filtered irradiance, plus the part
    that must not be blurred (emitters seen directly, specular-chain emission)."""
    return (np.asarray(reflectance, np.float32) * np.asarray(filtered_irradiance, np.float32)
            + np.asarray(unfiltered, np.float32))
