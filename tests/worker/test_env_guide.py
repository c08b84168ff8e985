"""Sky light sampled where the view sees it (worker.env_guide): the direction pdf is a pdf,
sampling follows it, and guided environment samples (with the BSDF ray's MIS using the same
pdf) give the same direct light as uniform ones, with less noise, in a room lit through a
window."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from igi.common import bundled
from igi.common.camera import camera_rays
from igi.common.loader import load_scene
from igi.common.sobol_stream import rng
from igi.worker.env_guide import BINS_PHI, BINS_Z, EnvGuide, build_guide, guide_environment_samples
from igi.worker.renderer import Renderer
from igi.worker.shading import bsdf_direct, gather_vpls, trace_eye
from igi.worker.vpl import build_vpl_set

ENVMAP_DATA = Path(__file__).resolve().parents[1] / "data" / "envmap"


def _guide(seed=0) -> EnvGuide:
    g = np.random.default_rng(seed)
    counts = g.random(BINS_Z * BINS_PHI) ** 8  # a peaked histogram
    hist = counts / counts.sum()
    return EnvGuide(np.cumsum(hist), hist / (4 * np.pi / (BINS_Z * BINS_PHI)), 0.7)


def test_pdf_integrates_to_one_and_sampling_follows_it():
    guide = _guide()
    g = np.random.default_rng(1)
    n = 400_000
    z = 1 - 2 * g.random(n)
    phi = 2 * np.pi * g.random(n)
    r = np.sqrt(1 - z * z)
    w = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    q = guide.pdf(w)
    assert np.all(q > 0)
    assert abs(q.mean() * 4 * np.pi - 1) < 0.01  # ∫ q dω = 1
    # E_q[f/q] = ∫ f for f = 1 + x + z²: samples drawn from q, weighted 1/q
    s = guide.sample(g.random((n, 3)))
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 1.0, atol=1e-12)
    f = 1 + s[:, 0] + s[:, 2] ** 2
    est = np.mean(f / guide.pdf(s))
    assert abs(est - 4 * np.pi * (1 + 1 / 3)) < 0.03 * 4 * np.pi


def _view_end_points(scene):
    """A renderer of ``scene`` and the end points of its camera's 24 x 18 eye rays."""
    r = Renderer(scene)
    cam = scene.camera
    ys, xs = np.mgrid[0:18, 0:24]
    o, d = camera_rays(cam.to_world, cam.fov_x, 24, 18, xs.ravel() * cam.width / 24, ys.ravel() * cam.height / 18)
    end = trace_eye(scene, r.geom, r.lights, o, d, -1, 8, rng(0, 9)).end
    return r, end


def _window_room():
    return _view_end_points(load_scene(bundled.resolve("window-room")))


def _direct_totals(r, end, guided: bool, seeds) -> np.ndarray:
    out = []
    for s in seeds:
        v = build_vpl_set(r.scene, r.geom, r.lights, s, 0, 16, 0, 1)
        if guided:
            guide = build_guide(r.scene, r.geom, r.lights, end, rng(s, "rays"))
            assert guide is not None
            guide_environment_samples(v, r.lights, guide, 16, rng(s, "samples"))
            v.env_guide = guide
        a, irr = gather_vpls(r.geom, end, v, 0.0, 2)
        irr = irr + bsdf_direct(r.scene, r.geom, r.lights, end, a, v.direct_count, 2, rng(s, "bsdf"), v.env_guide)
        out.append(float((a * irr).sum()))
    return np.array(out)


def _agreeing_totals(r, end) -> tuple[np.ndarray, np.ndarray]:
    """Direct light of 60 sets, plain and guided, whose means agree within 4 standard errors."""
    seeds = range(60)
    plain = _direct_totals(r, end, False, seeds)
    guided = _direct_totals(r, end, True, seeds)
    assert plain.mean() > 0
    se = np.sqrt(plain.var(ddof=1) / len(plain) + guided.var(ddof=1) / len(guided))
    assert abs(plain.mean() - guided.mean()) < 4 * se
    return plain, guided


def test_guided_sky_samples_are_unbiased_and_less_noisy():
    plain, guided = _agreeing_totals(*_window_room())
    assert guided.std() < plain.std()


