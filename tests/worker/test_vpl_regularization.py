"""Glossy VPLs radiate through regularized lobes (Kaplanyan & Dachsbacher 2013): a smooth lobe
is widened to ``vpl_lobe_alpha`` so one VPL cannot spike, while the energy it reflects stays
(worker.regularization)."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common import bsdf
from igi.common.scene import DIFFUSE, ROUGHCONDUCTOR, ROUGHPLASTIC, Material, Texture
from igi.worker.renderer import radius_scale
from igi.common.params import make_params
from igi.worker.regularization import mu_dirs, regularization_gain, regularized_senders


def _points(kind, alpha, n=1):
    mat = Material("m", kind, diffuse=Texture.constant(0.5), specular=Texture.constant(1.0), alpha=alpha)
    return bsdf.SurfacePoints.constant(mat, n)


def _hemisphere(n, seed=0):
    u = np.random.default_rng(seed).random((n, 2))
    z = u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)  # uniform: pdf 1/(2π)


def test_smooth_lobes_are_widened_and_nothing_else_changes():
    pts = [_points(ROUGHCONDUCTOR, 0.05), _points(ROUGHPLASTIC, 0.1), _points(ROUGHPLASTIC, 0.8),
           _points(DIFFUSE, 0.1)]
    from igi.worker.vpl import concat_surface

    sp = concat_surface(pts)
    out = regularized_senders(sp, 0.5)
    np.testing.assert_allclose(out.alpha, [0.5, 0.5, 0.8, sp.alpha[3]])
    np.testing.assert_array_equal(out.kind, sp.kind)
    assert regularized_senders(sp, 0.0) is sp  # off
    assert regularized_senders(sp, 0.01) is sp  # nothing smoother than the bound


def test_regularized_lobe_peak_is_bounded_and_its_energy_kept():
    wo = _hemisphere(200_000)
    rng = np.random.default_rng(1)
    for cos_i in (0.95, 0.5, 0.2):
        wi = np.repeat([[np.sqrt(1 - cos_i * cos_i), 0.0, cos_i]], len(wo), axis=0)
        for kind in (ROUGHCONDUCTOR, ROUGHPLASTIC):
            smooth = _points(kind, 0.02, len(wo))
            reg = regularized_senders(smooth, 0.5)
            f_s = bsdf.eval(smooth, wi, wo).mean(axis=1)
            f_r = bsdf.eval(reg, wi, wo).mean(axis=1)
            lam = 0.5 / np.pi  # the peak of a Lambertian VPL of albedo 0.5
            # a smooth lobe spikes orders of magnitude over a Lambertian VPL; widened, a few times
            assert f_s.max() > 20 * lam
            assert f_r.max() < 8 * lam  # (the 1/(4 cos θ_i) of a microfacet lobe: highest at grazing)
            # reflected energy (directional albedo, BSDF-sampled): the widened microfacet lobe
            # loses what single scattering loses at α 0.5 (GGX masking: up to ~35% of a
            # plastic's light at grazing incidence); the gain gives it back
            u1, u2 = rng.random(len(wo)), rng.random((len(wo), 2))
            e_s = bsdf.sample(smooth, wi, u1, u2)[1].mean()
            e_r = bsdf.sample(reg, wi, u1, u2)[1].mean()
            gain = regularization_gain(smooth, reg, wi)
            assert e_r < 0.97 * e_s or cos_i > 0.9, (kind, cos_i, e_s, e_r)  # the loss is real
            assert float((bsdf.sample(reg, wi, u1, u2)[1] * gain).mean()) == pytest.approx(e_s, rel=0.02)
            assert f_r.max() * gain.max() < 30 * lam  # still no spike


def test_the_gain_restores_each_lobes_directional_albedo_and_leaves_the_rest_alone():
    # Conductors, plastics of two roughnesses and two IORs, a textured-like diffuse spread and a
    # Lambertian point in one batch: the per-lobe tables serve each point with its own lobe.
    mats = [Material("c", ROUGHCONDUCTOR, specular=Texture.constant(0.8), alpha=0.02),
            Material("p1", ROUGHPLASTIC, diffuse=Texture.constant(0.2), alpha=0.01),
            Material("p2", ROUGHPLASTIC, diffuse=Texture.constant(0.7), alpha=0.1, int_ior=1.8),
            Material("p3", ROUGHPLASTIC, diffuse=Texture.constant(0.5), alpha=0.8),
            Material("d", DIFFUSE, diffuse=Texture.constant(0.5))]
    ids = np.repeat(np.arange(len(mats)), 5)
    sp = bsdf.gather(mats, ids, None)
    wi = mu_dirs(np.tile([0.95, 0.6, 0.35, 0.15, 0.06], len(mats)))
    reg = regularized_senders(sp, 0.5)
    gain = regularization_gain(sp, reg, wi)
    want = bsdf.directional_albedo(sp, wi, 4096)
    got = bsdf.directional_albedo(reg, wi, 4096) * gain
    np.testing.assert_allclose(got, want, rtol=0.03)
    untouched = np.isin(ids, [3, 4])  # rough enough already / Lambertian
    np.testing.assert_array_equal(gain[untouched], 1.0)
    assert gain[~untouched].max() > 1.5  # grazing light on a widened lobe needs much of it back


def test_the_bound_shrinks_while_accumulating_consistently():
    p = make_params(consistent=True)
    scales = [radius_scale(i, p) for i in (0, 1, 16, 256)]
    assert scales[0] == 1.0 and all(a > b for a, b in zip(scales, scales[1:]))
    assert radius_scale(256, make_params(consistent=False)) == 1.0


def _smooth_plastic_floor():
    """A smooth plastic floor (α 0.01, diffuse 0.5, normal +y) and a dim lamp far aside."""
    from igi.common.camera import look_at
    from igi.common.scene import AREA, Camera, Emitter, Mesh, Scene
    from tests.support.scenes_synthetic import quad

    mats = [Material("plastic", ROUGHPLASTIC, diffuse=Texture.constant(0.5), alpha=0.01),
            Material("lamp", DIFFUSE, diffuse=Texture.constant(0.0))]
    fv, ff = quad([-3, 0, -3], [0, 0, 6], [6, 0, 0])
    lv, lf = quad([4, 3, 4], [0.3, 0, 0], [0, 0, 0.3])
    if np.cross(lv[1] - lv[0], lv[2] - lv[0])[1] > 0:
        lf = lf[:, ::-1].copy()
    return Scene([Mesh("floor", fv, ff, 0), Mesh("lamp", lv, lf, 1, emitter=0)], mats,
                 [Emitter(AREA, radiance=np.full(3, 1e-3), mesh=1)],
                 Camera(look_at([0, 1, 1], [0, 0, 0], [0, 1, 0]), fov=40, width=8, height=8))


def test_a_caustic_photon_in_a_smooth_plastics_mirror_direction_is_no_spike_where_it_is_read_back():
    """The clamp compensation and the lensed chains read the light a surface y reflects toward
    x (worker.final_gather): y is a sender like a VPL, so its lobe is regularized too.
    One photon arriving from y's mirror direction on a plastic of α 0.01 read with the raw lobe
    is ~500 Lambertian photons' worth (modern-hall: one such read put a 1000× spike into a
    pixel's filtered irradiance, smeared over a whole 5×5 interleave block)."""
    from igi.worker.caustics import PhotonSet
    from igi.worker.hash_grid import HashGrid
    from igi.worker.renderer import Renderer
    from igi.common import bsdf
    from igi.worker.arrivals import Arrivals
    from igi.worker.final_gather import final_gather
    from igi.worker.shading import BSDFRays, EndPoints
    from igi.worker.vpl import _empty_set

    scene = _smooth_plastic_floor()
    r = Renderer(scene)
    d = np.array([[0.0, -1.0, -1.0]]) / np.sqrt(2)  # from x = (0, 1, 1) down to y = origin
    hits = r.geom.intersect(np.array([[0.0, 1.0, 1.0]]), d)
    assert hits.valid[0]
    radius = 0.05
    pos = np.zeros((1, 3))
    mirror = np.array([[0.0, 1.0, -1.0]]) / np.sqrt(2)  # where the photon came from
    photons = PhotonSet(pos, np.ones((1, 3)), mirror, np.array([[0.0, 1.0, 0.0]]), np.ones(1, np.int32),
                        radius, HashGrid(pos, radius), 1)
    lambertian = 0.5 / np.pi / (np.pi * radius ** 2)  # the same photon on a diffuse 0.5 surface

    y = Arrivals(hits.position, hits.ns, hits.ng, hits.material, hits.uv, hits.t, d, np.array([1]), np.array([0]),
                 np.ones((1, 3)), np.array([0]))
    # x: an end point at the ray's origin with no light of its own (no VPLs, no BSDF ray, far
    # from the photon): all it gathers is y's
    up = np.array([[0.0, 1.0, 0.0]])
    x = EndPoints(np.array([0]), np.array([[0.0, 1.0, 1.0]]), up, up, np.array([[0.0, 0.0, 1.0]]),
                  bsdf.gather(scene.materials, np.array([0]), None), np.ones((1, 3)), np.array([0]), np.array([True]),
                  np.array([1.0]))
    empty = r.geom.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    no_rays = BSDFRays(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool), np.zeros((0, 3)), empty)

    def read(lobe_alpha):
        albedo, irr = final_gather(scene, r.geom, r.lights, x, no_rays, y, _empty_set(), 0.01, -1,
                                   np.random.default_rng(0), lobe_alpha, photons)
        return float((albedo * irr).mean()) / lambertian

    assert read(0.0) > 100  # the raw lobe: the spike
    assert 0.5 < read(0.5) < 4  # regularized: about a Lambertian photon


