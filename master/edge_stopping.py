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
"""
from __future__ import annotations

import numpy as np

MIN_FRAMES = 3  # earlier frames before a frame is guided


class EdgeStoppingGuide:
    """Per-pixel running sums of the raw irradiance luminance of one accumulation's frames.

    ``track(key)`` before each frame (a new key — camera, parameters, scene — starts over, as the
    :class:`~igi.master.accumulation.Accumulator` does); the frame assembler reads :meth:`planes`
    before filtering a frame and, in its compiled pass, adds the frame's luminance to the
    :meth:`learner` sums and writes the next frame's guide into :meth:`next_planes` (then
    :meth:`learnt`). :meth:`tolerances` and :meth:`add` are the same in numpy terms, for tests and
    tools.

    The guide a frame reads is kept in the layout of the assembler's planes (``layout``: a tuple
    the assembler names; the planes' shape is its last two entries): the pass that learns frame
    m writes the mean and k standard errors of frames 1..m there, so the next frame reads them
    without a pass of its own. Planes of another layout or ``k`` (or sums changed by :meth:`add`)
    are computed from the sums instead."""

    def __init__(self):
        self.key = None
        self.count = 0
        self._s1: np.ndarray | None = None
        self._s2: np.ndarray | None = None
        self._read: tuple | None = None  # (layout, k, count, gm, gt): the guide of `count` frames
        self._write: tuple | None = None  # (layout, gm, gt): the buffers the next pass writes

    def track(self, key) -> "EdgeStoppingGuide":
        """Start over when ``key`` differs from the last frame's; returns self."""
        if key != self.key:
            self.key = key
            self.reset()
        return self

    def reset(self) -> None:
        """Forget the frames (the sums are zeroed in place: a moving view resets every frame)."""
        self.count = 0
        if self._s1 is not None:
            self._s1.fill(0.0)
            self._s2.fill(0.0)

    def sums(self, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(luminance sums, sums of squares, frames) of the earlier frames, (H, W) float64; None
        when ``k`` <= 0 (off), the frames had another shape or fewer than MIN_FRAMES were added."""
        if k <= 0 or self._s1 is None or self._s1.shape != tuple(shape) or self.count < MIN_FRAMES:
            return None
        return self._s1, self._s2, self.count

    def tolerances(self, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean, k·standard error) of the earlier frames' luminance, (H, W) float32 each, as the
        filter reads them (``master.kernels.discontinuity.guide_planes`` in image order); None
        where :meth:`sums` is."""
        H, W = shape
        planes = self.planes(k, shape, (1, 0, W, 1, H * W))
        if planes is None:
            return None
        return planes[0].reshape(H, W).copy(), planes[1].reshape(H, W).copy()

    def planes(self, k: float, shape: tuple[int, int], layout: tuple) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean, k·standard error) of the earlier frames in the assembler's ``layout`` = (n, pad,
        SW, planes, cells): (planes, cells) float32 each, cells outside the image a miss (mean 0,
        tolerance +inf); None where :meth:`sums` is. Read-only: the next frame's pass may write
        the buffers these were."""
        s = self.sums(k, shape)
        if s is None:
            return None
        r = self._read
        if r is None or r[0] != layout or r[1] != k or r[2] != self.count:
            from igi.master.kernels.discontinuity import guide_planes

            n, pad, SW = layout[:3]
            gm, gt = np.zeros(layout[3:], np.float32), np.full(layout[3:], np.inf, np.float32)
            guide_planes(s[0], s[1], float(s[2]), float(k), n, pad, SW, gm, gt)
            self._read = r = (layout, k, self.count, gm, gt)
        return r[3], r[4]

    def next_planes(self, layout: tuple) -> tuple[np.ndarray, np.ndarray]:
        """The buffers a pass writes the guide of the frames so far plus its own into (see
        :meth:`planes`), not those :meth:`planes` returned; pass them to :meth:`learnt`."""
        w = self._write
        if w is None or w[0] != layout:
            shape = layout[3:]
            w = (layout, np.zeros(shape, np.float32), np.full(shape, np.inf, np.float32))  # outside: misses
        self._write = None
        return w[1], w[2]

    def learner(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The (H, W) float64 sums a frame's luminance is added to (the frame assembler adds it in
        its compiled pass, then calls :meth:`learnt`); frames of another shape start over."""
        if self._s1 is None or self._s1.shape != tuple(shape):
            self._s1 = np.zeros(shape)
            self._s2 = np.zeros(shape)
            self.count = 0
        return self._s1, self._s2

    def learnt(self, k: float = 0.0, layout: tuple | None = None, written=None) -> None:
        """One more frame was added to the :meth:`learner` sums; ``written``: the
        :meth:`next_planes` buffers its pass filled with the guide of all frames so far (mean and
        ``k`` standard errors, in ``layout``), or None."""
        self.count += 1
        if written is None:
            return
        old = self._read
        if old is not None and old[3] is not written[0]:
            self._write = (old[0], old[3], old[4])  # the older buffers: the next pass writes them
        self._read = (layout, k, self.count, written[0], written[1])

    def add(self, luminance: np.ndarray) -> None:
        """Add one frame's raw irradiance luminance (H, W) (non-finite values count as 0)."""
        lum = np.nan_to_num(np.asarray(luminance, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        s1, s2 = self.learner(lum.shape)
        s1 += lum
        s2 += lum * lum
        self.learnt()
