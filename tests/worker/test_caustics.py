"""Caustic photons: energy through a glass slab, unbiased aiming, and the render plan's skip;
suns (directional lights, an environment map's peak) through glass against Mitsuba references."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import binary_erosion, uniform_filter

from igi.common.camera import look_at
from igi.common.geometry import Geometry
from igi.common.lights import LightSampler
from igi.common.loader import load_scene
from igi.common.scene import (CONSTANT, DIELECTRIC, DIFFUSE, DIRECTIONAL, POINT, Camera, Emitter, Material, Mesh, Scene,
                              Texture)
from tests.support.paths import SHARED
from tests.support.scenes_synthetic import box_faces, quad
from igi.worker.caustics import build_photon_set, specular_targets
from igi.worker.renderer import Renderer

ETA = 1.5
LIGHT_Y = 2.0
SLAB_TOP, SLAB_BOTTOM, HALF = 1.0, 0.9, 0.5


def slab_scene() -> Scene:
    """A point light above a 1 x 0.1 x 1 glass slab above a large diffuse floor (no walls)."""
    mats = [Material("glass", DIELECTRIC, int_ior=ETA, ext_ior=1.0),
            Material("floor", DIFFUSE, diffuse=Texture.constant(0.5))]
    meshes = []
    for v, f in box_faces(1.0, inward=False):
        v = v * np.array([2 * HALF, SLAB_TOP - SLAB_BOTTOM, 2 * HALF]) + np.array([-HALF, SLAB_BOTTOM, -HALF])
        meshes.append(Mesh("slab", v, f, 0))
    v, f = quad([-5, 0, -5], [0, 0, 10], [10, 0, 0])  # normal +y
    meshes.append(Mesh("floor", v, f, 1))
    light = Emitter(POINT, intensity=np.ones(3), position=np.array([0.0, LIGHT_Y, 0.0]))
    cam = Camera(look_at([0, 3, 3], [0, 0, 0], [0, 1, 0]), fov=45, width=32, height=32)
    return Scene(meshes, mats, [light], cam)


def _fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    sin_t2 = (1 - cos_i ** 2) / eta ** 2
    cos_t = np.sqrt(np.maximum(0, 1 - sin_t2))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs ** 2 + rp ** 2)


def expected_transmitted_flux() -> float:
    """∫ I·T(θ) dω over the slab's top face; T = (1-R)/(1+R) sums all internal reflections
    of an infinite slab (the 1 x 1 slab leaks a negligible R²-order share out of its sides)."""
    n = 1500
    s = (np.arange(n) + 0.5) / n * 2 * HALF - HALF
    x, z = np.meshgrid(s, s)
    h = LIGHT_Y - SLAB_TOP
    d2 = x * x + z * z + h * h
    cos = h / np.sqrt(d2)
    r = _fresnel(cos, ETA)
    domega = cos / d2 * (2 * HALF / n) ** 2
    return float(np.sum((1 - r) / (1 + r) * domega))


def _photons(scene, count, aim, seed=3):
    geom = Geometry(scene)
    lights = LightSampler(scene, geom)
    return build_photon_set(scene, geom, lights, seed, 0, count, 0.01, 8, aim=aim)


def test_photons_through_glass_slab_carry_fresnel_transmitted_flux():
    # One set of 20000 photons spreads ~0.7% around the flux with the seed (the Fresnel choices
    # and the randomly paired higher dimensions): four sets, so the 1% bound is ~3 sigma.
    got = []
    for seed in range(4):
        ph = _photons(slab_scene(), 20000, aim=True, seed=seed)
        # Aiming: ~half the photons are stored (the six faces' spheres overlap the slab), against
        # the ~6% of the sphere of directions the slab subtends from the light.
        assert len(ph) > 0.3 * 20000
        assert np.all(ph.position[:, 1] == pytest.approx(0.0, abs=1e-6))  # stored on the floor only
        got.append(ph.power[:, 0].sum())
    assert np.mean(got) == pytest.approx(expected_transmitted_flux(), rel=0.01)


def test_aiming_on_and_off_agree_in_expectation():
    scene = slab_scene()
    aimed = _photons(scene, 20000, aim=True).power[:, 0].sum()
    # Without aiming only ~6% of photons reach the slab: 200k give ~1% relative error.
    blind = [_photons(scene, 100000, aim=False, seed=s).power[:, 0].sum() for s in (1, 2)]
    assert np.mean(blind) == pytest.approx(aimed, rel=0.03)


def test_specular_targets_are_bounding_spheres_of_mirror_and_glass_meshes():
    scene = slab_scene()
    c, r = specular_targets(scene, Geometry(scene))
    assert len(r) == 6  # the slab's six faces are six meshes
    v = np.concatenate([m.vertices for m in scene.meshes[:6]])
    for ci, ri, m in zip(c, r, scene.meshes[:6]):
        assert np.all(np.linalg.norm(m.vertices - ci, axis=1) <= ri)
    assert np.all(np.abs(c[:, 1] - 0.95) <= 0.06) and v[:, 1].min() >= 0.9 - 1e-12


def test_no_specular_surface_means_no_photons_and_no_grid():
    scene = load_scene(SHARED / "scenes" / "cornell-box" / "scene.xml")
    r = Renderer(scene)
    assert not r.plan.caustics
    from igi.common.params import make_params
    ph = r.photon_set(0, 0, make_params())
    assert len(ph) == 0 and ph.grid is None


def test_caustic_scene_builds_photons_in_a_grid():
    scene = load_scene(SHARED / "scenes" / "cornell-box-sphere" / "scene.xml")
    r = Renderer(scene)
    assert r.plan.caustics
    from igi.common.params import make_params
    ph = r.photon_set(0, 0, make_params(photons=500))
    assert len(ph) > 0 and ph.grid is not None
    assert ph.shot == 500


def test_photon_sets_built_together_equal_each_built_alone():
    """A frame's photon sets traced in one batch are bit for bit the sets each builds alone,
    photons in the same (light, trace) order, with two lights shooting."""
    from dataclasses import replace

    from igi.worker.caustics import build_photon_sets, photon_counts

    scene = slab_scene()
    second = replace(scene.emitters[0], position=np.array([0.3, 1.6, -0.2]), intensity=np.array([2.0, 1.0, 0.5]))
    scene = Scene(scene.meshes, scene.materials, [scene.emitters[0], second], scene.camera)
    geom = Geometry(scene)
    lights = LightSampler(scene, geom)
    ks = [2, 0, 5]
    together = build_photon_sets(scene, geom, lights, 4, ks, 300, 0.01, 8)
    shot = int(photon_counts(lights.powers, 300).sum())
    for k, s in zip(ks, together):
        alone = build_photon_set(scene, geom, lights, 4, k, 300, 0.01, 8)
        assert len(s) > 50 and s.shot == alone.shot == shot
        for name in ("position", "power", "direction", "normal", "depth"):
            np.testing.assert_array_equal(getattr(s, name), getattr(alone, name), err_msg=name)
    assert together[0].power[:, 2].min() < together[0].power[:, 2].max()  # both lights' photons in it


def test_photons_are_shared_by_power_and_each_light_keeps_its_flux():
    """photon_counts: equal lights get photons_per_light each (the paper's count), unequal ones
    share photons_per_light × their effective number by power, a dim one still gets its floor;
    and the caustic flux stays the sum of the lights' (each light's photons count 1/its own
    number): a second light of 9× the intensity at the same place carries 10× the flux."""
    from dataclasses import replace

    from igi.worker.caustics import MIN_PHOTON_SHARE, photon_counts

    assert list(photon_counts(np.full(4, 3.0), 500)) == [500] * 4
    c = photon_counts(np.array([200.0, 380.0, 0.1, 0.1]), 500)
    assert c[1] > c[0] > c[2] == c[3] == MIN_PHOTON_SHARE * 500
    assert 500 * 1.8 < c.sum() < 500 * 2.2  # two lights' worth, not four
    # A dim light above the slab and a 9x one far to its side: per unit power the first sends
    # far more light through the slab, so a wrong per-light weight would change the sum.
    base = slab_scene()
    side = replace(base.emitters[0], intensity=np.full(3, 9.0), position=np.array([2.5, 1.5, 0.0]))

    def flux(emitters, seeds=range(3)):
        scene = Scene(base.meshes, base.materials, emitters, base.camera)
        geom = Geometry(scene)
        lights = LightSampler(scene, geom)
        return np.mean([build_photon_set(scene, geom, lights, s, 0, 20000, 0.01, 8).power[:, 0].sum()
                        for s in seeds]), lights

    both, lights = flux([base.emitters[0], side])
    counts = photon_counts(lights.powers, 20000)
    assert counts[1] > 5 * counts[0]
    alone_a, alone_b = flux([base.emitters[0]])[0], flux([side])[0]
    assert alone_a > 2 * alone_b  # the weights matter: the dim light carries most of the caustic
    assert both == pytest.approx(alone_a + alone_b, rel=0.02)


def test_photons_are_built_from_the_shortest_path_depth_a_caustic_has():
    """A caustic seen directly, eye -> diffuse -> glass -> light, has 3 segments as Mitsuba
    counts them: --max-depth 3 keeps the caustic photons (it once dropped them below 4);
    direct light only (2) needs none."""
    from igi.common.params import make_params

    r = Renderer(load_scene(SHARED / "scenes" / "cornell-box-sphere" / "scene.xml"))
    assert len(r.photon_set(0, 0, make_params(photons=500, max_depth=3))) > 0
    assert len(r.photon_set(0, 0, make_params(photons=500, max_depth=2))) == 0


def test_caustic_share_is_the_flux_the_pilot_set_stores_over_the_lights_flux():
    """worker.caustics.caustic_share of the slab scene: the Fresnel-transmitted flux through the
    slab over the point light's 4π I (~6% of it), from a pilot set of 4000 photons."""
    from igi.worker.caustics import caustic_share

    scene = slab_scene()
    geom = Geometry(scene)
    share = caustic_share(scene, geom, LightSampler(scene, geom), 4000, 8)
    assert share == pytest.approx(expected_transmitted_flux() / (4 * np.pi), rel=0.05)
    assert caustic_share(scene, geom, LightSampler(scene, geom), 0, 8) == 0.0


