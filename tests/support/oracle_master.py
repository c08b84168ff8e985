"""The numpy master path that master.kernels replaced (issue 16): the discontinuity buffer
(FilterPlanes, filter_irradiance, compose) and the frame assembler's wire path (_WireFrame,
image in parallel stripes), exactly as they were: a test oracle and the "before" of
``python -m tests.support.master_speed``."""
from __future__ import annotations

import contextlib
import threading

import numpy as np

from igi.common.codec import decompress
from igi.common.frame import Tile, TileBuffers
from igi.common.interleave import scatter, sub_image_size, tile_slices
from igi.master.discontinuity_buffer import resolve_window, window_offsets  # unchanged helpers

from tests.support.oracle_codec import decode_raw, f16_to_f32, oct_decode_planes

# Pixels per row strip: ~16 float32 work arrays of this length stay within L2.
_STRIP_PIXELS = 8192


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


def continuous_neighbours(b: dict, y: int, x: int, window: int, dt: float, nt: float):
    """The discontinuity buffer's neighbours of pixel (y, x), written out one by one for test
    references: each (j, i) in the window but the centre, inside the image, with a finite depth
    within ``dt`` of the centre's (relative) and a normal whose dot product with the centre's
    is at least ``nt``. ``b``: image-order buffers (``depth`` (H, W), ``normal`` (H, W, 3))."""
    H, W = b["depth"].shape
    dc, nc = b["depth"][y, x], b["normal"][y, x]
    offs = range(-(window // 2), window - window // 2)
    for oy in offs:
        for ox in offs:
            j, i = y + oy, x + ox
            if (oy or ox) and 0 <= j < H and 0 <= i < W:
                d = b["depth"][j, i]
                if np.isfinite(d) and abs(d - dc) <= dt * dc and b["normal"][j, i] @ nc >= nt:
                    yield j, i


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
        from igi.master import parallel

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


# ---- frame assembly (old master/frame_assembly.py) ----

def tile_pixel_count(tile: Tile, n: int, width: int, height: int) -> int:
    """Pixels of ``tile`` inside a width x height image."""
    _, _, h, w = tile_slices(tile, n, width, height)
    return h * w


class OracleFrameAssembler:
    """Full-frame buffers of one frame, filled tile by tile."""

    def __init__(self, width: int, height: int, n: int):
        if width < 1 or height < 1 or n < 1:
            raise ValueError(f"bad frame {width}x{height}, interleave {n}")
        self.width, self.height, self.n = width, height, n
        self._buffers: dict[str, np.ndarray] | None = None  # float path (add / .buffers)
        self._wire: _WireFrame | None = None  # wire path (add_wire), until .buffers is read
        self.expected = width * height
        self.received = 0
        self._tiles: set[Tile] = set()

    @property
    def buffers(self) -> dict[str, np.ndarray]:
        """Full-frame float32 buffers (H, W, 3) / (H, W). Reading them turns a wire-path
        assembler into a float-path one (same values, bit for bit)."""
        if self._buffers is None:
            self._buffers = _empty_buffers(self.width, self.height)
            if self._wire is not None:
                self._wire.to_buffers(self._buffers)
                self._wire = None
        return self._buffers

    @property
    def complete(self) -> bool:
        return self.received >= self.expected

    def _check(self, tile: Tile, count: int | None) -> int:
        expected = tile_pixel_count(tile, self.n, self.width, self.height)
        if not 0 <= tile.k < self.n * self.n or (count is not None and count != expected):
            raise ValueError(f"tile {tile} holds {expected} pixels, buffers have {count}")
        return expected

    def add(self, tile: Tile, buffers: TileBuffers) -> bool:
        """Scatter one tile; returns True when the frame is complete. A tile already added is
        ignored (duplicate); a tile whose pixel count does not match raises ValueError."""
        if tile in self._tiles:
            return self.complete
        count = self._check(tile, len(buffers))
        scatter(tile, self.n, buffers, self.buffers)
        self._tiles.add(tile)
        self.received += count
        return self.complete

    def add_wire(self, tile: Tile, data: bytes) -> bool:
        """Like :meth:`add`, from the tile's wire bytes (``common.codec``). The data is fully
        validated (header, pixel count, lz4 frame and checksum) before anything is written:
        a bad payload raises ValueError and leaves the frame as it was."""
        if tile in self._tiles:
            return self.complete
        count = self._check(tile, None)

        p, raw = decompress(data, count)
        if self._buffers is not None:
            scatter(tile, self.n, decode_raw(p, raw), self._buffers)
        else:
            if self._wire is None:
                self._wire = _WireFrame(self.width, self.height, self.n)
            self._wire.put(tile, p, raw)
        self._tiles.add(tile)
        self.received += count
        return self.complete

    def image(self, params, index: int = 0) -> np.ndarray:
        """The filtered image (H, W, 3) float32, linear radiance, of accumulation frame ``index``.

        With ``consistent`` accumulation the discontinuity buffer's share fades after
        ``filter_frames`` frames: frame i uses w·filtered + (1-w)·raw irradiance with
        w = min(1, T/(i+1)), so the filter's blur (a bias no averaging removes) vanishes from
        the running mean like T·ln(N/T)/N, while the first frames stay smooth.
        """

        p = params if isinstance(params, dict) else _asdict(params)
        window = resolve_window(int(p["filter_window"]), self.n)
        w = filter_weight(p, index)
        if self._buffers is None:
            return self._wire_image(window, w, p)
        b = self.buffers
        if w <= 0.0 or window <= 1:
            return compose(b["reflectance"], b["irradiance"], b["unfiltered"])
        filtered = filter_irradiance(b["irradiance"], b["depth"], b["normal"], window,
                                     float(p["depth_threshold"]), float(p["normal_threshold"]))
        if w < 1.0:
            filtered = w * filtered + (1.0 - w) * b["irradiance"]
        return compose(b["reflectance"], filtered, b["unfiltered"])

    def _wire_image(self, window: int, w: float, p: dict) -> np.ndarray:
        """image() of the wire path: the same operations as the float path, planar and in
        parallel stripes (bit-identical results)."""
        from igi.master import parallel

        H, W = self.height, self.width
        wire = self._wire if self._wire is not None else _WireFrame(W, H, self.n)
        use_filter = w > 0.0 and window > 1
        with _scratch(H, W, window_pad(window) if use_filter else 0) as sc:
            wire.decode_into(sc)
            planes = sc.planes
            vals = sc.values  # (3 buffers, 3 channels, H, W) views: reflectance, irradiance, unfiltered
            if use_filter:
                filt = planes.filter(window_offsets(window), float(p["depth_threshold"]),
                                     float(p["normal_threshold"]), out=sc.out)
                irr = [planes.interior(planes.centre[c]) for c in range(3)]
            else:
                filt = vals[1]
                irr = None
                w = 1.0
            img = np.empty((H, W, 3), np.float32)
            rows = max(1, -(-H // (4 * parallel.threads())))

            def finish(y0: int) -> None:
                y1 = min(H, y0 + rows)
                for c in range(3):
                    f = filt[c, y0:y1]
                    if w < 1.0:  # the float path's w * filtered + (1 - w) * irradiance, per element
                        f = w * f + (1.0 - w) * irr[c][y0:y1]
                    # compose(): reflectance * filtered + unfiltered
                    img[y0:y1, :, c] = vals[0, c, y0:y1] * f + vals[2, c, y0:y1]

            parallel.pmap(finish, range(0, H, rows))
        return img


class _Scratch:
    """Per-frame working arrays of the wire path, kept between frames (fresh multi-megabyte
    arrays cost page faults every frame): values (3 buffers x 3 channels) and normals as flat
    padded planes (FilterPlanes), the filter's output, and the raw depth."""

    def __init__(self, H: int, W: int, pad: int):

        Hp, Wp = H + 2 * pad, W + 2 * pad
        self.key = (H, W, pad)
        self.flat = np.zeros((9, Hp * Wp), np.float32)  # reflectance, irradiance, unfiltered x 3
        self.planes = FilterPlanes(H, W, pad, ips=self.flat[3:6])
        self.out = np.empty((3, H * Wp), np.float32)
        self.depth = np.empty((H, W), np.float32)
        sl = (slice(pad, pad + H), slice(pad, pad + W))
        self.values = self.flat.reshape(3, 3, Hp, Wp)[(slice(None), slice(None)) + sl]
        self.normals = self.planes.nps.reshape(3, Hp, Wp)[(slice(None),) + sl]
        self.dp = self.planes.dp_interior


_scratch_lock = threading.Lock()
_scratch_free: dict[tuple, list[_Scratch]] = {}


@contextlib.contextmanager
def _scratch(H: int, W: int, pad: int):
    key = (H, W, pad)
    with _scratch_lock:
        free = _scratch_free.get(key)
        sc = free.pop() if free else None
    if sc is None:
        sc = _Scratch(H, W, pad)
    try:
        yield sc
    finally:
        with _scratch_lock:
            if len(_scratch_free) > 4 and key not in _scratch_free:  # resolutions come and go
                _scratch_free.clear()
            lst = _scratch_free.setdefault(key, [])
            if len(lst) < 2:
                lst.append(sc)


def _empty_buffers(width: int, height: int) -> dict[str, np.ndarray]:
    return {
        "reflectance": np.zeros((height, width, 3), np.float32),
        "irradiance": np.zeros((height, width, 3), np.float32),
        "unfiltered": np.zeros((height, width, 3), np.float32),
        "depth": np.full((height, width), np.inf, np.float32),
        "normal": np.zeros((height, width, 3), np.float32),
    }


# byte planes of the values a pixel has before its tile arrives: float16 0, depth +inf (miss),
# normal code (-32768, -32768) (the reserved "no normal" code, decodes to 0)
_INF_BYTES = np.frombuffer(np.float32(np.inf).astype("<f4").tobytes(), np.uint8)
_NO_NORMAL_BYTES = np.frombuffer(np.int16(-32768).astype("<i2").tobytes(), np.uint8)


class _WireFrame:
    """A frame's tiles as they came off the wire: the decompressed byte planes (still
    byte-shuffled) of every sub-image k, laid out as the sub-images (a tile is a rectangle of
    one, so storing it is one contiguous copy per section). All n² sub-images share one array
    (padded to the largest), so decoding handles every k of a row block in one call."""

    def __init__(self, width: int, height: int, n: int):
        self.width, self.height, self.n = width, height, n
        K = n * n
        self.sizes = [sub_image_size(width, height, n, k) for k in range(K)]
        self.swm = max(s[0] for s in self.sizes)
        self.shm = max(s[1] for s in self.sizes)
        shape = (K, self.shm, self.swm)
        self.f16 = np.zeros((3, 2) + shape + (3,), np.uint8)  # section, byte, k, y, x, channel
        self.dep = np.empty((4,) + shape, np.uint8)  # byte, k, y, x
        self.dep[...] = _INF_BYTES[:, None, None, None]
        self.nor = np.empty((2,) + shape + (2,), np.uint8)  # byte, k, y, x, component
        self.nor[...] = _NO_NORMAL_BYTES[:, None, None, None, None]

    def put(self, tile: Tile, p: int, raw: np.ndarray) -> None:
        if len(raw) != 26 * p:
            raise ValueError("the numpy master reads codec payloads without a lobe section only")
        sw, sh = self.sizes[tile.k]
        w, h = min(tile.sx1, sw) - tile.sx0, min(tile.sy1, sh) - tile.sy0
        if w * h != p:
            raise ValueError(f"tile {tile} holds {w * h} pixels, data has {p}")
        k, ys, xs = tile.k, slice(tile.sy0, tile.sy0 + h), slice(tile.sx0, tile.sx0 + w)
        # common.codec layout (version 2): 3 float16 sections x 2 byte planes x 3 channels x P,
        # depth 4 planes x P, normal 2 byte planes x 2 components x P
        self.f16[:, :, k, ys, xs] = raw[:18 * p].reshape(3, 2, 3, h, w).transpose(0, 1, 3, 4, 2)
        self.dep[:, k, ys, xs] = raw[18 * p:22 * p].reshape(4, h, w)
        self.nor[:, k, ys, xs] = raw[22 * p:26 * p].reshape(2, 2, h, w).transpose(0, 2, 3, 1)

    def convert(self, sy0: int, sy1: int, values, normals, dp=None, depth=None) -> None:
        """Decode sub-image rows ``sy0 .. sy1`` of every k (image rows sy0·n … sy1·n - 1) into
        image space: ``values`` (3 buffers, 3 channels, H, W) float32 (reflectance,
        irradiance, unfiltered), ``normals`` (3, H, W), ``dp`` (H, W) the depth with NaN at
        misses (the filter's form), ``depth`` (H, W) the depth as sent; any strides. Row
        blocks are disjoint, so threads may convert different blocks at once; a block's
        destination rows stay in cache while all n² sub-images write into them."""
        n, K, swm = self.n, self.n * self.n, self.swm
        rows = sy1 - sy0
        src = slice(sy0, sy1)
        # float16: byte planes -> little-endian uint16 -> float32, every k and section at once
        pair = np.empty((3, K, rows, swm, 3, 2), np.uint8)
        pair[..., 0] = self.f16[:, 0, :, src]
        pair[..., 1] = self.f16[:, 1, :, src]
        vals = f16_to_f32(pair.view(np.uint16)[..., 0])  # (3, K, rows, swm, 3)
        qp = np.empty((2, K, rows, swm, 2), np.uint8)  # component, k, y, x, byte
        for c in range(2):
            qp[c, ..., 0] = self.nor[0, :, src, :, c]
            qp[c, ..., 1] = self.nor[1, :, src, :, c]
        q = qp.view(np.int16)[..., 0]
        nrm = oct_decode_planes(q[0], q[1])  # (3, K, rows, swm)
        d = np.empty((K, rows, swm, 4), np.uint8)
        for b in range(4):
            d[..., b] = self.dep[b, :, src]
        d = d.view(np.float32)[..., 0]
        dnan = np.where(np.isfinite(d), d, np.float32(np.nan)) if dp is not None else None
        for k, (sw, sh) in enumerate(self.sizes):
            rk = min(sy1, sh) - sy0
            if sw == 0 or rk <= 0:
                continue
            ky, kx = divmod(k, n)
            y0 = sy0 * n + ky
            at = (slice(y0, y0 + (rk - 1) * n + 1, n), slice(kx, kx + (sw - 1) * n + 1, n))
            values[(slice(None), slice(None)) + at] = vals[:, k, :rk, :sw].transpose(0, 3, 1, 2)
            normals[(slice(None),) + at] = nrm[:, k, :rk, :sw]
            if dp is not None:
                dp[at] = dnan[k, :rk, :sw]
            if depth is not None:
                depth[at] = d[k, :rk, :sw]

    def row_blocks(self, threads: int) -> list[tuple[int, int]]:
        """Sub-image row blocks for :meth:`convert`: ~1 MB of destination rows each (cache),
        at least a few per thread."""
        row_bytes = self.width * 4 * 14  # 9 value planes, 3 normals, depth, dp
        step = max(1, min((1 << 20) // (row_bytes * self.n), -(-self.shm // (2 * threads))))
        return [(r, min(self.shm, r + step)) for r in range(0, self.shm, step)]

    def decode_into(self, sc: "_Scratch", depth: bool = False) -> None:
        from igi.master import parallel

        parallel.pmap(lambda r: self.convert(r[0], r[1], sc.values, sc.normals, sc.dp,
                                             sc.depth if depth else None),
                      self.row_blocks(parallel.threads()))

    def to_buffers(self, b: dict[str, np.ndarray]) -> None:
        H, W = self.height, self.width
        with _scratch(H, W, 0) as sc:
            self.decode_into(sc, depth=True)
            for s, name in enumerate(("reflectance", "irradiance", "unfiltered")):
                np.copyto(b[name], sc.values[s].transpose(1, 2, 0))
            np.copyto(b["normal"], sc.normals.transpose(1, 2, 0))
            np.copyto(b["depth"], sc.depth)


def filter_weight(params: dict, index: int) -> float:
    """Share of the filtered irradiance in accumulation frame ``index`` (see FrameAssembler.image)."""
    t = int(params.get("filter_frames", -1))
    if t < 0 or index < t or not params.get("consistent", False) or not params.get("accumulate", True):
        return 1.0
    return t / (index + 1.0)


def _asdict(params) -> dict:
    from igi.common.params import params_to_dict

    return params_to_dict(params)


# ---- accumulation (old master/accumulation.py Accumulator.add / mean) ----
def accumulate_numpy(total: np.ndarray, half: np.ndarray, img: np.ndarray) -> None:
    total += img
    half += img


def mean_numpy(total: np.ndarray, count: int) -> np.ndarray:
    return (total / count).astype(np.float32)
