"""The compiled composition of a task's buffers (worker.kernels.tile_buffers) equals the numpy
code it replaced in worker.renderer.render_tile, bit for bit: several end points per pixel
(glass splits), main points and secondary ones, NaN/±Inf values, pixels no end point reaches,
no end points at all."""
from __future__ import annotations

import numpy as np

from igi.worker.kernels import tile_buffers


def _numpy_compose(pixel, main, albedo, throughput, irr, unf, p):
    """render_tile's numpy form (before the kernel)."""
    refl = np.zeros((p, 3))
    irr_buf = np.zeros((p, 3))
    unf = unf.copy()
    refl[pixel[main]] = albedo[main] * throughput[main]
    irr_buf[pixel[main]] = irr[main]
    sec = ~main
    if sec.any():
        np.add.at(unf, pixel[sec], throughput[sec] * albedo[sec] * irr[sec])
    return refl, irr_buf, unf


def test_the_compiled_composition_equals_the_numpy_one_bit_for_bit():
    rng = np.random.default_rng(4)
    p = 500
    pixel = rng.integers(0, p, 1500)
    main = np.zeros(1500, bool)
    firsts = np.unique(pixel, return_index=True)[1]  # at most one main end point a pixel
    main[firsts[rng.random(len(firsts)) < 0.8]] = True
    albedo, throughput, irr = (rng.random((1500, 3)) * 3 for _ in range(3))
    irr[::97] = np.nan
    irr[5::101, 1] = np.inf
    throughput[7::89] = 1e-300
    unf0 = rng.random((p, 3))
    refl, irr_buf, unf = np.zeros((p, 3)), np.zeros((p, 3)), unf0.copy()
    tile_buffers.compose(pixel, main, albedo, throughput, irr, refl, irr_buf, unf)
    r2, i2, u2 = _numpy_compose(pixel, main, albedo, throughput, irr, unf0, p)
    np.testing.assert_array_equal(refl, r2)
    np.testing.assert_array_equal(irr_buf, i2)
    np.testing.assert_array_equal(unf, u2)
    assert np.isnan(unf).any() and (~main).sum() > 100  # hostile and secondary rows were exercised


def test_no_end_points_leave_the_buffers_as_they_were():
    unf = np.ones((4, 3))
    refl, irr_buf = np.zeros((4, 3)), np.zeros((4, 3))
    z3 = np.zeros((0, 3))
    tile_buffers.compose(np.zeros(0, np.int64), np.zeros(0, bool), z3, z3, z3, refl, irr_buf, unf)
    assert not refl.any() and not irr_buf.any() and np.all(unf == 1)


def test_filter_lobes_moves_a_layer_pixels_unfiltered_radiance_to_its_lobe_keeping_its_radiance():
    """filter_lobes: at a pixel whose main end point is flagged (a split plastic's layer) the
    unfiltered radiance moves to the pixel's lobe whatever its reflectance (lobe + unfiltered
    unchanged, unfiltered 0); unflagged pixels keep theirs and no lobe (NO_LOBE)."""
    from igi.common.frame import NO_LOBE

    rng = np.random.default_rng(5)
    p = 400
    pixel = rng.permutation(p)  # one main end point a pixel
    carry = rng.random(p) < 0.5
    unf = rng.random((p, 3)) * 2
    lobe = np.full((p, 3), NO_LOBE)
    unf2 = unf.copy()
    tile_buffers.filter_lobes(pixel, carry, unf2, lobe)
    moved = np.zeros(p, bool)
    moved[pixel[carry]] = True
    assert moved.sum() > 100 and (~moved).sum() > 100  # both kinds of pixel exercised
    np.testing.assert_array_equal(lobe[moved], unf[moved])
    assert not unf2[moved].any()
    np.testing.assert_array_equal(unf2[~moved], unf[~moved])
    assert np.all(lobe[~moved] == NO_LOBE)