def test_boosted_photons_grow_with_the_square_of_the_caustic_share_up_to_the_bound():
    from igi.common.params import PARAM_BY_NAME, PHOTON_BOOST_MAX
    from igi.worker.caustics import boosted_photons

    assert boosted_photons(500, 0.05, 0.1) == 500  # at most the reference share: the count as given
    assert boosted_photons(500, 0.1, 0.1) == 500
    assert boosted_photons(500, 0.2, 0.1) == 2000  # twice the share: four times the photons
    # in steps of √2: a pilot's last digits do not move the count (and every photon of a set)
    assert boosted_photons(500, 0.14, 0.1) == boosted_photons(500, 0.1414, 0.1) == 1000
    assert boosted_photons(500, 0.17, 0.1) == round(500 * 2 ** 1.5)
    assert boosted_photons(500, 0.9, 0.1) == 500 * PHOTON_BOOST_MAX
    assert boosted_photons(500, 0.9, 0.0) == 500  # photon_share 0: off
    assert boosted_photons(90000, 0.9, 0.1) == PARAM_BY_NAME["photons"].max


def test_a_scene_rich_in_caustics_builds_its_sets_with_the_boosted_count():
    """The renderer's sets take photon_count(params): the slab scene (~6% of the light in
    caustics) keeps --photons at the default reference 0.1 and takes the 16x bound at 0.01 —
    but not on a moving view's frames."""
    from igi.common.params import PHOTON_BOOST_MAX, make_params

    r = Renderer(slab_scene())
    for share, want in ((0.1, 500), (0.0, 500), (0.01, 500 * PHOTON_BOOST_MAX)):
        params = make_params(photons=500, photon_share=share)
        assert r.photon_count(params) == want
        assert r.photon_set(0, 0, params).shot == want
    assert r.photon_count(make_params(photons=500, photon_share=0.01, moving_camera=True)) == 500


