"""The compiled BSDF-direct light (worker.kernels.bsdf_direct via worker.shading.add_bsdf_direct)
adds the numpy form's light bit for bit (tests/support/oracle_bsdf_direct.py): an area light, a
lit sky with and without its guide, several ray batches into one buffer, grazing hits, NaN and
infinite weights and distances, and no rays at all."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from igi.worker.shading import BSDFRays, LightMIS, add_bsdf_direct, bsdf_direct
from tests.support.end_points import traced_end_points
from tests.support.oracle_bsdf_direct import bsdf_direct_numpy

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN inputs


def _hostile(rays: BSDFRays) -> BSDFRays:
    """``rays`` with NaN / infinite weights, pdfs and distances, and grazing emitter hits."""
    w, pdf, t = rays.weight.copy(), rays.pdf.copy(), rays.hits.t.copy()
    ns, delta = rays.hits.ns.copy(), rays.delta.copy()
    w[::11] = np.nan
    w[5::13, 1] = np.inf
    pdf[3::17] = 0.0
    t[7::19] = np.inf
    delta[2::5] = True  # delta samples: MIS weight 1
    lit = np.flatnonzero(rays.hits.valid & (rays.hits.emitter >= 0))
    # shading normals almost perpendicular to the ray, front side: cos 1e-9, under the pdf's
    # 1e-7 floor; every second one exactly perpendicular (cos 0: the back side, no light)
    d = rays.direction[lit[::3]]
    side = np.cross(d, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1)[:, None]
    side[::2] -= 1e-9 * d[::2]
    ns[lit[::3]] = side
    return dataclasses.replace(rays, weight=w, pdf=pdf, delta=delta, hits=dataclasses.replace(rays.hits, t=t, ns=ns))


@pytest.mark.parametrize("name, sky", [("cornell-box", False), ("cornell-box-sphere", True),
                                       ("grey-white-room", False)])
@pytest.mark.parametrize("hostile", [False, True])
def test_light_equals_the_numpy_light(monkeypatch, name, sky, hostile):
    scene, r, eye, rays, _d2, g = traced_end_points(monkeypatch, name, True, sky, -1, 3)
    if hostile:
        rays = _hostile(rays)
    end = eye.end
    albedo = g.random((len(end), 3)) * 0.9
    albedo[::7] = 0.0  # the 1e-6 floor
    mis = LightMIS(4, None, None)
    lit = rays.lit(r.lights.environment())
    assert len(lit) > 0  # the test sees light
    want = bsdf_direct_numpy(r.lights, rays, albedo, mis)
    got = np.zeros((len(end), 3))
    add_bsdf_direct(r.lights, [(rays, 0)], albedo, mis, got)
    np.testing.assert_array_equal(got, want)


def test_the_guided_sky_and_a_set_emitter_choice_equal_the_numpy_light(monkeypatch):
    scene, r, eye, rays, _d2, g = traced_end_points(monkeypatch, "grey-white-room", True, False, -1, 5)
    from igi.common.params import make_params
    from igi.common.camera import resolve_camera
    from igi.worker.vpl_importance import View

    cam, fov, w, h = resolve_camera(scene, None, 64, 48)
    vpls = r.vpl_set(0, 0, make_params(), view=View.of(cam, fov, w, h))
    assert vpls.env_guide is not None  # the window room's sky is guided
    pmf = r.lights.pmf * np.linspace(0.5, 1.5, len(r.lights.pmf))
    mis = LightMIS(vpls.direct_count, vpls.env_guide, pmf / pmf.sum())
    albedo = np.full((len(eye.end), 3), 0.5)
    assert np.any(~rays.hits.valid)  # rays leave through the window
    want = bsdf_direct_numpy(r.lights, rays, albedo, mis)
    got = np.zeros_like(want)
    add_bsdf_direct(r.lights, [(rays, 0)], albedo, mis, got)
    np.testing.assert_array_equal(got, want)


def test_batches_light_their_own_rows_of_one_buffer(monkeypatch):
    scene, r, eye, rays, _d2, g = traced_end_points(monkeypatch, "cornell-box", True, False, -1, 7)
    n = len(eye.end)
    albedo = np.concatenate([np.full((n, 3), 0.4), np.full((n, 3), 0.8)])
    mis = LightMIS(4, None, None)
    got = np.ones((2 * n, 3))  # added to what is there
    add_bsdf_direct(r.lights, [(rays, 0), (rays, n)], albedo, mis, got)
    np.testing.assert_array_equal(got[:n], 1.0 + bsdf_direct_numpy(r.lights, rays, albedo[:n], mis))
    np.testing.assert_array_equal(got[n:], 1.0 + bsdf_direct_numpy(r.lights, rays, albedo[n:], mis))


def test_no_rays_and_no_lit_rays_add_nothing(monkeypatch):
    scene, r, eye, rays, _d2, g = traced_end_points(monkeypatch, "cornell-box", True, False, -1, 9)
    none = rays.subset(np.zeros(0, np.int64))
    dark = rays.subset(np.flatnonzero(rays.hits.valid & (rays.hits.emitter < 0)))
    got = np.full((len(eye.end), 3), 2.0)
    add_bsdf_direct(r.lights, [(none, 0), (dark, 0)], np.ones((len(eye.end), 3)), LightMIS(4, None, None), got)
    assert np.all(got == 2.0)
    assert len(bsdf_direct(scene, r.geom, r.lights, eye.end.subset(np.zeros(0, np.int64)), np.zeros((0, 3)), 4, -1,
                           g, rays=none)) == 0
