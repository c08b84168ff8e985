"""Load the master's compiled kernels before its first frame (issue 16: start-up).

The master decodes tiles (common.kernels.wire_decode), filters and composes frames
(``discontinuity``) and accumulates them (``accumulate``, ``filter_selection``) with numba kernels. The first call of
each in a process loads it from numba's disk cache, and the first of all builds numba's
context: ~0.5 s that used to land inside the first frame a user waits for, after the workers'
first tiles had arrived. :func:`warm_up_master` runs that path once on a tiny synthetic frame;
the broker starts it on a thread of its own as it starts, while the workers start (seconds).

A process must not exit while that thread is inside LLVM: LLVM's static destructors then run under
it and abort the process (a one-frame ``igi render`` on a cold cache did, after writing its image).
So the warm-up stops between steps once asked, and an exit handler asks and waits for it.
"""
from __future__ import annotations

import atexit
import logging
import threading
import time

import numpy as np

from igi.common.gc_policy import settle_long_lived

log = logging.getLogger(__name__)

_SIZE, _N = 10, 5  # a tiny frame: every sub-image of a 5x5 interleave, 2x2 pixels each


def _tile_buffers(count: int, rng: np.random.Generator):
    from igi.common.frame import TileBuffers

    normal = rng.normal(size=(count, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    f = lambda: rng.random((count, 3), dtype=np.float32)  # noqa: E731
    return TileBuffers(reflectance=f(), irradiance=f(), unfiltered=f(),
                       depth=(1.0 + rng.random(count)).astype(np.float32), normal=normal)


class _Stopped(Exception):
    """The process is exiting: the warm-up leaves the kernels it has not loaded yet."""


def warm_up_master(stop: threading.Event | None = None) -> float:
    """Decode, merge, filter, compose and accumulate one tiny frame (the wire path the broker
    takes), at the first frame's filter weight and at a faded one; returns the seconds taken.
    Once ``stop`` is set it raises :class:`_Stopped` at the next step (each may compile)."""
    def step() -> None:
        if stop is not None and stop.is_set():
            raise _Stopped

    t0 = time.perf_counter()
    from igi.common.codec import encode
    from igi.common.params import make_params, params_to_dict
    from igi.master.accumulation import Accumulator
    from igi.master.edge_stopping import MIN_FRAMES, EdgeStoppingGuide
    from igi.master.frame_assembly import FrameAssembler, task_tiles, tile_pixel_count

    params = params_to_dict(make_params(interleave=_N))
    rng = np.random.default_rng(0)
    frame = FrameAssembler(_SIZE, _SIZE, _N)
    for tile in task_tiles(_SIZE, _SIZE, _N):
        step()
        frame.add_wire(tile, encode(_tile_buffers(tile_pixel_count(tile, _N, _SIZE, _SIZE), rng)))
    acc = Accumulator()
    guide = EdgeStoppingGuide().track("warm-up")
    for index in range(MIN_FRAMES + 1):  # learning, then guided
        step()
        acc.add(frame.image(params, index, guide))
    step()
    acc.add(frame.image(params, 10 * int(params["filter_frames"])))  # past the fade
    step()
    acc.mean(guide)  # with the filter's shares weighed (master.filter_selection)
    return time.perf_counter() - t0


_started: threading.Thread | None = None  # once per process: the kernels stay loaded
_lock = threading.Lock()
_stop = threading.Event()
_EXIT_WAIT_S = 120.0  # one step's cold compiles (the first frame's filter and compose) on a loaded 2-core box


def _stop_at_exit() -> None:
    """atexit: daemon threads still run here, before LLVM's destructors; the warm-up finishes
    the step it is in and returns."""
    _stop.set()
    if _started is not None:
        _started.join(_EXIT_WAIT_S)
        if _started.is_alive():
            log.warning("master warm-up still compiling after %.0f s at exit", _EXIT_WAIT_S)


atexit.register(_stop_at_exit)


def warm_up_master_in_background() -> threading.Thread:
    """:func:`warm_up_master` on a daemon thread, once per process (later brokers get the same
    thread); a failure is logged, never raised: the first frame then loads the kernels itself."""
    global _started

    def run() -> None:
        try:
            log.debug("master kernels ready in %.2f s", warm_up_master(_stop))
            settle_long_lived()  # the kernels' objects out of the frames' full collections
        except _Stopped:
            log.debug("master warm-up stopped: the process is exiting")
        except Exception as e:  # noqa: BLE001 - only an optimization
            log.info("master warm-up failed (%s: %s); the first frame loads the kernels", type(e).__name__, e)

    with _lock:
        if _started is None:
            _started = threading.Thread(target=run, name="igi-master-warm", daemon=True)
            _started.start()
        return _started
