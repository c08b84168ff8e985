"""Progressive accumulation of frames while nothing moves (docs/architecture.md, paper §4.4, §5.2).

:class:`Accumulator` keeps float64 running sums (a float32 image added 1e6 times drifts by
~1e-10 relative, far below float16 wire quantization) and two independent halves — the even
and the odd frames — whose difference estimates the remaining error of the mean without a
reference (issue 11). It resets whenever the accumulation key changes: camera, resolution,
scene version or any parameter except the seed.

:func:`sequence_spec` is THE frame sequencing shared by the broker and ``render_local``:
frame ``i`` after a reset uses seed ``base_seed + i`` (a new independent realization of the
VPL/photon sets) and sub-pixel jitter ``halton(i)`` (pixel centre for i = 0) so accumulated
frames also anti-alias (the references use a box pixel filter). When only the camera moves the
index restarts at 0 after the reset, so the seed — and the workers' cached sets — stay the same.
"""
from __future__ import annotations

import numpy as np

from igi.common.camera import radical_inverse
from igi.common.frame import FrameSpec, frame_seed
from igi.master.filter_selection import select
from igi.master.kernels.accumulate import add_frame
from igi.master.kernels.accumulate import mean as mean_kernel


def jitter_for(index: int) -> tuple[float, float]:
    """Sub-pixel position of accumulation frame ``index``: centre, then Halton (2, 3)."""
    if index <= 0:
        return (0.5, 0.5)
    return (radical_inverse(index, 2), radical_inverse(index, 3))


def sequence_spec(frame: int, index: int, camera_to_world, fov_x: float, width: int, height: int,
                  params: dict, scene_version: int = 0) -> FrameSpec:
    """FrameSpec of frame number ``frame``, the ``index``-th since the last accumulation reset.

    Without accumulation every frame is index 0 (same seed, no jitter: a static image stays
    static); with it, seed and jitter advance with the index.
    """
    cam = tuple(float(x) for x in np.asarray(camera_to_world, np.float64).reshape(16))
    if not params.get("accumulate", True):
        index = 0
    seed = frame_seed(params.get("seed", 0), index)
    return FrameSpec(frame=frame, seed=seed, camera_to_world=cam, fov_x=float(fov_x), width=width,
                     height=height, params=dict(params), scene_version=scene_version,
                     jitter=jitter_for(index))


_PER_FRAME_PARAMS = ("seed", "consistent_first_frame", "moving_camera")


def accumulation_key(spec: FrameSpec) -> tuple:
    """What must stay equal for frames to be averaged: everything but seed, jitter, frame and
    whether the frame was a moving camera's (the stream's first frame: no consistent estimators,
    fewer indirect VPLs — an estimate of the same image, so it joins the average)."""
    params = tuple(sorted((k, v) for k, v in spec.params.items() if k not in _PER_FRAME_PARAMS))
    return (spec.camera_to_world, spec.fov_x, spec.width, spec.height, spec.scene_version, params)


class Accumulator:
    """Running mean of frames, reset on any change of its key."""

    def __init__(self):
        self.key = None
        self.reset()

    def reset(self) -> None:
        self._sum = None
        self._halves = [None, None]
        self._counts = [0, 0]
        self.count = 0

    def add(self, image: np.ndarray, key=None) -> int:
        """Add one frame (H, W, C); a ``key`` different from the last one resets first.
        Returns the number of frames in the mean."""
        img = np.asarray(image)
        if key != self.key or (self._sum is not None and self._sum.shape != img.shape):
            self.reset()
            self.key = key
        if self._sum is None:
            self._sum = np.zeros(img.shape, np.float64)
            self._halves = [np.zeros(img.shape, np.float64), np.zeros(img.shape, np.float64)]
        half = self.count % 2
        if img.dtype == np.float32 and img.flags.c_contiguous:
            # one compiled pass for both float64 sums (the same additions as below)
            add_frame(self._sum.reshape(-1), self._halves[half].reshape(-1), img.reshape(-1))
        else:
            self._sum += img
            self._halves[half] += img
        self._counts[half] += 1
        self.count += 1
        return self.count

    def mean(self, guide=None) -> np.ndarray | None:
        """The accumulated image (float32), None before the first frame. ``guide``: the frames'
        ``master.edge_stopping.EdgeStoppingGuide``; each pixel then keeps the filter's share of the
        mean only as far as its measured bias allows (``master.filter_selection``)."""
        if self._sum is None or self.count == 0:
            return None
        out = np.empty(self._sum.shape, np.float32)
        mean_kernel(self._sum.reshape(-1), self.count, out.reshape(-1))  # float32(sum / count)
        if guide is not None:
            return select(out, guide.shares_learnt())
        return out

    def halves(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Means of the even and the odd frames (independent realizations), None before 2 frames."""
        if self._counts[0] == 0 or self._counts[1] == 0:
            return None
        return (self._halves[0] / self._counts[0], self._halves[1] / self._counts[1])

    def relative_error(self) -> float | None:
        """Estimated relMSE of the mean (the relMSE of common/metrics.py, docs/accuracy.md, with the mean as reference):
        for two independent halves A, B of equal size, E[(A-B)²] = 2·Var(half) and
        Var(mean) = Var(half)/2, so relMSE(mean) ≈ mean((A-B)²/(mean²+0.01)) / 4."""
        h = self.halves()
        if h is None:
            return None
        a, b = h
        m = self._sum / self.count
        return float(np.mean((a - b) ** 2 / (m * m + 0.01)) / 4.0)
