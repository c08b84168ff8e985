"""Assembling a frame on the master: tiles in, full-frame buffers and the filtered image out.

:class:`FrameAssembler` receives (tile, TileBuffers) pairs in any order, scatters them into
full-frame buffers (sub-image pixel (sx, sy) of set k lands on image pixel
(sx·n + k mod n, sy·n + k div n)), knows when every pixel has arrived, and produces the image:
discontinuity buffer over the irradiance (window ``filter_window``, -1 → n), multiplied by the
pixel's own reflectance, plus the split lobes (filtered beside the irradiance, over the neighbours
that have one) and the unfiltered part (docs/design-notes.md, discontinuity buffer; paper §4.3).

Two ways in, one image out: :meth:`FrameAssembler.add` takes decoded float buffers;
:meth:`FrameAssembler.add_wire` (the broker) takes a task's wire bytes, lz4-decompresses them
and decodes them in one compiled pass (``common.codec.decode_into``) straight into image-space
float32 planes, on the receiving thread; the frame's image is then one fused compiled pass
(discontinuity filter + compose, ``master.kernels.discontinuity``) in row stripes on
``master.parallel``'s threads. Both give bit-identical buffers and images
(tests/bench/test_scaling_model.py), and the same images as the numpy path they replaced
(tests/master/test_master_kernels.py).

:func:`task_tiles` is THE task decomposition of a frame; the broker and ``render_local`` both
use it, so both paths render exactly the same tiles.
"""
from __future__ import annotations

import threading
import weakref

import numpy as np

from igi.common.codec import decode_into, decode_raw, decompress
from igi.common.frame import NO_LOBE, Tile, TileBuffers
from igi.common.interleave import make_tiles, scatter, task_tile_size, tile_slices
from igi.master.discontinuity_buffer import resolve_window, run_stripes, window_offsets
from igi.master.edge_stopping import EdgeStoppingGuide
from igi.master.kernels.discontinuity import finish_sub, plane_pad

# Task size: every task pays a fixed cost per bounce of its eye paths and chains (~0.5 ms of small
# numpy calls and one Embree batch each, whatever the batch size), so larger tasks render faster
# (measured 640x480: 16384 against 4096 pixels, one process: 8-11% less CPU a frame on
# grey-white-room and cornell-box-glossy, 11% on modern-hall; 2 workers on cornell-box-sphere
# 1.49 -> 1.73 frames/s); but a frame must still be cut into enough tasks for every render
# thread. The default is one fixed size, so a frame's image never depends on how many workers
# rendered it (DESIGN.md); ``Broker(task_pixels=None)`` opts in to task_pixels_for, the largest
# tasks that leave each thread TASKS_PER_THREAD tasks among the frames in flight (clusters past
# ~32 render threads, where 16384-pixel tasks run out: model at 64 workers 40.7 vs 51.8 fps).
SMALLEST_TASK_PIXELS = 4096  # ~20-50 ms of worker time at 22 VPLs on this machine's cores
LARGEST_TASK_PIXELS = 16384  # a whole 5x5 sub-image at 640x480
TASKS_PER_THREAD = 4  # tasks per render thread among the frames in flight (balance, set affinity)
DEFAULT_TASK_PIXELS = LARGEST_TASK_PIXELS  # the broker's and render_local's fixed size
VALUE_NAMES = ("reflectance", "irradiance", "unfiltered", "lobe")  # the planes' 12 value channels, in order
_NO_GUIDE = np.zeros((0, 0), np.float32)  # finish_sub's guide planes when a frame is not guided
_NO_SUMS = np.zeros((0, 0), np.float64)  # finish_sub's guide sums when no guide learns
_NO_SHARES = np.zeros((0, 3, 0), np.float64)  # finish_sub's filter shares when none are summed


