"""An edge-stopping guide for the discontinuity buffer, from the frames accumulated so far.

The discontinuity buffer (paper §4.3) averages a pixel's irradiance with that of its
geometrically continuous neighbours: right where irradiance is smooth, a blur where it is not —
shadow edges, the thin dark gaps of a window frame, a room's corners — and that blur is a bias
accumulation does not remove (it only fades after ``filter_frames``). While the view stands
still, the frames already accumulated know where irradiance is not smooth: per pixel, the mean
and the sample variance of its raw (unfiltered) irradiance luminance over the m earlier frames.
A neighbour j of centre c then counts only where

    |mean_j - mean_c| <= k (s_j + s_c),    s = sqrt(variance / m), the mean's standard error,

``k`` = ``filter_guide``. Where the earlier frames cannot tell j from c (a difference within
their noise) the filter averages as before; where they show an edge their noise does not
explain, it stops. As frames pile up, s shrinks like 1/sqrt(m), and the filter keeps to
irradiance that is statistically the same: its bias shrinks with the noise. This is the
variance-guided edge-stopping of Dammertz et al. 2010 (edge-avoiding à-trous) and Schied et al.
2017 (SVGF), over a still camera's frames instead of reprojected ones.

Only *earlier* frames guide a frame: its own noise must not choose which of its neighbours
count (that would correlate the choice with the values averaged: a bias). A frame is guided
once MIN_FRAMES frames came before it (fewer give variances too noisy to trust), and only while
frames accumulate (without accumulation every frame is the same: no variance to learn).

A guided filter no longer fades after ``filter_frames`` (its blur shrinks with the noise, and
the averaging goes on); the test watches luminance only, so neighbours of equal luminance and
different colour stay averaged — a hue blur at coloured shadow edges that does not shrink.

Many small differences within the noise can still add up to a bias (a sun's terminator, a
penumbra's curvature): the guide therefore also sums each frame's filter share (filtered less raw
radiance) per pixel, and ``master.filter_selection`` takes back from the running mean whatever of
it the frames show to be bias.
"""
from __future__ import annotations

import numpy as np

MIN_FRAMES = 3  # earlier frames before a frame is guided


def image_layout(shape: tuple[int, int]) -> tuple:
    """The planes' ``layout`` (n, pad, SW, planes, cells) of a frame kept in image order."""
    H, W = shape
    return (1, 0, W, 1, H * W)


