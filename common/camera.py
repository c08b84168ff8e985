"""Mitsuba 3's perspective camera, so that pixel (i, j) of igi and of Mitsuba see the same point.

Mitsuba's ``camera_to_sample = scale(-0.5, -0.5·aspect, 1) · translate(-1, -1/aspect, 0) ·
perspective(fov_x)``. Inverting it, film position (sx, sy) ∈ [0,1]² (sx right, sy down) maps
to the camera-space direction ((1 - 2 sx)·tan(fov_x/2), (1 - 2 sy)·tan(fov_x/2)/aspect, 1),
camera +x being the image's left and +y its top. Pixel (i, j) covers
sx ∈ [i/W, (i+1)/W), sy ∈ [j/H, (j+1)/H).
"""
from __future__ import annotations

import functools

import numpy as np

from . import reconstruction_filter as rf
from .kernels import camera_rays as kc
from .scene import Camera, Scene


def camera_rays(to_world: np.ndarray, fov_x: float, width: int, height: int,
                px: np.ndarray, py: np.ndarray, jitter: np.ndarray | tuple = (0.5, 0.5),
                lens: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World-space origins and unit directions through pixels (px, py) at sub-pixel ``jitter``.

    ``jitter`` is (2,) or (N, 2) sub-pixel positions from the pixel's corner, (0.5, 0.5) its centre:
    in [0, 1)² for the pixel's box, up to a reconstruction filter's radius beyond it
    (:func:`frame_jitter`). ``lens``: Mitsuba's
    thin lens, (aperture radius, focus distance, (N, 2) numbers in [0, 1)² for the aperture):
    each ray leaves its point of the aperture (concentric disk) toward where the pinhole ray
    through its pixel meets the plane in focus, as Mitsuba's ``thinlens`` sensor traces it.
    """
    m = np.asarray(to_world, np.float64).reshape(4, 4)
    jit = np.asarray(jitter, np.float64)
    px = np.ascontiguousarray(px, np.int64).ravel()
    py = np.ascontiguousarray(py, np.int64).ravel()
    per_pixel = jit.ndim == 2
    d_cam = np.empty((len(px), 3))
    kc.film_directions(px, py, np.ascontiguousarray(jit.reshape(-1, 2)), per_pixel, float(width), float(height),
                       float(np.tan(np.radians(fov_x) / 2)), d_cam)
    o = np.broadcast_to(m[:3, 3], d_cam.shape).copy()
    if lens is not None and lens[0] > 0:
        radius, focus, u = lens
        from .microfacet import square_to_uniform_disk_concentric  # (scipy: only where a lens is)

        a = radius * np.column_stack(square_to_uniform_disk_concentric(np.asarray(u, np.float64).reshape(-1, 2)))
        d_cam *= focus  # the point in focus: d_cam has z = 1
        d_cam[:, :2] -= a
        o += a @ m[:3, :2].T
    d = d_cam @ m[:3, :3].T
    kc.normalize_rows(d)
    return o, d


def radical_inverse(i: int, base: int) -> float:
    """The ``base``-ary digits of i mirrored about the point: the i-th point of van der Corput's
    sequence (Halton's in that base)."""
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def lens_jitter(index: int, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """(N, 2) numbers for the thin lens's aperture of pixels (px, py) in accumulation frame
    ``index``: Halton's bases (5, 7) over the frames (the sub-pixel jitter takes 2 and 3), each
    pixel's rotation of them a point of :func:`pixel_tile` read at another place of the tile, so
    a pixel's aperture samples are stratified over the frames and an 8 x 8 block's within a
    frame (one in each 1/64 along either axis)."""
    px = np.ascontiguousarray(px, np.int64).ravel()
    py = np.ascontiguousarray(py, np.int64).ravel()
    rot = pixel_tile()[(py + 3) % 8, (px + 5) % 8][:, ::-1]
    return np.mod(rot + np.array([radical_inverse(index, 5), radical_inverse(index, 7)]), 1.0)


@functools.cache
def pixel_tile() -> np.ndarray:
    """(8, 8, 2) sub-pixel offsets of an 8 x 8 pixel tile: the first 64 points of the 2-D Sobol
    sequence laid out in Morton order, so every aligned 2 x 2, 4 x 4 and 8 x 8 block of pixels
    holds an aligned run of 4, 16 or 64 points — a (0, m, 2)-net, one point in each of the
    block's elementary intervals. Built on first use: only workers need it, and scipy.stats
    would add ~0.4 s to the import of every process that reads a camera."""
    from scipy.stats import qmc

    pts = qmc.Sobol(2, scramble=False).random_base2(6)
    tile = np.empty((8, 8, 2))
    for y in range(8):
        for x in range(8):
            m = 0
            for bit in range(3):
                m |= ((x >> bit) & 1) << (2 * bit) | ((y >> bit) & 1) << (2 * bit + 1)
            tile[y, x] = pts[m]
    tile.flags.writeable = False  # shared by every call
    return tile


def pixel_jitter(jitter: tuple, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """(N, 2) sub-pixel positions of pixels (px, py) in an accumulated frame: the frame's
    ``jitter`` point (master.accumulation's Halton sequence over frames) shifted by the pixel's
    offset in :func:`pixel_tile`, modulo 1 — a per-pixel Cranley–Patterson rotation.

    With one point for the whole frame, every pixel along an edge samples the same sub-pixel
    position: their errors are equal, so no block of pixels averages them (a thin sliver of a
    bright light across a pixel row stays missing until the sequence happens to land in it).
    Rotated per pixel, each pixel still walks a stratified sequence over the frames, and the
    pixels of a block sample a stratified set of positions within each frame (interleaved
    sampling of the pixel area, Keller & Heidrich 2001). The same on every worker."""
    px = np.ascontiguousarray(px, np.int64).ravel()
    out = np.empty((len(px), 2))
    jx, jy = np.asarray(jitter, np.float64)
    kc.rotated_jitter(pixel_tile(), float(jx), float(jy), px, np.ascontiguousarray(py, np.int64).ravel(), out)
    return out


def frame_jitter(jitter: tuple, accumulated: bool, px: np.ndarray, py: np.ndarray, camera: Camera, width: int,
                 height: int) -> np.ndarray | tuple:
    """Sub-pixel positions of a frame's eye rays through pixels (px, py) of a ``width`` x
    ``height`` film: the frame's ``jitter`` point for every pixel on the first frame after a
    reset (the pixel centres; within a filter's radius of the film's edge, the median of the
    filter cut there), each pixel's rotation of it on accumulated frames (:func:`pixel_jitter`) —
    then drawn from the film's reconstruction filter (common.reconstruction_filter; the pixel's
    own box leaves them as they are)."""
    jit = pixel_jitter(jitter, px, py) if accumulated else jitter
    if rf.is_identity(camera.rfilter, camera.rfilter_params):
        return jit
    return rf.filtered_jitter(camera.rfilter, camera.rfilter_params, jit, np.ravel(px), np.ravel(py), width, height)


def rays_for_camera(cam: Camera, px: np.ndarray, py: np.ndarray, jitter=(0.5, 0.5)):
    return camera_rays(cam.to_world, cam.fov_x, cam.width, cam.height, px, py, jitter)


def look_at(origin, target, up) -> np.ndarray:
    """Mitsuba's lookat transform (columns: left, up, forward, origin); see common.transform."""
    from .transform import look_at as _look_at

    return _look_at(origin, target, up)


def resolve_camera(scene: Scene, camera=None, width: int | None = None,
                   height: int | None = None) -> tuple[tuple, float, int, int]:
    """(camera_to_world as 16 floats, fov_x, width, height) from the scene's camera, overridden
    by ``camera`` — a :class:`Camera`, a 4×4 / 16-float to_world matrix, or
    ``(to_world, fov_x)`` — and an explicit resolution. Width/height given alone keep the
    camera's aspect ratio for the other one."""
    cam = scene.camera
    to_world, fov_x = cam.to_world, cam.fov_x
    cw, ch = cam.width, cam.height
    if isinstance(camera, Camera):
        to_world, fov_x, cw, ch = camera.to_world, camera.fov_x, camera.width, camera.height
    elif camera is not None:
        if isinstance(camera, tuple) and len(camera) == 2 and np.size(camera[0]) == 16:
            to_world, fov_x = camera
        else:
            to_world = camera
    m = np.asarray(to_world, np.float64).reshape(16)
    if width is None and height is None:
        width, height = cw, ch
    elif width is None:
        width = max(1, round(height * cw / ch))
    elif height is None:
        height = max(1, round(width * ch / cw))
    return tuple(float(x) for x in m), float(fov_x), int(width), int(height)