def task_pixels_for(pixels: int, threads: int, frames_in_flight: int) -> int:
    """Pixels per task for frames of ``pixels`` pixels rendered by ``threads`` render threads
    (all workers' together) with ``frames_in_flight`` frames open at once: as large as
    possible while the open frames hold TASKS_PER_THREAD tasks per thread, within
    [SMALLEST_TASK_PIXELS, LARGEST_TASK_PIXELS]. 640x480 with 3 frames in flight: whole 5x5
    sub-images (one task per k) up to 16 threads, two tasks per k at 32, 4096 pixels from 57."""
    fit = int(pixels) * max(1, int(frames_in_flight)) // (TASKS_PER_THREAD * max(1, int(threads)))
    return int(min(LARGEST_TASK_PIXELS, max(SMALLEST_TASK_PIXELS, fit)))


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
        self._wire: _Planes | None = None  # wire path (add_wire), until .buffers is read
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
                self._wire.to_buffers(self._buffers, self._tiles)
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
            wf = self._planes()
            _, _, h, w = tile_slices(tile, self.n, self.width, self.height)
            k = tile.k
            q = wf.pad
            if decode_into(raw, p, h, w, 1, tile.sy0 + q, tile.sx0 + q, wf.vals[k], wf.nrm[k], wf.depth[k]):
                wf.lobes = True
            wf.covered += p
        self._tiles.add(tile)
        self.received += count
        return self.complete

    def _planes(self) -> "_Planes":
        if self._wire is None:
            self._wire = _Planes.acquire(self.width, self.height, self.n)
            weakref.finalize(self, _Planes.release, self._wire)
        return self._wire

    def image(self, params, index: int = 0, guide: EdgeStoppingGuide | None = None) -> np.ndarray:
        """The filtered image (H, W, 3) float32, linear radiance, of accumulation frame ``index``.

        With ``consistent`` accumulation the discontinuity buffer's share fades after
        ``filter_frames`` frames: frame i uses w·filtered + (1-w)·raw irradiance with
        w = min(1, T/(i+1)), so the filter's blur (a bias no averaging removes) vanishes from
        the running mean like T·ln(N/T)/N, while the first frames stay smooth.

        ``guide``: the accumulation's edge-stopping guide (``master.edge_stopping``; the caller
        tracks its key): its earlier frames guide this frame's filter (``filter_guide``), and
        this frame's raw irradiance is added to it. Ignored without accumulation, with
        ``filter_guide`` 0 or without a filter (window 1). A guided irradiance filter does not
        fade (its blur shrinks with the noise of the luminance it watches, and it keeps
        averaging) unless ``filter_frames`` is 0 (no filter); the split lobes, never guided,
        fade only without ``filter_select`` (with it the running mean takes back whatever share
        of either filter is measurably biased: ``master.filter_selection``).
        """
        p = params if isinstance(params, dict) else _asdict(params)
        window = resolve_window(int(p["filter_window"]), self.n)
        if not p.get("accumulate", True) or float(p.get("filter_guide", 0.0)) <= 0 or window <= 1:
            guide = None  # every frame the same (nothing to learn), or nothing it would guide
        fade = filter_weight(p, index)
        kept = guide is not None and fade > 0
        w = (1.0 if kept else fade, 1.0 if kept and float(p.get("filter_select", 0.0)) > 0 else fade)
        if self._buffers is None:
            return self._planes().image(self._tiles, window, w, p, guide)
        b = self.buffers
        pl = _Planes.acquire(self.width, self.height, 1)  # the frame in image order: one sub-image
        try:
            for s, name in enumerate(VALUE_NAMES):
                pl.interior(pl.vals[0, 3 * s:3 * s + 3])[...] = b[name].transpose(2, 0, 1)
            pl.lobes = bool(np.any(b["lobe"][..., 0] >= 0))
            pl.interior(pl.nrm[0])[...] = b["normal"].transpose(2, 0, 1)
            pl.interior(pl.depth[0])[...] = b["depth"]
            return pl.finish(window, w, p, guide)
        finally:
            _Planes.release(pl)


def _window_reach(window: int) -> tuple[int, int]:
    """(lo, hi): the window's offsets run -lo .. hi."""
    offs = window_offsets(window)
    return -offs[0], offs[-1]


