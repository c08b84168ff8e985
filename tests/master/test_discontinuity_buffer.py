import numpy as np
import pytest

from igi.master.discontinuity_buffer import compose, filter_irradiance, resolve_window, window_offsets


def _reference(irr, depth, normal, window, dt, nt):
    """Per-pixel loops straight from the definition (§4.3), for comparison."""
    H, W = depth.shape
    out = irr.astype(np.float64).copy()
    offs = window_offsets(window)
    for y in range(H):
        for x in range(W):
            dc = depth[y, x]
            if not np.isfinite(dc):
                continue
            acc, cnt = irr[y, x].astype(np.float64), 1
            for oy in offs:
                for ox in offs:
                    j, i = y + oy, x + ox
                    if (oy, ox) == (0, 0) or not (0 <= j < H and 0 <= i < W):
                        continue
                    if abs(depth[j, i] - dc) <= dt * dc and np.dot(normal[j, i], normal[y, x]) >= nt:
                        acc = acc + irr[j, i]
                        cnt += 1
            out[y, x] = acc / cnt
    return out


def _wall(H=120, W=160, seed=0):
    rng = np.random.default_rng(seed)
    irr = (1.0 + rng.normal(0, 0.3, (H, W, 3))).astype(np.float32)
    depth = np.full((H, W), 2.0, np.float32)
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = 1
    return irr, depth, normal


def test_flat_wall_3x3_lowers_variance_about_ninefold():
    irr, depth, normal = _wall()
    out = filter_irradiance(irr, depth, normal, 3, 0.05, 0.9)
    inner = (slice(1, -1), slice(1, -1))  # border pixels have fewer neighbours
    ratio = irr[inner].var() / out[inner].var()
    assert ratio >= 6.0
    assert 8.0 < ratio < 10.0  # i.i.d. noise: exactly 9 in expectation


def test_filter_mean_is_preserved_on_flat_wall():
    irr, depth, normal = _wall(seed=1)
    out = filter_irradiance(irr, depth, normal, 5, 0.05, 0.9)
    assert out.dtype == np.float32 and out.shape == irr.shape
    assert abs(out.mean() - irr.mean()) < 1e-3