def test_guided_sky_over_an_open_floor_is_exactly_the_sky_radiance():
    """A Lambertian floor under a uniform sky L = 1 reflects radiance ρ·L: guided samples from a
    deliberately wrong (peaked) guide, MIS-combined with the BSDF ray through the same pdf, must
    average to irradiance/π = 1 per unit albedo (within noise: a 1/q weight left out or a wrong
    pdf in the MIS is caught by this; the subtler bias of a uniform pdf in the BSDF ray's MIS,
    ~4%, is below this test's 4σ ≈ 9%)."""
    from igi.common.camera import look_at
    from igi.common.scene import CONSTANT, DIFFUSE, Camera, Emitter, Material, Mesh, Scene, Texture

    v = np.array([[-50, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]], float)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.int32)
    scene = Scene([Mesh("floor", v, f, 0)], [Material("floor", DIFFUSE, diffuse=Texture.constant(0.5))],
                  [Emitter(CONSTANT, radiance=np.ones(3))],
                  Camera(look_at([0, 5, 5], [0, 0, 0], [0, 1, 0]), fov=40, width=16, height=16))
    r = Renderer(scene)
    guide = _guide(3)
    means = _floor_irradiance(r, EnvGuide(guide.cdf, guide.density, float(r.lights.pmf[0]))).mean(axis=1)
    se = np.std(means) / np.sqrt(len(means))
    assert abs(np.mean(means) - 1.0) < 4 * se + 0.005  # the deliberately peaked guide is noisy


def _floor_irradiance(r, guide: EnvGuide) -> np.ndarray:
    """(200, 3): per set (seeds 0..199) the mean irradiance per unit albedo over the 16 x 16 camera
    pixels of a floor scene, from environment samples redrawn from ``guide`` and the BSDF ray's MIS
    through it, direct light only."""
    cam = r.scene.camera
    ys, xs = np.mgrid[0:16, 0:16]
    o, d = camera_rays(cam.to_world, cam.fov_x, 16, 16, xs.ravel(), ys.ravel())
    end = trace_eye(r.scene, r.geom, r.lights, o, d, -1, 8, rng(0, 1)).end
    assert len(end) == 256 and np.all(end.ns[:, 1] > 0.99)
    means = []
    for s in range(200):
        vs = build_vpl_set(r.scene, r.geom, r.lights, s, 0, 16, 0, 1)
        guide_environment_samples(vs, r.lights, guide, 16, rng(s, "samples"))
        a, irr = gather_vpls(r.geom, end, vs, 0.0, 2)
        irr = irr + bsdf_direct(r.scene, r.geom, r.lights, end, a, vs.direct_count, 2, rng(s, "bsdf"), guide)
        means.append(irr.mean(axis=0))
    return np.array(means)


def _envmap_scene(name: str):
    return _view_end_points(load_scene(ENVMAP_DATA / f"{name}.xml"))


def test_a_sky_map_guided_through_a_window_gives_the_light_of_its_own_samples():
    """The window room lit by a map with a sun (tests/data/envmap/room.xml): guided samples — half
    from the map, half from the escaped rays' histogram, each weighted L(ω)/q(ω), the BSDF ray's
    MIS through the same q — give the direct light the map's own samples give."""
    r, end = _envmap_scene("room")
    assert r.lights.env_map is not None
    _agreeing_totals(r, end)


def test_an_open_sky_that_is_a_map_is_not_guided_a_window_is():
    outdoor, end = _envmap_scene("outdoor")
    assert build_guide(outdoor.scene, outdoor.geom, outdoor.lights, end, rng(1, "rays")) is None
    room, end = _envmap_scene("room")
    guide = build_guide(room.scene, room.geom, room.lights, end, rng(1, "rays"))
    assert guide is not None and guide.sky_map is room.lights.env_map


def test_a_floor_under_a_sky_map_reflects_the_maps_irradiance_through_any_guide():
    """A Lambertian floor under the outdoor map (sun included) reflects ρ·E/π with E = ∫ L cos dω
    (computed here by the map's own importance sampling, 10⁶ directions): environment samples
    from a deliberately wrong (peaked) guide mixed with the map, MIS-combined with the BSDF ray
    through the same pdf, must average to it."""
    from igi.common.camera import look_at
    from igi.common.scene import DIFFUSE, Camera, Material, Mesh, Scene, Texture

    sky = load_scene(ENVMAP_DATA / "outdoor.xml")
    (env,) = [e for e in sky.emitters]
    v = np.array([[-50, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]], float)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.int32)
    scene = Scene([Mesh("floor", v, f, 0)], [Material("floor", DIFFUSE, diffuse=Texture.constant(0.5))], [env],
                  Camera(look_at([0, 5, 5], [0, 0, 0], [0, 1, 0]), fov=40, width=16, height=16))
    r = Renderer(scene)
    m = r.lights.env_map
    w, p = m.sample(np.random.default_rng(7).random((1_000_000, 2)))
    e_over_pi = (m.radiance(w) * (np.maximum(w[:, 1], 0) / p)[:, None]).mean(0) / np.pi
    peaked = _guide(3)
    means = _floor_irradiance(r, EnvGuide(peaked.cdf, peaked.density, float(r.lights.pmf[0]), sky_map=m))
    se = means.std(axis=0) / np.sqrt(len(means))
    assert np.all(np.abs(means.mean(axis=0) - e_over_pi) < 4 * se + 0.005 * e_over_pi)