def _sun_slab_scene(emitter: Emitter) -> Scene:
    scene = slab_scene()
    scene.emitters[:] = [emitter]
    return scene


def _sky_with_sun(rows: tuple[int, int], width: int = 512, height: int = 256) -> np.ndarray:
    """A dim lat-long sky (0.2) with a 2 x 2-texel sun of 5000 at ``rows`` (row 0: straight up)."""
    img = np.full((height, width, 3), 0.2)
    img[rows[0]:rows[1], 100:102] = 5000.0
    return img


def test_a_sun_straight_down_through_a_glass_slab_carries_its_transmitted_irradiance():
    """Distant lights shoot caustic photons: a directional light of irradiance E straight down
    through the 1 × 1 slab stores E · area · (1 - R)/(1 + R) on the floor (80,000 photons: the
    quasi-random aim converges to ~0.1%)."""
    sun = Emitter(DIRECTIONAL, irradiance=np.array([2.0, 1.0, 0.5]), direction=np.array([0.0, -1.0, 0.0]))
    r = _fresnel(np.array([1.0]), ETA)[0]
    got = np.mean([_photons(_sun_slab_scene(sun), 80_000, aim=True, seed=s).power.sum(axis=0) for s in (1, 2)],
                  axis=0)
    assert got == pytest.approx(np.array([2.0, 1.0, 0.5]) * (2 * HALF) ** 2 * (1 - r) / (1 + r), rel=0.005)