@pytest.mark.parametrize("window", [1, 2, 3, 4, 5])
def test_matches_per_pixel_definition(window):
    rng = np.random.default_rng(window)
    H, W = 17, 23
    irr = rng.random((H, W, 3)).astype(np.float32)
    depth = rng.choice([1.0, 1.02, 1.2, 3.0, np.inf], (H, W)).astype(np.float32)
    normal = rng.normal(size=(H, W, 3)).astype(np.float32)
    normal[rng.random((H, W)) < 0.6] = (0, 0, 1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    out = filter_irradiance(irr, depth, normal, window, 0.05, 0.9)
    np.testing.assert_allclose(out, _reference(irr, depth, normal, window, 0.05, 0.9), rtol=1e-5, atol=1e-6)


def test_never_mixes_across_a_depth_discontinuity():
    H, W = 40, 60
    irr = np.zeros((H, W, 3), np.float32)
    irr[:, :30] = (1.0, 2.0, 3.0)
    irr[:, 30:] = (10.0, 20.0, 30.0)
    depth = np.where(np.arange(W) < 30, 1.0, 1.5)[None, :].repeat(H, 0).astype(np.float32)
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = 1
    for w in (3, 5, 4):
        out = filter_irradiance(irr, depth, normal, w, 0.05, 0.9)
        np.testing.assert_array_equal(out[:, :30], irr[:, :30])
        np.testing.assert_array_equal(out[:, 30:], irr[:, 30:])
    # With noise: each side is the mean of its own side's neighbours only.
    rng = np.random.default_rng(2)
    noisy = irr + rng.random((H, W, 3)).astype(np.float32)
    out = filter_irradiance(noisy, depth, normal, 3, 0.05, 0.9)
    y, x = 10, 29  # left of the edge: the column x+1 belongs to the far wall
    np.testing.assert_allclose(out[y, x], noisy[y - 1:y + 2, x - 1:x + 1].reshape(-1, 3).mean(0), rtol=1e-6)
    y, x = 10, 30
    np.testing.assert_allclose(out[y, x], noisy[y - 1:y + 2, x:x + 2].reshape(-1, 3).mean(0), rtol=1e-6)


def test_never_mixes_across_a_normal_crease():
    H, W = 30, 30
    irr = np.zeros((H, W, 3), np.float32)
    irr[:15] = 5.0
    irr[15:] = 0.5
    depth = np.full((H, W), 3.0, np.float32)  # same depth: only the normal tells them apart
    normal = np.zeros((H, W, 3), np.float32)
    normal[:15] = (0, 0, 1)
    normal[15:] = (0, np.sqrt(0.5), np.sqrt(0.5))  # 45 degree crease: dot 0.707 < 0.9
    out = filter_irradiance(irr, depth, normal, 5, 0.05, 0.9)
    np.testing.assert_array_equal(out, irr)
    mixed = filter_irradiance(irr, depth, normal, 5, 0.05, 0.5)  # threshold below the crease
    assert not np.array_equal(mixed, irr)


def test_window_one_returns_input_exactly():
    irr, depth, normal = _wall(seed=3)
    irr[0, 0] = np.inf
    out = filter_irradiance(irr, depth, normal, 1, 0.05, 0.9)
    np.testing.assert_array_equal(out, irr)
    assert out is not irr


def test_misses_are_untouched_and_never_leak():
    irr, depth, normal = _wall(H=20, W=20, seed=4)
    miss = np.zeros((20, 20), bool)
    miss[5:8, 5:8] = True
    miss[0, :] = True
    depth[miss] = np.inf
    irr[miss] = 1e6
    out = filter_irradiance(irr, depth, normal, 3, 0.05, 0.9)
    np.testing.assert_array_equal(out[miss], irr[miss])
    assert out[~miss].max() < 10.0


def test_output_is_nan_free_when_inputs_are_zero():
    H, W = 16, 16
    zeros3 = np.zeros((H, W, 3), np.float32)
    for depth in (np.zeros((H, W), np.float32), np.full((H, W), 1.0, np.float32)):
        for w in (2, 3, 5):
            out = filter_irradiance(zeros3, depth, zeros3, w, 0.05, 0.9)
            assert np.all(np.isfinite(out)) and np.all(out == 0)
    rng = np.random.default_rng(5)
    depth = rng.choice([0.0, 1.0], (H, W)).astype(np.float32)
    out = filter_irradiance(rng.random((H, W, 3)), depth, zeros3, 3, 0.0, -1.0)
    assert np.all(np.isfinite(out))


def test_non_finite_irradiance_does_not_spread():
    irr, depth, normal = _wall(H=12, W=12, seed=7)
    irr[3, 3] = np.inf
    irr[8, 8, 1] = np.nan
    out = filter_irradiance(irr, depth, normal, 3, 0.05, 0.9)
    bad = np.zeros((12, 12), bool)
    bad[3, 3] = bad[8, 8] = True
    assert np.all(np.isfinite(out[~bad]))
    assert np.isinf(out[3, 3, 0]) and np.isnan(out[8, 8, 1])


def test_even_window_block_holds_every_interleave_set_once():
    n = 4
    H, W = 16, 16
    ys, xs = np.mgrid[0:H, 0:W]
    k = (ys % n) * n + xs % n
    irr = np.zeros((H, W, 3), np.float32)
    irr[..., 0] = 2.0 ** k  # one bit per set: the sum tells which sets were averaged
    depth = np.ones((H, W), np.float32)
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = 1
    out = filter_irradiance(irr, depth, normal, n, 0.05, 0.9)
    inner = out[n:-n, n:-n, 0] * n * n
    np.testing.assert_array_equal(inner, 2.0 ** (n * n) - 1)


def test_single_row_and_column_images():
    for shape in ((1, 9), (9, 1), (1, 1)):
        irr = np.arange(np.prod(shape) * 3, dtype=np.float32).reshape(shape + (3,))
        depth = np.ones(shape, np.float32)
        normal = np.zeros(shape + (3,), np.float32)
        normal[..., 2] = 1
        out = filter_irradiance(irr, depth, normal, 3, 0.05, 0.9)
        np.testing.assert_allclose(out, _reference(irr, depth, normal, 3, 0.05, 0.9), rtol=1e-6)


def test_compose_is_reflectance_times_filtered_plus_unfiltered():
    rng = np.random.default_rng(6)
    a, b, c = (rng.random((4, 5, 3)).astype(np.float32) for _ in range(3))
    np.testing.assert_allclose(compose(a, b, c), a * b + c, rtol=1e-7)


def test_window_resolution_and_offsets():
    assert resolve_window(-1, 3) == 3
    assert resolve_window(5, 3) == 5
    assert list(window_offsets(3)) == [-1, 0, 1]
    assert list(window_offsets(4)) == [-2, -1, 0, 1]
    assert list(window_offsets(1)) == [0]
    with pytest.raises(ValueError):
        resolve_window(0, 3)
    with pytest.raises(ValueError):
        filter_irradiance(np.zeros((4, 4, 3)), np.zeros((4, 5)), np.zeros((4, 4, 3)), 3, 0.1, 0.9)
