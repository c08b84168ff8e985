"""The in-process reference renderer: one process renders exactly the distributed path's tasks,
for ``igi render --workers 0``, tests and benchmarks.

:func:`render_local` calls ``Renderer.render_tile`` directly for every task of
:func:`master.frame_assembly.task_tiles`, frame specs from
:func:`master.accumulation.sequence_spec`, the same :class:`FrameAssembler` and
:class:`Accumulator` as the broker. With ``quantize=True`` (default) each tile's buffers also
make the wire round trip (``common.codec`` encode → decode), so the output is bit-identical to
what master + workers produce for the same scene, parameters and seeds.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from igi.common.camera import resolve_camera
from igi.common.malloc_policy import reuse_freed_blocks
from igi.common.params import make_params, params_to_dict
from igi.common.scene import Scene

from .accumulation import Accumulator, accumulation_key, sequence_spec
from .edge_stopping import EdgeStoppingGuide
from .frame_assembly import DEFAULT_TASK_PIXELS, FrameAssembler, task_tiles


def roundtrip(buffers, enabled: bool = True):
    """The buffers as the master receives them from the wire (codec encode → decode)."""
    if not enabled:
        return buffers
    from igi.common.codec import decode, encode

    return decode(encode(buffers), len(buffers))


def render_local(scene: Scene, params=None, frames: int = 1, camera=None,
                 on_frame: Callable[[int, np.ndarray], object] | None = None, *,
                 width: int | None = None, height: int | None = None, renderer=None,
                 task_pixels: int = DEFAULT_TASK_PIXELS, quantize: bool = True,
                 scene_version: int = 0,
                 on_plain_mean: Callable[[int, np.ndarray], object] | None = None) -> np.ndarray:
    """Render ``frames`` frames in this process and return the image (H, W, 3) float32, linear.

    ``params``: a Params, a dict of overrides, or None (defaults). With ``accumulate`` on the
    result is the mean of the frames (seeds params.seed, +1, …); off, the last frame (all
    frames are then identical). ``on_frame(i, image_so_far)`` is called after each frame;
    ``on_plain_mean(i, mean)`` before it with the plain running mean, without the filter
    selection's blend (``master.filter_selection``), for estimators that take the mean apart
    frame by frame (the CLI's noise estimate).
    ``renderer`` reuses an existing ``worker.renderer.Renderer`` for ``scene``.
    """
    reuse_freed_blocks()  # this process is master and worker: tile buffers stay in the heap
    if params is None:
        params = make_params()
    elif isinstance(params, dict):
        params = make_params(**params)
    pdict = params_to_dict(params)
    if renderer is None:
        from igi.worker.renderer import Renderer

        renderer = Renderer(scene, scene_version=scene_version)
    cam, fov_x, w, h = resolve_camera(scene, camera, width, height)
    n = params.interleave
    tiles = task_tiles(w, h, n, task_pixels)
    acc = Accumulator()
    guide = EdgeStoppingGuide()
    image = None
    for i in range(max(1, int(frames))):
        spec = sequence_spec(i, i, cam, fov_x, w, h, pdict, scene_version)
        asm = FrameAssembler(w, h, n)
        for tile in tiles:
            asm.add(tile, roundtrip(renderer.render_tile(spec, tile), quantize))
        key = accumulation_key(spec)
        frame_img = asm.image(pdict, i if params.accumulate else 0, guide.track(key))
        acc.add(frame_img, key)
        if on_plain_mean is not None:
            on_plain_mean(i, acc.mean())
        image = acc.mean(guide)
        if on_frame is not None:
            on_frame(i, image)
    return image
