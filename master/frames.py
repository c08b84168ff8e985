"""What the frame loop (``master/frame_loop.py``) keeps per frame and per task, and how a frame
ends: a :class:`FrameResult`, or :class:`FrameCancelled` / :class:`FrameFailed`.

A :class:`Frame` is a :class:`FrameSpec` cut into tasks (:class:`Task`: a tile of one interleaved
sub-image each), their assembler and the Future its submitter waits on. A task remembers its
current assignment (worker, epoch, when sent) and the workers it should avoid (issue 20).
"""
from __future__ import annotations

import concurrent.futures as cf
import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from igi.common.frame import FrameSpec, Tile, accumulation_index
from igi.common.params import make_params, params_to_dict

from . import scheduler
from .frame_assembly import FrameAssembler


class FrameCancelled(Exception):
    """The frame was dropped before completion (scene edit, new camera in streaming, stop)."""


class FrameFailed(RuntimeError):
    """A task of the frame failed on the workers repeatedly."""


@dataclass
class FrameResult:
    """A completed frame: its spec and the assembled full-frame buffers (not yet filtered)."""

    spec: FrameSpec
    assembler: FrameAssembler
    bytes: int  # wire bytes of the accepted RESULT payloads
    tasks: int
    started: float  # time.monotonic() at submission
    finished: float

    @property
    def buffers(self) -> dict[str, np.ndarray]:
        return self.assembler.buffers

    def image(self, guide=None) -> np.ndarray:
        """Filtered + composed image (discontinuity buffer), computed in the caller's thread;
        ``guide``: the accumulation's ``master.edge_stopping.EdgeStoppingGuide``, if any."""
        return self.assembler.image(self.spec.params, accumulation_index(self.spec), guide)


@dataclass
class Task:
    frame: int
    task: int
    tile: Tile
    set_key: tuple
    epoch: int = 0
    worker: bytes | None = None
    sent: float = 0.0
    pixels: int = 0  # (set when sent: what its timeout scales with)
    builds_set: bool = False  # sent to a worker that did not hold its set
    failures: int = 0
    avoid: frozenset = frozenset()  # workers this task failed or timed out on (issue 20)
    trusted_only: bool = False  # lost by a worker that never delivered: to trusted workers first
    pending: Any = None  # its scheduler.PendingTask (rebuilt when ``avoid`` changes)

    def as_pending(self, key) -> scheduler.PendingTask:
        if self.pending is None:
            self.pending = scheduler.PendingTask(key, self.set_key, self.avoid, self.trusted_only)
        return self.pending

    def avoid_worker(self, ident: bytes) -> None:
        self.avoid = self.avoid | {ident}
        self.pending = None

    def lost_by(self, ident: bytes, trusted: bool) -> None:
        """The worker ``ident`` gave this task back without a result (left, timed out, failed)."""
        self.avoid_worker(ident)
        if not trusted:
            self.trusted_only = True


@dataclass
class Frame:
    spec: FrameSpec
    assembler: FrameAssembler
    future: cf.Future
    tasks: dict  # task id -> Task (open tasks only)
    total: int
    started: float
    bytes: int = 0
    stream_gen: int | None = None  # generation of the stream view, None for one-shot frames


def params_dict(params) -> dict:
    """The full parameter dict of ``params``: a Params, a dict of overrides or None (defaults)."""
    if params is None:
        return params_to_dict(make_params())
    if isinstance(params, dict):
        return params_to_dict(make_params(**params))
    if dataclasses.is_dataclass(params):
        return params_to_dict(params)
    raise TypeError("params must be a Params, a dict of overrides or None")
