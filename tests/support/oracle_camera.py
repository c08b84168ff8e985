"""The numpy forms of common.camera's primary rays and per-pixel jitter (before
common.kernels.camera_rays): the oracles of tests/common/test_camera.py."""
from __future__ import annotations

import numpy as np

from igi.common.camera import pixel_tile


def camera_rays_numpy(to_world, fov_x, width, height, px, py, jitter=(0.5, 0.5)):
    m = np.asarray(to_world, np.float64).reshape(4, 4)
    jit = np.asarray(jitter, np.float64)
    sx = (px + jit[..., 0]) / width
    sy = (py + jit[..., 1]) / height
    aspect = width / height
    t = np.tan(np.radians(fov_x) / 2)
    d_cam = np.stack([(1 - 2 * sx) * t, (1 - 2 * sy) * t / aspect, np.ones_like(sx, dtype=np.float64)], axis=-1)
    d = d_cam @ m[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(m[:3, 3], d.shape).copy(), d


def pixel_jitter_numpy(jitter, px, py):
    x = pixel_tile()[np.asarray(py, np.int64) % 8, np.asarray(px, np.int64) % 8] + np.asarray(jitter, np.float64)
    return x - np.floor(x)