def _cells(layout: tuple, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(plane, cell) of each image pixel (H, W) in ``layout``: sub-image k = (y mod n)·n + x mod n,
    cell (y div n + pad)·SW + x div n + pad."""
    n, pad, SW = layout[:3]
    y, x = np.indices(shape)
    return (y % n) * n + x % n, (y // n + pad) * SW + x // n + pad


class EdgeStoppingGuide:
    """Per-pixel running sums of the raw irradiance luminance of one accumulation's frames.

    ``track(key)`` before each frame (a new key — camera, parameters, scene — starts over, as the
    :class:`~igi.master.accumulation.Accumulator` does). The frame assembler takes the
    :meth:`learner` sums, reads :meth:`planes` to filter a frame, and in the same compiled pass
    adds the frame's luminance to the sums and writes the next frame's guide into
    :meth:`next_planes` (then :meth:`learnt`). :meth:`sums`, :meth:`tolerances` and :meth:`add`
    are the same in image order, for tests and tools.

    Sums and guide are kept in the layout of the assembler's planes (``layout`` = (n, pad, SW,
    planes, cells), ``master.frame_assembly``): the pass reads and writes them cell by cell, in
    step with the frame's own planes. The pass that learns frame m writes the mean and k standard
    errors of frames 1..m, so the next frame reads them without a pass of its own; a guide for
    another ``k`` or for sums :meth:`add` changed is computed from the sums instead."""

    def __init__(self):
        self.key = None
        self.count = 0
        self.layout: tuple | None = None  # of the sums
        self._shape: tuple[int, int] | None = None  # the frames' (H, W)
        self._s1: np.ndarray | None = None
        self._s2: np.ndarray | None = None
        self._read: tuple | None = None  # (k, count, gm, gt): the guide of `count` frames
        self._share: np.ndarray | None = None  # the filter's share, (planes, 3, cells) float64 sums
        self._share2: np.ndarray | None = None  # and of its luminance squared (planes, cells)
        self._select: tuple = (0.0, 0)  # (c, window reach) the shares are weighed with
        self._shared = 0  # frames that added shares since the last reset
        self._sharing = False  # the frame being learnt adds shares
        self._scratch: np.ndarray | None = None  # the weighing's planes, kept: fresh ones cost page faults
        self._spare: tuple | None = None  # (gm, gt): buffers the next pass may write

    def track(self, key) -> "EdgeStoppingGuide":
        """Start over when ``key`` differs from the last frame's; returns self."""
        if key != self.key:
            self.key = key
            self.reset()
        return self

    def reset(self) -> None:
        """Forget the frames (the sums are zeroed in place: a moving view resets every frame)."""
        self.count = 0
        self._read = None
        if self._share is not None and (self._shared or self._sharing):  # (a moving view adds none)
            self._share.fill(0.0)
            self._share2.fill(0.0)
        self._shared, self._sharing = 0, False
        if self._s1 is not None:
            self._s1.fill(0.0)
            self._s2.fill(0.0)

    def learner(self, shape: tuple[int, int], layout: tuple) -> tuple[np.ndarray, np.ndarray]:
        """The sums ((planes, cells) float64 in ``layout``) a frame of ``shape`` (H, W) adds its
        luminance to (the frame assembler, in its compiled pass; then :meth:`learnt`); frames of
        another shape or layout start over."""
        if self._s1 is None or self._shape != tuple(shape) or self.layout != tuple(layout):
            self._shape, self.layout = tuple(shape), tuple(layout)
            self._s1 = np.zeros(layout[3:])
            self._s2 = np.zeros(layout[3:])
            self.count = 0
            self._read = self._spare = None
            self._share = self._share2 = None
            self._shared, self._sharing = 0, False
        return self._s1, self._s2

    def shares(self, c: float, reach: int) -> tuple[np.ndarray, np.ndarray]:
        """The sums (float64, in the :meth:`learner` layout: (planes, 3, cells) and (planes, cells))
        the frame :meth:`learner` was called for adds its filter share (RGB) and that share's
        luminance squared to (``master.filter_selection``; weighed with ``c`` over a window of
        ``reach``)."""
        if self._share is None:
            planes, cells = self.layout[3:]
            self._share = np.zeros((planes, 3, cells))
            self._share2 = np.zeros((planes, cells))
        self._select = (float(c), int(reach))
        self._sharing = True
        return self._share, self._share2

    def shares_learnt(self) -> tuple | None:
        """(share sums, luminance squares, layout, frames that added shares, c, reach, scratch planes
        for a shape, the frames' (H, W)) for ``master.filter_selection.select``; None when no frame
        added shares since the last reset."""
        if self._shared == 0:  # shares() since the last reset (it allocates them, with c > 0)
            return None
        return (self._share, self._share2, self.layout, self._shared, self._select[0], self._select[1], self._planes,
                self._shape)

    def _planes(self, shape: tuple[int, int]) -> np.ndarray:
        """Scratch planes (4, H, W) float32 for ``master.filter_selection``, kept between frames."""
        if self._scratch is None or self._scratch.shape[1:] != tuple(shape):
            self._scratch = np.empty((4,) + tuple(shape), np.float32)
        return self._scratch

    def _ready(self, k: float, shape: tuple[int, int]) -> bool:
        return k > 0 and self._s1 is not None and self._shape == tuple(shape) and self.count >= MIN_FRAMES

    def planes(self, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean, k·standard error) of the earlier frames in the sums' layout ((planes, cells)
        float32 each); None when ``k`` <= 0 (off), the frames had another shape or fewer than
        MIN_FRAMES were added. Read-only: a later pass may write the buffers they were."""
        if not self._ready(k, shape):
            return None
        r = self._read
        if r is None or r[0] != k or r[1] != self.count:
            from igi.master.kernels.discontinuity import guide_cells

            gm, gt = np.empty(self._s1.shape, np.float32), np.empty(self._s1.shape, np.float32)
            guide_cells(self._s1.ravel(), self._s2.ravel(), float(self.count), float(k), gm.ravel(), gt.ravel())
            self._read = r = (k, self.count, gm, gt)
        return r[2], r[3]

    def next_planes(self) -> tuple[np.ndarray, np.ndarray]:
        """Buffers (the sums' layout) a pass writes the guide of the frames so far plus its own
        into — never those :meth:`planes` returned; pass them to :meth:`learnt`."""
        spare, self._spare = self._spare, None
        if spare is None:
            spare = (np.zeros(self._s1.shape, np.float32), np.zeros(self._s1.shape, np.float32))
        return spare

    def learnt(self, k: float = 0.0, written: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """One more frame was added to the sums; ``written``: the :meth:`next_planes` buffers its
        pass filled with the guide of all frames so far (``k`` standard errors), or None."""
        self.count += 1
        self._shared += self._sharing
        self._sharing = False
        if written is None:
            return
        if self._read is not None:
            self._spare = (self._read[2], self._read[3])  # the older guide: the next pass writes it
        self._read = (k, self.count, written[0], written[1])

    def sums(self, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(luminance sums, sums of squares, frames) of the earlier frames in image order, (H, W)
        float64 copies; None where :meth:`planes` is."""
        if not self._ready(k, shape):
            return None
        at = _cells(self.layout, shape)
        return self._s1[at], self._s2[at], self.count

    def tolerances(self, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean, k·standard error) of the earlier frames' luminance, (H, W) float32 each, as the
        filter reads them; None where :meth:`planes` is."""
        planes = self.planes(k, shape)
        if planes is None:
            return None
        at = _cells(self.layout, shape)
        return planes[0][at], planes[1][at]

    def add(self, luminance: np.ndarray) -> None:
        """Add one frame's raw irradiance luminance (H, W) (non-finite values count as 0), in the
        sums' layout (image order if none yet)."""
        lum = np.nan_to_num(np.asarray(luminance, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        shape = lum.shape
        layout = self.layout if self._shape == shape else image_layout(shape)
        s1, s2 = self.learner(shape, layout)
        at = _cells(layout, shape)
        s1[at] += lum
        s2[at] += lum * lum
        self.learnt()