def test_the_gathers_glossy_senders_carry_the_gain_once_per_set():
    """The gather's per-VPL colours (shading.vpl_columns) scale a widened glossy sender by its
    gain at its incident direction and leave Lambertian senders as ρ/π · power; the columns are
    made once per set and settings and not shared with a replace()d copy."""
    from dataclasses import replace

    from igi.common.geometry import Geometry
    from igi.common.lights import VPL_SURFACE
    from igi.worker.shading import vpl_columns
    from igi.worker.vpl import VPLSet, concat_surface
    from tests.support.scenes_synthetic import furnace_box

    sp = concat_surface([_points(ROUGHCONDUCTOR, 0.05, 3), _points(DIFFUSE, 0.1, 2)])
    wi = np.array([[0.6, 0.0, 0.8], [0.0, 0.95, 0.31], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.3, 0.0, 0.95]])
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    m = len(wi)
    power = np.arange(1, m + 1)[:, None] * np.ones((1, 3))
    z = np.zeros((m, 3))
    v = VPLSet(np.full(m, VPL_SURFACE, np.int8), z, np.tile([0, 0, 1.0], (m, 1)), z, power, np.ones(m, np.int32),
               wi, sp, False)
    geom = Geometry(furnace_box(0.5, 1.0))
    cols = vpl_columns(v, geom, 1e-3, lobe_alpha=0.5)
    gain = regularization_gain(sp.subset(np.arange(3)), regularized_senders(sp.subset(np.arange(3)), 0.5), wi[:3])
    assert np.all(gain > 1.01)  # widening a 0.05 lobe to 0.5 loses light at these angles
    np.testing.assert_allclose(cols.color[:3], power[:3] * gain, rtol=1e-12)
    np.testing.assert_allclose(cols.color[3:], power[3:] * sp.diffuse[3:] / np.pi, rtol=1e-6)  # float32 ρ
    assert vpl_columns(v, geom, 1e-3, lobe_alpha=0.5) is cols
    assert vpl_columns(v, geom, 2e-3, lobe_alpha=0.5) is not cols
    np.testing.assert_allclose(vpl_columns(v, geom, 1e-3, lobe_alpha=0.0).color[:3], power[:3])  # no widening
    assert replace(v, power=power * 2).derived == {}
