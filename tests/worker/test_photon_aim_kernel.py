"""worker.kernels.photon_aim (its steps alone: tests/support/photon_aim_steps.py) against its
numpy original (tests/support/oracle_photon_aim.py): one and many targets, emission points
inside a sphere, directions on a cone's rim and outside every cone."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.lights import to_world
from igi.worker.kernels import photon_aim
from tests.support import oracle_photon_aim as oracle
from tests.support import photon_aim_steps as steps


def _scene(seed: int, targets: int, n: int):
    g = np.random.default_rng(seed)
    centres = g.normal(size=(targets, 3)) * 3
    radii = g.uniform(0.05, 1.0, targets)
    pos = g.normal(size=(n, 3)) * 4
    pos[: n // 10] = centres[0] + g.normal(size=(n // 10, 3)) * radii[0] * 0.3  # inside target 0
    return g, centres, radii, pos


@pytest.mark.parametrize("seed,targets", [(0, 1), (1, 3), (2, 12)])
def test_chosen_cones_and_mixture_pdf_equal_numpy(seed, targets):
    g, centres, radii, pos = _scene(seed, targets, 2000)
    n = len(pos)
    choice = g.random(n)
    cos_max, axis = np.empty(n), np.empty((n, 3))
    steps.chosen_cones(pos, choice, centres, radii, cos_max, axis)
    _, want_cos, want_axes = oracle.cone_mixture_pdf(pos, np.zeros((n, 3)), centres, radii)
    t = np.minimum((choice * targets).astype(np.int64), targets - 1)
    np.testing.assert_array_equal(cos_max, want_cos[np.arange(n), t])
    np.testing.assert_array_equal(axis, want_axes[np.arange(n), t])
    assert np.any(cos_max == -1.0) and np.any(cos_max > 0)  # inside and outside: not vacuous
    # directions inside the chosen cone (as the emission draws them), on its rim, and anywhere
    cz = 1 - g.random(n) * (1 - cos_max)
    cz[::7] = cos_max[::7]
    r = np.sqrt(np.maximum(0, 1 - cz * cz))
    phi = 2 * np.pi * g.random(n)
    d = to_world(np.stack([r * np.cos(phi), r * np.sin(phi), cz], axis=1), axis)
    d[::5] = g.normal(size=(len(d[::5]), 3))
    d[::5] /= np.linalg.norm(d[::5], axis=1)[:, None]
    pdf = np.empty(n)
    steps.cone_mixture_pdf(pos, d, centres, radii, pdf)
    want, _, _ = oracle.cone_mixture_pdf(pos, d, centres, radii)
    # the same cones contain each direction, so the pdfs agree to rounding — except that a
    # direction exactly on a rim (every 7th) may fall on either side of it, its cosine being
    # summed in another order than numpy's einsum sums it
    same = np.isclose(pdf, want, rtol=1e-12, atol=0)
    rim = np.zeros(n, bool)
    rim[::7] = True
    assert same[~rim].all() and same[rim].mean() > 0.5
    drawn = ~rim
    drawn[::5] = False
    assert np.all(pdf[drawn] > 0) and np.all(np.isfinite(pdf))  # a drawn direction lies in its own cone
    assert np.any(pdf[::5] == 0)  # some random directions miss every cone


def test_mixture_pdf_integrates_to_one_over_the_sphere():
    """The mixture is a density: its integral over all directions is 1 (Monte Carlo, uniform
    directions), for overlapping and nested targets."""
    centres = np.array([[2.0, 0, 0], [2.5, 0.3, 0], [0, -3, 1]])
    radii = np.array([0.8, 0.5, 1.2])
    g = np.random.default_rng(5)
    n = 400_000
    d = g.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pdf = np.empty(n)
    steps.cone_mixture_pdf(np.zeros((n, 3)), d, centres, radii, pdf)
    assert abs(4 * np.pi * pdf.mean() - 1.0) < 0.01


@pytest.mark.parametrize("seed,targets", [(3, 1), (4, 5)])
def test_aimed_emission_equals_the_numpy_emission(seed, targets):
    """kernels.photon_aim.aimed_emission: the numpy form's directions, pdfs, area emitters'
    flux (grazing and back-facing directions included) and offset origins, bit for bit."""
    from igi.bench.stress_scenes import load_shared
    from igi.common.geometry import Geometry

    geom = Geometry(load_shared("cornell-box-sphere"))
    g, centres, radii, pos = _scene(seed, targets, 3000)
    n = len(pos)
    nrm = g.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    u = g.random((n, 5))
    emitter = g.integers(0, 3, n)
    area = emitter != 2  # emitter 2 a point light: flux 0 here, origin unmoved
    radiance = np.array([[5.0, 4.0, 3.0], [1.0, 2.0, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    total = np.array([0.3, 1.7, 0.0])
    d, pdf, flux, o = (np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty((n, 3)))
    photon_aim.aimed_emission(pos, nrm, u, centres, radii, emitter, area, radiance, total, *geom.offset_terms(), d,
                              pdf, flux, o)
    want = oracle.aimed_emission(pos, nrm, u, centres, radii, emitter, area, radiance, total, geom.offset)
    for got, w, name in zip((d, pdf, flux, o), want, ("direction", "pdf", "flux", "origin")):
        np.testing.assert_array_equal(got, w, err_msg=name)
    assert np.any(flux[area] == 0) and np.any(flux[area] > 0)  # back-facing and lit: not vacuous
    np.testing.assert_array_equal(o[~area], pos[~area])


def _distant(d, u, centres, radii, center=np.zeros(3), radius=10.0):
    n = len(d)
    o, pdf = np.empty((n, 3)), np.empty(n)
    photon_aim.distant_emission(np.ascontiguousarray(d), np.ascontiguousarray(u), centres, radii, center, radius,
                                o, pdf)
    return o, pdf


def test_a_suns_photons_start_upstream_on_the_shadow_disk_of_their_target():
    """Each photon of a distant light crosses the disk its chosen target's sphere casts across
    the light's direction, and starts outside the scene's bounding sphere, upstream."""
    centres = np.array([[0.0, 1.0, 0.0], [2.0, 0.5, -1.0]])
    radii = np.array([0.5, 0.25])
    g = np.random.default_rng(2)
    n = 20_000
    d = np.tile(g.normal(size=3), (n, 1))
    d /= np.linalg.norm(d, axis=1)[:, None]
    u = g.random((n, 5))
    o, pdf = _distant(d, u, centres, radii)
    t = np.minimum((u[:, 2] * 2).astype(int), 1)
    rel = o - centres[t]
    across = rel - np.einsum("ij,ij->i", rel, d)[:, None] * d
    assert np.all(np.linalg.norm(across, axis=1) <= radii[t] * (1 + 1e-9))
    assert np.all(np.linalg.norm(o, axis=1) >= 10.0)  # outside the bounding sphere (centre 0, radius 10)
    assert np.all(np.einsum("ij,ij->i", o - centres[t], d) < 0)  # upstream of the target
    assert np.all(pdf > 0) and np.all(np.isfinite(pdf))


def test_the_shadow_disk_mixture_is_an_area_density_in_the_plane_across_the_light():
    """The mixture's integral over the plane across the light is 1 (Monte Carlo, uniform points
    on a square that holds every disk), overlapping and nested disks included."""
    centres = np.array([[0.0, 0.0, 0.0], [0.4, 0.1, 3.0], [-1.0, 0.5, -2.0], [-1.0, 0.4, 5.0]])
    radii = np.array([0.8, 0.5, 0.3, 0.1])
    d = np.array([0.0, 0.0, 1.0])  # along z: the plane across it is (x, y)
    g = np.random.default_rng(5)
    n = 400_000
    side = 4.0
    p = np.zeros((n, 3))
    p[:, :2] = (g.random((n, 2)) - 0.5) * side
    o, drawn = _distant(np.tile(d, (n, 1)), g.random((n, 5)), centres, radii)
    assert np.all(drawn > 0)
    # E over drawn points of 1/pdf is the union's area; uniform points on the square measure it too
    inside = np.zeros(n, bool)
    for c, r in zip(centres, radii):
        inside |= np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) <= r
    union = side * side * inside.mean()
    assert np.mean(1.0 / drawn) == pytest.approx(union, rel=0.01)
