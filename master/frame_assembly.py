"""Assembling a frame on the master: tiles in, full-frame buffers and the filtered image out.

:class:`FrameAssembler` receives (tile, TileBuffers) pairs in any order, scatters them into
full-frame buffers (sub-image pixel (sx, sy) of set k lands on image pixel
(sx·n + k mod n, sy·n + k div n)), knows when every pixel has arrived, and produces the image:
discontinuity buffer over the irradiance (window ``filter_window``, -1 → n), multiplied by the
pixel's own reflectance, plus the unfiltered part (docs/design-notes.md, discontinuity buffer; paper §4.3).

Two ways in, one image out: :meth:`FrameAssembler.add` takes decoded float buffers;
:meth:`FrameAssembler.add_wire` (the broker) takes a task's wire bytes and keeps them in
compact per-sub-image byte planes (lz4 decompression plus one contiguous copy per tile, all on
the receiving thread), so the float conversion, scatter into image space, filter and compose
run once per frame, in parallel stripes (``master.parallel``), straight into the filter's
padded planes. Both give bit-identical buffers and images (tests/bench/test_scaling_model.py).

:func:`task_tiles` is THE task decomposition of a frame; the broker and ``render_local`` both
use it, so both paths render exactly the same tiles.
"""
from __future__ import annotations

import contextlib
import threading

import numpy as np

from common.frame import Tile, TileBuffers
from common.interleave import make_tiles, scatter, sub_image_size, task_tile_size, tile_slices

DEFAULT_TASK_PIXELS = 4096  # ~20-50 ms of worker time at 22 VPLs on this machine's cores


def task_tiles(width: int, height: int, n: int, task_pixels: int = DEFAULT_TASK_PIXELS) -> list[Tile]:
    """The tasks of a frame: every sub-image k (k-major order) cut into tiles of about
    ``task_pixels`` pixels (``interleave.task_tile_size``), empty sub-images skipped."""
    tile_w, tile_h = task_tile_size(width, height, n, task_pixels)
    return make_tiles(width, height, n, tile_w, tile_h)


def tile_pixel_count(tile: Tile, n: int, width: int, height: int) -> int:
    """Pixels of ``tile`` inside a width x height image."""
    _, _, h, w = tile_slices(tile, n, width, height)
    return h * w


class FrameAssembler:
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
        from common.codec import decode_raw, decompress

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
        from master.discontinuity_buffer import compose, filter_irradiance, resolve_window

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
        from master import parallel
        from master.discontinuity_buffer import window_offsets, window_pad

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
        from master.discontinuity_buffer import FilterPlanes

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
        sw, sh = self.sizes[tile.k]
        w, h = min(tile.sx1, sw) - tile.sx0, min(tile.sy1, sh) - tile.sy0
        if w * h != p:
            raise ValueError(f"tile {tile} holds {w * h} pixels, data has {p}")
        k, ys, xs = tile.k, slice(tile.sy0, tile.sy0 + h), slice(tile.sx0, tile.sx0 + w)
        # common.codec layout: 3 float16 sections x 2 byte planes x P x 3, depth 4 planes x P,
        # normal 2 byte planes x P x 2
        self.f16[:, :, k, ys, xs] = raw[:18 * p].reshape(3, 2, h, w, 3)
        self.dep[:, k, ys, xs] = raw[18 * p:22 * p].reshape(4, h, w)
        self.nor[:, k, ys, xs] = raw[22 * p:26 * p].reshape(2, h, w, 2)

    def convert(self, sy0: int, sy1: int, values, normals, dp=None, depth=None) -> None:
        """Decode sub-image rows ``sy0 .. sy1`` of every k (image rows sy0·n … sy1·n - 1) into
        image space: ``values`` (3 buffers, 3 channels, H, W) float32 (reflectance,
        irradiance, unfiltered), ``normals`` (3, H, W), ``dp`` (H, W) the depth with NaN at
        misses (the filter's form), ``depth`` (H, W) the depth as sent; any strides. Row
        blocks are disjoint, so threads may convert different blocks at once; a block's
        destination rows stay in cache while all n² sub-images write into them."""
        from common.codec import f16_to_f32, oct_decode_planes

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
        from master import parallel

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
    from common.params import params_to_dict

    return params_to_dict(params)
