"""worker.kernels.regularization_gain (through worker.regularization.regularization_gain)
against the numpy form it replaced (tests/support/oracle_regularization.py): the same gains bit
for bit, on mixed lobes, grazing and normal incidence, both hemispheres, one material or many."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common import bsdf
from igi.common.scene import CONDUCTOR, DIFFUSE, ROUGHCONDUCTOR, ROUGHPLASTIC, Material, Texture
from igi.worker.regularization import regularization_gain, regularized_senders
from tests.support.oracle_regularization import regularization_gain as oracle_gain

_MATS = [Material("c", ROUGHCONDUCTOR, specular=Texture.constant(0.8), alpha=0.02),
         Material("c2", ROUGHCONDUCTOR, specular=Texture.constant([0.9, 0.6, 0.3]), alpha=0.2, distribution="beckmann"),
         Material("p1", ROUGHPLASTIC, diffuse=Texture.constant(0.2), alpha=0.01),
         Material("p2", ROUGHPLASTIC, diffuse=Texture.constant(0.7), alpha=0.1, int_ior=1.8),
         Material("p3", ROUGHPLASTIC, diffuse=Texture.constant(0.5), alpha=0.8),
         Material("m", CONDUCTOR),
         Material("d", DIFFUSE, diffuse=Texture.constant(0.5))]


def _directions(n, rng):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    # grazing, normal and exactly tangent incidence among them, both hemispheres
    d[: n // 8, 2] = rng.choice([0.0, 1e-9, -1e-9, 1.0, -1.0, 0.05, 0.999], n // 8)
    return d


@pytest.mark.parametrize("lobe_alpha", [0.05, 0.3, 0.5, 0.9])
@pytest.mark.parametrize("materials", [[0], [2], [0, 1, 2, 3, 4, 5, 6]])
def test_gains_equal_the_numpy_form_bit_for_bit(lobe_alpha, materials):
    rng = np.random.default_rng(len(materials) * 100 + int(lobe_alpha * 10))
    for n in (1, 7, 500):
        ids = rng.choice(np.asarray(materials), n)
        sp = bsdf.gather(_MATS, ids, None)
        reg = regularized_senders(sp, lobe_alpha)
        wi = _directions(n, rng)
        got, want = regularization_gain(sp, reg, wi), oracle_gain(sp, reg, wi)
        assert got.dtype == want.dtype and got.shape == want.shape
        assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), (lobe_alpha, materials, n)


def test_nothing_widened_is_all_ones_and_a_nan_direction_keeps_gain_one():
    sp = bsdf.gather(_MATS, np.array([4, 6, 5]), None)  # rough enough, Lambertian, mirror
    np.testing.assert_array_equal(regularization_gain(sp, regularized_senders(sp, 0.5), np.eye(3)), 1.0)
    sp = bsdf.gather(_MATS, np.array([0, 2, 0]), None)
    wi = np.array([[0.0, 0.0, np.nan], [0.0, 0.6, 0.8], [0.6, 0.0, 0.8]])
    g = regularization_gain(sp, regularized_senders(sp, 0.5), wi)
    np.testing.assert_array_equal(g[0], 1.0)
    rest = sp.subset(np.array([1, 2]))
    assert np.array_equal(g[1:], oracle_gain(rest, regularized_senders(rest, 0.5), wi[1:]))
