"""Mitsuba's reconstruction filters as the pixels' sample distribution (common.reconstruction_filter)."""
import numpy as np
import pytest

from igi.common import reconstruction_filter as rf
from igi.common.camera import frame_jitter, pixel_jitter
from igi.common.scene import Camera, SceneError

# Mitsuba 3.9.1 (scalar_rgb): mi.load_dict({"type": kind, ...}).eval(x) at x = 0, 0.25, 0.49, 0.7, 1, 1.3, 1.9
# and its radius() (its gaussian's exp is Dr.Jit's approximation: within 5e-4 of the exact one)
MITSUBA = {
    ("box", (0.5, 0.0)): (0.5, [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]),
    ("tent", (1.0, 0.0)): (1.0, [1.0, 0.75, 0.51, 0.3, 0.0, 0.0, 0.0]),
    ("tent", (1.5, 0.0)): (1.5, [1.0, 0.833333, 0.673333, 0.533333, 0.333333, 0.133333, 0.0]),
    ("gaussian", (0.5, 0.0)): (2.0, [0.999247, 0.882167, 0.618559, 0.374948, 0.13496, 0.033705, 0.000388]),
    ("gaussian", (0.3, 0.0)): (1.2, [0.999264, 0.70658, 0.263028, 0.065422, 0.003538, 0.0, 0.0]),
    ("mitchell", (1 / 3, 1 / 3)): (2.0, [0.888889, 0.782118, 0.545946, 0.309056, 0.055556, -0.029944, -0.002944]),
    ("catmullrom", (0.0, 0.0)): (2.0, [1.0, 0.867188, 0.576223, 0.2895, 0.0, -0.0735, -0.0045]),
    ("lanczos", (3.0, 0.0)): (3.0, [1.0, 0.890067, 0.621171, 0.33581, 0.0, -0.14233, -0.02377]),
}
X = np.array([0, 0.25, 0.49, 0.7, 1.0, 1.3, 1.9])


@pytest.mark.parametrize("key", list(MITSUBA), ids=[f"{k}-{p[0]:.2g}" for k, p in MITSUBA])
def test_filters_evaluate_as_mitsubas(key):
    kind, params = key
    r, values = MITSUBA[key]
    assert rf.radius(kind, params) == pytest.approx(r, abs=1e-6)
    np.testing.assert_allclose(rf.evaluate(kind, params, X), values, atol=5e-4 if kind == "gaussian" else 2e-6)
    np.testing.assert_array_equal(rf.evaluate(kind, params, X), rf.evaluate(kind, params, -X))  # symmetric


@pytest.mark.parametrize("kind,params", [("tent", (1.0, 0.0)), ("gaussian", (0.5, 0.0)),
                                         ("mitchell", (1 / 3, 1 / 3)), ("lanczos", (2.0, 0.0))])
def test_offsets_are_distributed_as_the_filters_positive_part(kind, params):
    """Uniform numbers through the inverse CDF land with the density of max(f, 0), normalized:
    a histogram of 200,000 stratified offsets against the filter's integral over each bin."""
    n = 200_000
    u = (np.arange(n) + 0.5) / n
    big = 10_000  # a pixel far from the film's edges: nothing cut
    got = rf.filtered_jitter(kind, params, np.stack([u, u[::-1]], 1), np.full(n, big), np.full(n, big),
                             2 * big, 2 * big)
    off = got - 0.5
    r = rf.radius(kind, params)
    assert np.all(np.abs(off) <= r + 1e-9)
    edges = np.linspace(-r, r, 41)
    fine = np.linspace(-r, r, 400_001)
    f = np.maximum(rf.evaluate(kind, params, fine), 0)
    mass = np.array([f[(fine >= a) & (fine < b)].sum() for a, b in zip(edges[:-1], edges[1:])])
    mass /= mass.sum()
    for axis in (0, 1):
        hist = np.histogram(off[:, axis], edges)[0] / n
        np.testing.assert_allclose(hist, mass, atol=2e-4)


def test_the_pixels_own_box_leaves_the_jitter_as_it_is_and_a_wider_box_spreads_it():
    j = np.random.default_rng(1).random((50, 2))
    px = np.arange(50)
    np.testing.assert_array_equal(rf.filtered_jitter("box", (0.5, 0.0), j, px, px, 64, 64), j)
    wide = rf.filtered_jitter("box", (1.0, 0.0), j, px + 5, px + 5, 128, 128)
    np.testing.assert_allclose(wide, 0.5 + (2 * j - 1), atol=1e-9)  # uniform over [-1, 1] around the centre


