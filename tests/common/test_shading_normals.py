"""Light from the lights with shading normals (common.kernels.shading_normals, Veach 1997 §5.3):
a flux arriving from wi is scaled by |wi·ns| / |wi·ng|, light leaving toward wo by
|wo·ng| / |wo·ns|; both are exactly 1 where the shading normal is the geometric one, so flat
scenes render bit for bit as before; and a particle estimate with them is the radiance a path
tracer computes with the shading normal."""
from __future__ import annotations

import numpy as np

from igi.common.kernels import shading_normals as sn
from igi.worker.light_paths import incident_ratios


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_the_ratios_are_exactly_one_where_the_normals_are_equal():
    rng = np.random.default_rng(7)
    for _ in range(200):
        n, w, o = _unit(rng.normal(size=3)), _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
        assert sn.incident_ratio(*w, *n, *n) == 1.0
        assert sn.exit_ratio(*w, *n, *n) == 1.0
        assert sn.adjoint_correction(*w, *o, *n, *n) == 1.0


def test_the_ratios_are_the_cosines_quotients_and_zero_along_the_true_surface():
    ng = np.array([0.0, 0.0, 1.0])
    ns = _unit([0.3, 0.0, 1.0])
    wi, wo = _unit([-0.5, 0.2, 0.6]), _unit([0.7, -0.1, 0.3])
    assert np.isclose(sn.incident_ratio(*wi, *ns, *ng), abs(wi @ ns) / abs(wi @ ng))
    assert np.isclose(sn.exit_ratio(*wo, *ns, *ng), abs(wo @ ng) / abs(wo @ ns))
    assert np.isclose(sn.adjoint_correction(*wi, *wo, *ns, *ng),
                      abs(wi @ ns) * abs(wo @ ng) / (abs(wi @ ng) * abs(wo @ ns)))
    along = np.array([1.0, 0.0, 0.0])  # in the true surface's plane: no light arrives
    assert sn.incident_ratio(*along, *ns, *ng) == 0.0
    along_s = _unit(np.cross(ns, [0.0, 1.0, 0.0]))  # in the shading plane: the BSDF gave 0
    assert sn.exit_ratio(*along_s, *ns, *ng) == 0.0
    w = np.stack([wi, wo, along])
    np.testing.assert_array_equal(incident_ratios(w, np.stack([ns] * 3), np.stack([ng] * 3), np.ones(3, bool)),
                                  [sn.incident_ratio(*x, *ns, *ng) for x in w])
    # off a mapped surface: 1
    np.testing.assert_array_equal(incident_ratios(w, np.stack([ns] * 3), np.stack([ng] * 3), np.zeros(3, bool)), 1.0)


def test_particles_weighted_by_the_incident_ratio_give_the_shading_normals_radiance():
    """A Lambertian plane z = 0 with a tilted shading normal under a distant light from wi: the
    path tracer's radiance is (ρ/π) E⊥ |wi·ns| (E⊥: irradiance on a plane facing the light).
    Particles fall on the plane with density ∝ |wi·ng|; each weighted by |wi·ns| / |wi·ng| and
    counted per unit area gives the same."""
    ng = np.array([0.0, 0.0, 1.0])
    ns = _unit([0.4, -0.2, 1.0])
    wi = _unit([-0.6, 0.3, 0.4])
    rho, e_perp = 0.7, 2.0
    # N particles through a beam of cross-section A⊥ carry E⊥ A⊥ / N each; they land on an
    # area A⊥ / |wi·ng| of the plane
    n, a_perp = 10_000, 1.0
    flux = np.full(n, e_perp * a_perp / n)
    ratio = sn.incident_ratio(*wi, *ns, *ng)
    area = a_perp / abs(wi @ ng)
    radiance = (rho / np.pi) * np.sum(flux * ratio) / area
    assert np.isclose(radiance, rho / np.pi * e_perp * abs(wi @ ns))