@pytest.mark.parametrize("sky", [False, True])
def test_a_suns_aimed_photons_agree_with_unaimed_ones(sky):
    """Aiming at the targets' shadow disks is unbiased: a tilted sun, or an environment map's
    peak, stores the same flux through the slab as photons spread over the scene's whole disk."""
    if sky:
        e = Emitter(CONSTANT, radiance=np.ones(3), image=_sky_with_sun((30, 32)))
    else:
        e = Emitter(DIRECTIONAL, irradiance=np.ones(3), direction=np.array([0.4, -1.0, 0.2]))
    scene = _sun_slab_scene(e)
    aimed = np.mean([_photons(scene, 40_000, aim=True, seed=s).power[:, 0].sum() for s in (1, 2)])
    assert aimed > 0
    # unaimed, ~0.5% of the photons meet the slab: 4 x 400k give ~1.5% (one sigma ~0.6%)
    blind = [_photons(scene, 400_000, aim=False, seed=s).power[:, 0].sum() for s in (1, 2, 3, 4)]
    assert np.mean(blind) == pytest.approx(aimed, rel=0.025)


def test_an_environment_maps_sun_through_the_slab_carries_the_peaks_irradiance():
    """A map's peak (its texels above SKY_PEAK × its mean: the sun) shoots photons, drawn from the
    peak's own distribution: through the slab they carry area × ∫ L_peak cos θ T(θ) dω (the sun
    ~2° off the zenith: the slab's sides take ~0.3%); the dim rest of the sky shoots none."""
    e = Emitter(CONSTANT, radiance=np.ones(3), image=_sky_with_sun((2, 4)))
    scene = _sun_slab_scene(e)
    geom = Geometry(scene)
    lights = LightSampler(scene, geom)
    peak = lights.sky_parts()[1]
    assert peak is not None and peak.image.max() > 0
    assert np.all(peak.image[:, :100] == 0)  # the sky's dim texels stay with the base
    sky, p = peak.sample(np.random.default_rng(0).random((400_000, 2)))
    cos = sky[:, 1]
    r = _fresnel(np.abs(cos), ETA)
    expected = (2 * HALF) ** 2 * np.mean(peak.radiance(sky)[:, 0] / p * np.maximum(cos, 0) * (1 - r) / (1 + r))
    got = np.mean([build_photon_set(scene, geom, lights, s, 0, 80_000, 0.01, 8).power[:, 0].sum() for s in (1, 2)])
    assert got == pytest.approx(expected, rel=0.015)