def test_the_centre_number_maps_to_the_centre_and_offsets_grow_with_it():
    u = np.linspace(0.001, 0.999, 999)
    for kind, params in [("tent", (1.0, 0.0)), ("gaussian", (0.5, 0.0)), ("catmullrom", (0.0, 0.0))]:
        off = rf.filtered_jitter(kind, params, np.stack([u, u], 1), np.full(999, 50), np.full(999, 50), 100, 100)
        assert off[499, 0] == pytest.approx(0.5, abs=1e-9)  # u = 0.5: the pixel's centre
        assert np.all(np.diff(off[:, 0]) > 0)


def test_no_sample_leaves_the_film_and_an_edge_pixel_draws_from_its_cut_filter():
    """Mitsuba's film samples only inside it (sample_border off) and normalizes the weights that
    reach a pixel: a pixel at the film's edge sees its filter cut there. Its offsets stay on the
    film and are distributed as the filter restricted to the film."""
    n = 100_000
    u = (np.arange(n) + 0.5) / n
    j = np.stack([u, u], 1)
    kind, params = "gaussian", (0.5, 0.0)
    for p, size in [(0, 40), (39, 40), (1, 40)]:
        got = rf.filtered_jitter(kind, params, j, np.full(n, p), np.full(n, p), size, size)
        pos = p + got[:, 0]  # film position in pixels
        assert pos.min() >= 0 and pos.max() <= size
        lo, hi = max(-2.0, -(p + 0.5)), min(2.0, size - p - 0.5)
        fine = np.linspace(lo, hi, 200_001)
        f = rf.evaluate(kind, params, fine)
        want_mean = (f * fine).sum() / f.sum()
        assert (got[:, 0] - 0.5).mean() == pytest.approx(want_mean, abs=2e-3)
    assert (rf.filtered_jitter(kind, params, j, np.full(n, 0), np.full(n, 0), 40, 40)[:, 0] - 0.5).mean() > 0.1  # (uncut: 0)


def test_frame_jitter_filters_the_rotated_jitter_of_accumulated_frames_only_through_the_cameras_filter():
    px, py = np.arange(16) % 4 + 8, np.arange(16) // 4 + 8
    box = Camera(np.eye(4))
    gauss = Camera(np.eye(4), rfilter="gaussian", rfilter_params=(0.5, 0.0))
    assert frame_jitter((0.5, 0.5), False, px, py, box, 32, 32) == (0.5, 0.5)  # a reset frame: pixel centres
    np.testing.assert_allclose(frame_jitter((0.5, 0.5), False, px, py, gauss, 32, 32), 0.5)
    rot = pixel_jitter((0.3, 0.7), px, py)
    np.testing.assert_array_equal(frame_jitter((0.3, 0.7), True, px, py, box, 32, 32), rot)
    np.testing.assert_array_equal(frame_jitter((0.3, 0.7), True, px, py, gauss, 32, 32),
                                  rf.filtered_jitter("gaussian", (0.5, 0.0), rot, px, py, 32, 32))


@pytest.mark.parametrize("kind,params,what", [
    ("sinc", (1.0, 0.0), "unknown reconstruction filter"),
    ("gaussian", (0.0, 0.0), "stddev 0.0 must be"),
    ("tent", (-1.0, 0.0), "radius -1.0 must be"),
    ("box", (float("nan"), 0.0), "not finite"),
    ("lanczos", (2.5, 0.0), "whole number"),
    ("mitchell", (float("inf"), 0.3), "not finite"),
    ("gaussian", (1e-200, 0.0), "stddev 1e-200 must be"),
    ("mitchell", (1e308, 1e308), "must lie in"),
])
def test_bad_filters_are_named(kind, params, what):
    with pytest.raises(SceneError, match=what):
        rf.validate(kind, params)


def test_negative_lobes_are_found_where_the_parameters_give_them():
    assert rf.has_negative_lobes("mitchell", (1 / 3, 1 / 3)) and rf.has_negative_lobes("lanczos", (3.0, 0.0))
    assert rf.has_negative_lobes("catmullrom", (0.0, 0.0))
    assert not rf.has_negative_lobes("mitchell", (1.0, 0.0))  # the cubic B-spline: positive everywhere
    assert not rf.has_negative_lobes("gaussian", (0.5, 0.0)) and not rf.has_negative_lobes("tent", (1.0, 0.0))