class _Planes:
    """A frame's decoded buffers as they arrive, per sub-image k of the interleave (a tile is
    a rectangle of one, so its decode writes contiguous rows): ``vals`` (n², 12, SH, SW)
    float32 reflectance, irradiance, unfiltered, lobe (x RGB), ``nrm`` (n², 3, SH, SW), ``depth``
    (n², SH, SW), where SH x SW is the largest sub-image with a border of ``pad`` pixels all
    round. The image is made in row stripes that are filtered and composed in sub-image space
    (``master.kernels.discontinuity.finish_sub``).

    The border and every cell outside a sub-image's own extent hold a miss (depth +inf, zero
    values, NO_LOBE), written once when the planes are made; decodes write only inside. ``pad`` covers
    the widest window the parameters allow, so a frame's filter reads its neighbours across
    the image's edges without a bounds test.

    ``lobes``: a tile since acquire held split lobes (the filter reads the lobe planes only then).

    Pooled per resolution (fresh multi-megabyte arrays cost page faults every frame): an
    assembler takes a set when its first tile arrives and gives it back when it is collected.
    Pixels no tile has written get the values of a pixel before its tile arrives (0, depth
    +inf = miss, normal 0) only when an incomplete frame is read."""

    _lock = threading.Lock()
    _free: dict[tuple[int, int, int], list["_Planes"]] = {}
    # kept per resolution: a few frames are in flight at once (fresh planes cost ~30 ms of
    # page faults at 640x480, more than the frame's decode and filter together)
    POOL = 4

    def __init__(self, width: int, height: int, n: int, pad: int | None = None):
        self.key = (width, height, n)
        self.width, self.height, self.n = width, height, n
        self.pad = _widest_pad(n) if pad is None else pad
        K, q = n * n, self.pad
        self.sw, self.sh = -(-width // n), -(-height // n)
        SH, SW = self.sh + 2 * q, self.sw + 2 * q
        self.vals = np.zeros((K, 12, SH, SW), np.float32)
        self.vals[:, 9:12] = NO_LOBE
        self.nrm = np.zeros((K, 3, SH, SW), np.float32)
        self.depth = np.full((K, SH, SW), np.inf, np.float32)
        self.covered = 0  # pixels written since acquire
        self.lobes = False  # a tile since acquire held split lobes

    def interior(self, a: np.ndarray) -> np.ndarray:
        """The view of a plane (or planes: the last two axes) without its border."""
        q = self.pad
        return a[..., q:q + self.sh, q:q + self.sw]

    @classmethod
    def acquire(cls, width: int, height: int, n: int) -> "_Planes":
        with cls._lock:
            free = cls._free.get((width, height, n))
            pl = free.pop() if free else None
        if pl is None:
            pl = cls(width, height, n)
        pl.covered = 0
        pl.lobes = False
        return pl

    @classmethod
    def release(cls, pl: "_Planes") -> None:
        with cls._lock:
            if len(cls._free) > 4 and pl.key not in cls._free:  # resolutions come and go
                cls._free.clear()
            lst = cls._free.setdefault(pl.key, [])
            if len(lst) < cls.POOL:
                lst.append(pl)

    def fill_missing(self, tiles) -> None:
        """Give every pixel none of ``tiles`` wrote its before-arrival values (incomplete
        frames only: a complete frame has written every pixel)."""
        if self.covered >= self.width * self.height:
            return
        missing = np.ones((self.n * self.n, self.sh, self.sw), bool)
        for t in tiles:
            _, _, h, w = tile_slices(t, self.n, self.width, self.height)
            missing[t.k, t.sy0:t.sy0 + h, t.sx0:t.sx0 + w] = False
        for k in range(len(missing)):
            vals, nrm = self.interior(self.vals[k]), self.interior(self.nrm[k])
            vals[:9, missing[k]] = 0.0
            vals[9:, missing[k]] = NO_LOBE
            nrm[:, missing[k]] = 0.0
        self.interior(self.depth)[missing] = np.inf
        self.covered = self.width * self.height

    def image(self, tiles, window: int, w: tuple[float, float], p: dict,
              guide: EdgeStoppingGuide | None = None) -> np.ndarray:
        self.fill_missing(tiles)
        return self.finish(window, w, p, guide)

    def finish(self, window: int, w: tuple[float, float], p: dict,
               guide: EdgeStoppingGuide | None = None) -> np.ndarray:
        """The image (H, W, 3): discontinuity filter (when a weight of ``w`` — the irradiance's,
        the lobes' — is > 0 and the window > 1; with the ``guide``'s edge stopping once it has
        learnt enough), the fading blends (weights < 1) and the compose, one compiled pass per
        block of sub-image rows on ``master.parallel``'s threads (blocks write disjoint image
        rows); then the frame's raw irradiance goes to the guide."""
        use_filter = max(w) > 0.0 and window > 1
        lo, hi = _window_reach(window)
        if use_filter and plane_pad(lo, hi, self.n) > self.pad:  # wider than the parameters allow
            wide = _Planes(self.width, self.height, self.n, plane_pad(lo, hi, self.n))
            for a, b in ((wide.vals, self.vals), (wide.nrm, self.nrm), (wide.depth, self.depth)):
                wide.interior(a)[...] = self.interior(b)
            wide.lobes = self.lobes
            return wide.finish(window, w, p, guide)
        dt, nt = float(p["depth_threshold"]), float(p["normal_threshold"])
        flat = lambda a: a.reshape(a.shape[:-2] + (-1,))  # noqa: E731 - a view: the planes are contiguous
        vals, nrm, depth = flat(self.vals), flat(self.nrm), flat(self.depth)
        H, W, n, q, SW = self.height, self.width, self.n, self.pad, self.sw + 2 * self.pad
        img = np.empty((H, W, 3), np.float32)
        k = float(p.get("filter_guide", 0.0))
        layout = (n, q, SW, n * n, self.vals.shape[2] * SW)  # the guide's, cell for cell the planes'
        gm, gt = _NO_GUIDE, _NO_GUIDE
        s1, s2, wm, wt = _NO_SUMS, _NO_SUMS, _NO_GUIDE, _NO_GUIDE
        sh, sh2 = _NO_SHARES, _NO_SUMS
        if guide is not None:
            s1, s2 = guide.learner((H, W), layout)
            gm, gt = (use_filter and guide.planes(k, (H, W))) or (_NO_GUIDE, _NO_GUIDE)
            wm, wt = guide.next_planes()
            c = float(p.get("filter_select", 0.0))
            if c > 0 and not p.get("moving_camera", False):  # (a moving view's frame is shown once)
                sh, sh2 = guide.shares(c, max(lo, hi))
        m = 0.0 if guide is None else guide.count + 1.0
        run_stripes(self.sh, W * n, lambda y0, y1: finish_sub(vals, nrm, depth, SW, n, q, H, W, y0, y1, use_filter,
                                                              lo, hi, dt, nt, float(w[0]), float(w[1]), self.lobes,
                                                              gm.size > 0, gm, gt, s1, s2, m, k, wm, wt, img,
                                                              sh, sh2))
        if guide is not None:
            guide.learnt(k, (wm, wt))
        return img

    def to_buffers(self, b: dict[str, np.ndarray], tiles) -> None:
        from igi.master.kernels.discontinuity import gather_rows

        self.fill_missing(tiles)
        H, W = self.height, self.width
        vals = np.empty((12, H, W), np.float32)
        nrm = np.empty((3, H, W), np.float32)
        gather_rows(self.vals, self.nrm, self.depth, self.n, self.pad, W, 0, H, vals, nrm, b["depth"])
        for s, name in enumerate(VALUE_NAMES):
            np.copyto(b[name], vals[3 * s:3 * s + 3].transpose(1, 2, 0))
        np.copyto(b["normal"], nrm.transpose(1, 2, 0))


def _widest_pad(n: int) -> int:
    """The border the widest window the parameters allow needs at interleave ``n``."""
    from igi.common.params import PARAM_BY_NAME

    widest = int(max(PARAM_BY_NAME["filter_window"].max, n))  # -1 (the default) is the interleave size
    return plane_pad(*_window_reach(widest), n)


def _empty_buffers(width: int, height: int) -> dict[str, np.ndarray]:
    return {
        "reflectance": np.zeros((height, width, 3), np.float32),
        "irradiance": np.zeros((height, width, 3), np.float32),
        "unfiltered": np.zeros((height, width, 3), np.float32),
        "lobe": np.full((height, width, 3), NO_LOBE, np.float32),
        "depth": np.full((height, width), np.inf, np.float32),
        "normal": np.zeros((height, width, 3), np.float32),
    }


def filter_weight(params: dict, index: int) -> float:
    """Share of the filtered irradiance in accumulation frame ``index`` (see FrameAssembler.image)."""
    t = int(params.get("filter_frames", -1))
    if t < 0 or index < t or not params.get("consistent", False) or not params.get("accumulate", True):
        return 1.0
    return t / (index + 1.0)


def _asdict(params) -> dict:
    from igi.common.params import params_to_dict

    return params_to_dict(params)