def test_a_constant_sky_and_a_sun_behind_the_floor_shoot_no_photons():
    """A constant sky has no peak; a directional light from below the floor meets no glass first
    (it starts outside the scene: the floor shades the slab): no photons are stored."""
    const = _sun_slab_scene(Emitter(CONSTANT, radiance=np.ones(3)))
    assert len(_photons(const, 20_000, aim=True)) == 0
    below = _sun_slab_scene(Emitter(DIRECTIONAL, irradiance=np.ones(3), direction=np.array([0.0, 1.0, 0.0])))
    assert len(_photons(below, 20_000, aim=True)) == 0


SUN_DATA = Path(__file__).resolve().parents[1] / "data" / "sun_caustics"


def _seen_diffuse(scene: Scene, w: int, h: int) -> np.ndarray:
    """(h, w): pixels whose first hits (4 sub-pixel rays) are all off mirror/glass, as their
    neighbours' — where the references compare (a light tracer leaves glass black; a sun's glint
    in a glass ball is a sub-pixel firefly both renderers take many frames to average)."""
    from igi.common.camera import camera_rays, resolve_camera
    from igi.common.scene import SPECULAR_KINDS

    cam, fov, w, h = resolve_camera(scene, None, w, h)
    ys, xs = np.divmod(np.arange(w * h), w)
    geom = Geometry(scene)
    ok = np.ones(w * h, bool)
    for jitter in ((0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)):
        hits = geom.intersect(*camera_rays(cam, fov, w, h, xs, ys, jitter))
        mat = hits.material[hits.valid]
        spec = np.isin([scene.materials[m].kind for m in mat], SPECULAR_KINDS)
        ok[np.flatnonzero(hits.valid)[spec]] = False
    # and not beside such a pixel (a reference's pixel there may hold some of the glass)
    return binary_erosion(ok.reshape(h, w), iterations=1, border_value=1)


