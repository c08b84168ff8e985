"""The compiled caustic photon estimate (worker.kernels.photon_estimate via
worker.caustics.gather_photons) equals the numpy form it replaced
(tests/support/oracle_photon_estimate.py): Lambertian and glossy end points, photons from both
sides and exactly in the tangent plane, path-length limits, zero albedo, NaN and Inf powers."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from igi.bench.stress_scenes import eye_end_points, load_shared
from igi.worker.caustics import PhotonSet, gather_photons
from igi.worker.hash_grid import HashGrid
from igi.worker.renderer import Renderer
from tests.support.oracle_photon_estimate import gather_photons_numpy

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN/Inf


def _photons_around(end, g, radius, per_point=3):
    """Photons scattered within ~r of the end points, arriving from all directions."""
    src = g.integers(0, len(end), per_point * len(end))
    pos = end.position[src] + g.normal(size=(len(src), 3)) * radius * 0.5
    d = g.normal(size=(len(src), 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tangent = np.arange(0, len(src), 11)  # exactly in the tangent plane of their end point
    t = np.cross(end.ns[src[tangent]], g.normal(size=(len(tangent), 3)))
    d[tangent] = t / np.linalg.norm(t, axis=1)[:, None]
    power = g.random((len(src), 3))
    power[5] = np.nan
    power[9] = [np.inf, 1.0, -np.inf]
    depth = g.integers(1, 6, len(src)).astype(np.int32)
    n = d.copy()
    return PhotonSet(pos, power, d, n, depth, radius, HashGrid(pos, radius))


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
@pytest.mark.parametrize("max_depth", [-1, 5])
def test_estimate_equals_the_numpy_estimate(name, max_depth):
    r = Renderer(load_shared(name))
    end = eye_end_points(r, 40, 30)
    g = np.random.default_rng(3)
    end = dataclasses.replace(end, segments=g.integers(1, 4, len(end)).astype(end.segments.dtype))
    photons = _photons_around(end, g, 0.02 * r.geom.diagonal)
    albedo = g.random((len(end), 3))
    albedo[::7] = 0.0
    got = gather_photons(end, photons, albedo, max_depth)
    want = gather_photons_numpy(end, photons, albedo, max_depth)
    assert np.count_nonzero(want) > len(end)  # the photons do reach many end points
    np.testing.assert_array_equal(got, want)


def test_no_photons_and_no_end_points_give_zeros():
    r = Renderer(load_shared("cornell-box"))
    end = eye_end_points(r, 8, 6)
    photons = _photons_around(end, np.random.default_rng(0), 0.01)
    ones = np.ones((len(end), 3))
    assert not gather_photons(end, dataclasses.replace(photons, grid=None), ones, -1).any()
    assert gather_photons(end, photons, ones, -1).any()
    assert gather_photons(end.subset(np.zeros(0, np.int64)), photons, np.ones((0, 3)), -1).shape == (0, 3)
