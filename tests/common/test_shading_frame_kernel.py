"""The compiled shading-frame transforms (common.kernels.shading_frame behind
common.lights.to_local / to_world) equal the numpy formulation of Duff et al. 2017 they replaced,
round-trip, and stay orthonormal at the poles (n = ±z, the branch of the basis)."""
from __future__ import annotations

import numpy as np

from igi.common.lights import frame_from, to_local, to_world
from igi.common.scene import ROUGHDIELECTRIC, SPECULAR_KINDS, kind_in


def _numpy_local(w, n):
    s, t = frame_from(n)
    return np.stack([np.einsum("ij,ij->i", w, s), np.einsum("ij,ij->i", w, t), np.einsum("ij,ij->i", w, n)], axis=1)


def _normals(n, seed=0):
    g = np.random.default_rng(seed)
    nrm = g.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    nrm[:6] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0], [0, 0, -1 + 1e-16], [1e-9, 0, -1]]
    nrm[:6] /= np.linalg.norm(nrm[:6], axis=1)[:, None]
    return nrm


def test_to_local_and_to_world_equal_the_numpy_frames_and_round_trip():
    n = _normals(5000)
    w = np.random.default_rng(1).normal(size=(5000, 3))
    np.testing.assert_allclose(to_local(w, n), _numpy_local(w, n), rtol=0, atol=1e-14)
    s, t = frame_from(n)
    np.testing.assert_array_equal(to_world(w, n), w[:, 0:1] * s + w[:, 1:2] * t + w[:, 2:3] * n)
    np.testing.assert_allclose(to_world(to_local(w, n), n), w, atol=1e-12)
    # the local z axis is the normal; the frame is orthonormal everywhere
    np.testing.assert_allclose(to_world(np.tile([0.0, 0.0, 1.0], (5000, 1)), n), n, atol=1e-15)
    for axis in np.eye(3):
        np.testing.assert_allclose(np.linalg.norm(to_world(np.tile(axis, (5000, 1)), n), axis=1), 1.0, atol=1e-12)


def test_transforms_broadcast_one_normal_and_take_float32_and_empty_input():
    w = np.random.default_rng(2).normal(size=(7, 3)).astype(np.float32)
    one = np.array([0.0, 0.6, 0.8])
    np.testing.assert_allclose(to_local(w, one), _numpy_local(w.astype(np.float64), np.tile(one, (7, 1))),
                               atol=1e-12)
    assert to_local(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)
    assert to_world(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


def test_kind_in_is_isin_for_every_code_and_rejects_unknown_codes():
    codes = np.concatenate([np.arange(-3, 20), [-128, 127]]).astype(np.int8)
    for kinds in (SPECULAR_KINDS, (2, 6), (0,), ()):
        want = np.isin(codes, kinds) & (codes >= 0) & (codes <= ROUGHDIELECTRIC)
        np.testing.assert_array_equal(kind_in(codes, kinds), want)
        # codes of another integer type take the range-checked path (300: past a byte's table)
        wide = np.concatenate([codes.astype(np.int64), [300, -300]])
        np.testing.assert_array_equal(kind_in(wide, kinds), np.concatenate([want, [False, False]]))