def _sun_render(name: str, params: dict, frames: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(igi's image at 80 × 60, the reference 2 × 2-block-averaged, the pixels to compare)."""
    from igi.common.image_io import read_image
    from igi.common.metrics import block_average
    from igi.master.inprocess import render_local

    scene = load_scene(SUN_DATA / f"{name}.xml")
    img = render_local(scene, params, frames=frames, width=80, height=60)
    ref = block_average(read_image(SUN_DATA / f"{name}_ref.exr")[..., :3], 2)
    return img, ref, _seen_diffuse(scene, 80, 60)


def _relmse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    return float(np.mean((img[mask] - ref[mask]) ** 2 / (ref[mask] ** 2 + 1e-2)))


def test_an_environment_maps_sun_focused_by_a_glass_ball_matches_the_path_tracer():
    """glass_ball.xml: a glass ball on the ground under an environment map with a small sun
    (Mitsuba's path tracer, 16,384 spp, the reference). The sun's caustic is photon-mapped from the
    map's peak, and the surfaces' mirror/glass chains see the map without it: after 16 frames the
    relMSE is ~0.004 where the camera sees no glass first (the ball's glint is a firefly to both
    renderers), the shadow's mean within 8% (3% measured); without photons the chains find the sun
    as fireflies (0.1, and the shadow +37%)."""
    img, ref, seen = _sun_render("glass_ball", {})
    off, _, _ = _sun_render("glass_ball", {"photons": 0}, frames=4)  # (its fireflies do not average out)
    err, err_off = _relmse(img, ref, seen), _relmse(off, ref, seen)
    assert err < 0.3 * err_off, (err, err_off)
    assert err < 0.01
    shadow = np.zeros_like(seen)
    shadow[35:42, 0:26] = True  # the ball's shadow on the ground, the caustic in it
    shadow &= seen
    assert img[shadow].mean(axis=0) == pytest.approx(ref[shadow].mean(axis=0), rel=0.08)  # without photons: +37%


def test_a_directional_sun_through_a_window_pane_lights_the_room_as_the_reference_does():
    """pane.xml: the window room with a thin glass pane in its window, a directional sun and a
    constant sky (reference: the sun by Mitsuba's light tracer — its path tracer cannot see a
    directional light through glass — plus the sky by its path tracer). The sun's patch on the
    floor comes only from photons: within 10% of the reference inside it after 16 frames (its
    edges are blurred by the photon radius and the filter), the room's mean within 8%; without
    photons the patch is dark and the room lacks the light it throws around."""
    from igi.common.luminance import luminance

    img, ref, seen = _sun_render("pane", {})
    off, _, _ = _sun_render("pane", {"photons": 0}, frames=4)  # (the missing patch is a mean: 4 frames tell)
    patch = seen & binary_erosion(uniform_filter(luminance(ref), 3) > 0.2, iterations=2)
    assert patch.sum() > 50

    def ratio(x: np.ndarray, where: np.ndarray) -> float:
        return float(luminance(x[where].mean(axis=0)) / luminance(ref[where].mean(axis=0)))

    assert ratio(img, patch) == pytest.approx(1.0, abs=0.1)
    assert ratio(off, patch) < 0.2
    assert ratio(img, seen) == pytest.approx(1.0, abs=0.08)
    assert ratio(off, seen) < 0.75


def test_a_suns_photons_are_boosted_by_its_caustic_share_of_the_view():
    """The share that boosts a sun's photons is taken on the view (caustics.distant_view_share):
    inside the window room all the sun's light comes through the pane — the full boost; a glass
    ball on a sunlit lawn focuses a small part of the sun's light on the view — none. (Measured
    by flux through the scene's disk, both shares are small: the sun mostly lights the roof.)"""
    from igi.common.camera import resolve_camera
    from igi.common.params import PHOTON_BOOST_MAX, make_params
    from igi.worker.caustics import distant_view_share
    from igi.worker.vpl_importance import View

    params = make_params()
    for name, boosted in (("pane", True), ("glass_ball", False)):
        scene = load_scene(SUN_DATA / f"{name}.xml")
        r = Renderer(scene)
        view = View.of(*resolve_camera(scene))
        share = distant_view_share(scene, r.geom, r.lights, r.camera_pool(params, view).first(1024), params.photons,
                                   params.specular_depth, r._specular_targets)
        assert (share > 0.9) if boosted else (share < params.photon_share), (name, share)
        assert r.photon_count(params) == params.photons  # the flux share: below --photon-share in both
        want = int(params.photons * PHOTON_BOOST_MAX) if boosted else params.photons
        assert r.photon_count(params, view) == want


def test_the_numpy_chains_see_the_map_less_its_peak_as_the_compiled_ones():
    """The surfaces' chains read the sky of ``sky_map`` in their numpy form too: the base's
    radiance where the peak's photons are shot, the whole map's where not."""
    from igi.common.params import make_params
    from igi.worker.indirect_caustics import _sky_radiance

    scene = load_scene(SUN_DATA / "glass_ball.xml")
    r = Renderer(scene)
    base, peak = r.lights.sky_parts()
    assert peak is not None and r.chain_sky(make_params()) is base
    assert r.chain_sky(make_params(photons=0)) is r.lights.env_tables  # no photons: the whole map
    g = np.random.default_rng(1)
    d = g.normal(size=(2000, 3))
    d = np.concatenate([d / np.linalg.norm(d, axis=1)[:, None], peak.sample(g.random((20, 2)))[0]])  # and the sun
    whole = r.lights.env_map
    assert _sky_radiance(r.lights, r.lights.env_tables, d) == pytest.approx(whole.radiance(d))
    less = _sky_radiance(r.lights, base, d)
    assert less + peak.radiance(d) == pytest.approx(whole.radiance(d), rel=1e-5)
    assert less.max() < whole.radiance(d).max() / 10  # the sun is gone
