"""Environment maps (common/environment_map.py, common/kernels/environment_map.py): Mitsuba 3's
``envmap`` read as Mitsuba reads it, and sampled where it is bright without bias.

The Mitsuba figures come from tests/data/envmap (made by its make_assets.py with Mitsuba 3's
Python API: ``emitter.eval`` / ``pdf_direction`` on 2,000 random directions of a rotated map)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from igi.common.environment_map import EnvironmentMap, environment_map
from igi.common.loader import load_scene
from igi.common.scene import SceneError

DATA = Path(__file__).resolve().parents[1] / "data" / "envmap"


def _lookup_map(tmp_path: Path, name: str) -> EnvironmentMap:
    """The map of the scene the ``name`` records were made with: lookup.xml (no geometry: loaded
    from a copy with a small ball added, igi renders nothing without triangles) or outdoor.xml."""
    scene = str(np.load(DATA / f"lookup_rays_{name}.npz")["scene"])
    if scene != "lookup.xml":
        return environment_map(load_scene(DATA / scene))
    shutil.copy(DATA / f"{name}.exr", tmp_path / f"{name}.exr")
    xml = (DATA / "lookup.xml").read_text().replace("pattern.exr", f"{name}.exr")
    xml = xml.replace("</scene>", '<shape type="sphere"><float name="radius" value="0.1"/></shape></scene>')
    (tmp_path / "lookup.xml").write_text(xml)
    return environment_map(load_scene(tmp_path / "lookup.xml"))


def _uniform_sphere(rng, n):
    z = 1 - 2 * rng.random(n)
    phi = 2 * np.pi * rng.random(n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@pytest.mark.parametrize("name", ["pattern", "sky"])
def test_radiance_is_mitsubas_bilinear_lookup_of_the_rotated_map(name, tmp_path):
    """Every direction reads what Mitsuba 3's envmap.eval returns for it: the lat-long frame,
    the rotation, the half-texel shift, the periodic column and the rows' polar angles."""
    rec = np.load(DATA / f"lookup_rays_{name}.npz")
    m = _lookup_map(tmp_path, name)
    np.testing.assert_allclose(m.radiance(rec["d"]), rec["L"], rtol=2e-4, atol=1e-5 * float(np.abs(rec["L"]).max()))


@pytest.mark.parametrize("name", ["pattern", "sky"])
def test_the_sampling_density_is_mitsubas_warp(name, tmp_path):
    """The density samples are drawn from is Mitsuba 3's pdf_direction, direction by direction:
    luminance × sin θ of the texel rows, bilinear, over 2π² sin θ (its warp: Hierarchical2D)."""
    rec = np.load(DATA / f"lookup_rays_{name}.npz")
    m = _lookup_map(tmp_path, name)
    np.testing.assert_allclose(m.pdf(rec["d"]), rec["pdf"], rtol=1e-4)


def test_the_sampling_density_is_a_pdf_that_covers_every_lit_direction():
    """The density integrates to 1 over the sphere, is positive wherever the map is not black
    (so L / p is unbiased), and sample() lands where pdf() says, with the pdf pdf() gives."""
    rng = np.random.default_rng(4)
    img = rng.gamma(0.5, 1.0, (9, 14, 3))
    img[3:5, 2:4] = 0.0  # a black patch: its interior need not be sampled
    img[6, 9] = 3000.0  # a sun
    R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    m = EnvironmentMap(img, R)
    d = _uniform_sphere(rng, 400_000)
    p = m.pdf(d)
    assert abs(p.mean() * 4 * np.pi - 1) < 0.02
    lit = m.radiance(d).max(axis=1) > 0
    assert (p[lit] > 0).all()
    w, q = m.sample(rng.random((200_000, 2)))
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(m.pdf(w), q, rtol=1e-9)
    # the integral of L over the sphere: importance-sampled against uniform directions
    est = (m.radiance(w) / q[:, None]).mean(0)
    ref = m.radiance(_uniform_sphere(rng, 2_000_000)).mean(0) * 4 * np.pi
    np.testing.assert_allclose(est, ref, rtol=0.03)
    # the sun's patches take a share of the samples near their share of the power
    sun = m.radiance(w).max(axis=1) > 100
    assert sun.mean() > 0.5


def test_a_constant_map_is_sampled_nearly_uniformly_over_the_sphere():
    """Luminance × sin θ, bilinear between the rows: a constant map's density is the uniform one
    up to the piecewise-linear sin θ (within 3% away from the poles on 33 rows), and its samples
    weighted L / p integrate to 4π L."""
    m = EnvironmentMap(np.full((33, 64, 3), 2.0))
    w, q = m.sample(np.random.default_rng(1).random((200_000, 2)))
    np.testing.assert_allclose(m.radiance(w), 2.0, rtol=1e-6)
    mid = np.abs(w[:, 1]) < 0.9
    np.testing.assert_allclose(q[mid] * 4 * np.pi, 1.0, rtol=0.03)
    np.testing.assert_allclose((m.radiance(w) / q[:, None]).mean(0), 8 * np.pi, rtol=0.01)
    assert np.abs(w.mean(axis=0)).max() < 0.01


def test_the_samples_follow_the_mitsuba_frames_sun_direction(tmp_path):
    """The brightest direction Mitsuba reports for the sky of outdoor.xml (rotated by its
    to_world) is where the map's samples crowd (the samples' frame is the lookup's)."""
    rec = np.load(DATA / "lookup_rays_sky.npz")
    sun_mi = rec["d"][np.argmax(rec["L"].sum(axis=1))]
    m = _lookup_map(tmp_path, "sky")
    w, _q = m.sample(np.random.default_rng(2).random((20_000, 2)))
    bright = w[m.radiance(w).sum(axis=1) > 1000]
    assert len(bright) > 1000
    assert float(bright.mean(axis=0) @ sun_mi) > 0.95


def _scene(tmp_path, emitters: str, sky: np.ndarray | None = None) -> Path:
    from igi.common.image_io import write_exr

    if sky is not None:
        write_exr(tmp_path / "sky.exr", sky)
    p = tmp_path / "scene.xml"
    p.write_text(f"""<scene version="3.0.0">
        <shape type="sphere"><float name="radius" value="1"/></shape>
        {emitters}
    </scene>""")
    return p


def test_the_loader_keeps_the_map_its_scale_and_rotation(tmp_path):
    sky = np.random.default_rng(3).random((6, 12, 3)).astype(np.float32)
    p = _scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/>
        <float name="scale" value="2.5"/><transform name="to_world"><rotate y="1" angle="90"/></transform></emitter>""",
               sky)
    scene = load_scene(p)
    (e,) = scene.emitters
    np.testing.assert_allclose(e.image, sky * 2.5, rtol=1e-6)
    np.testing.assert_allclose(e.to_world @ [1.0, 0, 0], [0, 0, -1.0], atol=1e-6)
    np.testing.assert_allclose(e.radiance, environment_map(scene).mean)
    assert not any("envmap" in w for w in scene.warnings)  # no longer a fallback


@pytest.mark.parametrize("emitters, words", [
    ("""<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>
        <emitter type="constant"/>""", "only one environment emitter"),
    ("""<emitter type="envmap"><string name="filename" value="none.exr"/></emitter>""", "none.exr"),
    ("""<emitter type="envmap"/>""", "needs a filename"),
])
def test_bad_environment_maps_are_errors_that_name_the_problem(tmp_path, emitters, words):
    p = _scene(tmp_path, emitters, np.ones((4, 8, 3), np.float32))
    with pytest.raises(SceneError, match=words):
        load_scene(p)


def test_a_map_with_nan_is_refused_naming_it(tmp_path):
    sky = np.ones((4, 8, 3), np.float32)
    sky[1, 2, 0] = np.nan
    p = _scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>""", sky)
    with pytest.raises(SceneError, match="non-finite"):
        load_scene(p)


def test_a_map_travels_to_the_workers_whole_and_an_edit_of_its_radiance_scales_it(tmp_path):
    """The scene codec carries the map and its rotation (a worker's sky is the master's, bit for
    bit; a changed map changes the digest), and a viewer's edit of the sky's radiance — the
    map's mean — scales the map to the new mean."""
    from igi.common.scene_codec import apply_edit, decode_scene, encode_scene

    sky = np.random.default_rng(5).random((6, 12, 3)).astype(np.float32) + 0.1
    p = _scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/>
        <transform name="to_world"><rotate x="1" angle="25"/></transform></emitter>""", sky)
    scene = load_scene(p)
    back = decode_scene(encode_scene(scene))
    np.testing.assert_array_equal(back.emitters[0].image, scene.emitters[0].image)
    np.testing.assert_array_equal(back.emitters[0].to_world, scene.emitters[0].to_world)
    assert back.digest() == scene.digest()
    brighter = apply_edit(scene, {"op": "set_emitter", "emitter": 0, "param": "radiance",
                                  "value": (2 * scene.emitters[0].radiance).tolist()})
    np.testing.assert_allclose(brighter.emitters[0].image, 2 * scene.emitters[0].image, rtol=1e-6)
    np.testing.assert_allclose(environment_map(brighter).mean, 2 * environment_map(scene).mean, rtol=1e-6)
    assert brighter.digest() != scene.digest()


def test_a_sample_on_a_pole_row_or_a_nan_direction_carries_no_infinity():
    """u0 = 0 picks the zenith's patch row, where the density (∝ sin θ) vanishes on the row
    itself: the sample lands just off it, with a positive pdf; a NaN direction reads nothing."""
    m = EnvironmentMap(np.random.default_rng(6).random((6, 8, 3)) + 0.1)
    w, p = m.sample(np.array([[0.0, 0.3], [1.0 - 1e-16, 0.7], [0.0, 0.0]]))
    assert np.all(p > 0) and np.all(np.isfinite(p))
    assert np.all(np.isfinite(m.radiance(w) / p[:, None]))
    assert np.all(m.radiance(np.full((1, 3), np.nan)) == 0) and m.pdf(np.full((1, 3), np.nan))[0] == 0


def test_a_maps_radiance_edit_to_zero_is_refused_and_a_rotation_must_be_one(tmp_path):
    from igi.common.scene_codec import apply_edit, decode_scene, encode_scene

    p = _scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>""",
               np.ones((4, 8, 3), np.float32))
    scene = load_scene(p)
    with pytest.raises(ValueError, match="not set to 0"):
        apply_edit(scene, {"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [0, 1, 1]})
    scene.emitters[0].to_world = np.diag([2.0, 1.0, 1.0])  # a scale, not a rotation
    with pytest.raises(SceneError, match="rotation"):
        decode_scene(encode_scene(scene))


def test_a_map_beyond_the_memory_budget_is_refused_naming_its_size(tmp_path):
    from igi.common.limits import set_memory_budget

    p = _scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>""",
               np.ones((64, 128, 3), np.float32))
    set_memory_budget("1M")
    try:
        with pytest.raises(SceneError, match=r"128x64 needs .* over half the memory budget"):
            load_scene(p)
    finally:
        set_memory_budget(None)
    assert environment_map(load_scene(p)).shape == (64, 128)


def test_a_radiance_hdr_map_loads_as_its_exr_twin(tmp_path):
    """Poly Haven and most HDRI libraries ship Radiance .hdr files: the map reads the same (to
    RGBE's precision) as an OpenEXR of the same pixels."""
    import cv2

    sky = np.random.default_rng(8).uniform(0.2, 2.0, (6, 12, 3)).astype(np.float32)
    cv2.imwrite(str(tmp_path / "sky.hdr"), sky[..., ::-1])
    hdr = load_scene(_scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.hdr"/></emitter>"""))
    exr = load_scene(_scene(tmp_path, """<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>""",
                            sky))
    a, b = hdr.emitters[0].image, exr.emitters[0].image  # one exponent a pixel: a step of 1/256 of its brightest
    assert np.all(np.abs(a - b) <= b.max(axis=2, keepdims=True) / 128)


def test_peak_split_sums_to_the_map_and_bounds_the_base():
    """A map splits texel by texel into base + peak: every lookup (bilinear between texels) of
    the two sums to the map's, the base's texels stay at or below the bound (ratio × the map's
    mean luminance, their colour kept) and the peak holds only the texels above it — off the
    pole rows, where the map's sampling density is 0."""
    from igi.common.luminance import luminance

    g = np.random.default_rng(3)
    img = 0.5 + g.random((32, 64, 3))
    img[10:12, 20:22] = [4000.0, 3000.0, 2000.0]  # a sun
    img[20, 40] = [2000.0, 1.0, 1.0]  # a bright red texel, above the bound (~170) by its red alone
    img[0, 5] = [900.0, 900.0, 900.0]  # a bright texel on the pole row
    full = EnvironmentMap(img)
    base, peak = full.peak_split(16.0)
    bound = 16.0 * luminance(full.mean)
    assert luminance(base.image[1:-1]).max() <= bound * (1 + 1e-6)  # (float32 texels)
    over = luminance(img) > bound
    assert over.sum() == 6 and over[0, 5]
    over[0] = False  # a pole row's texel stays in the base: its sampling density vanishes there
    assert np.all(peak.image[~over] == 0) and np.all(peak.image[over] > 0)
    assert base.image[0, 5] == pytest.approx(img[0, 5])
    red = base.image[20, 40]
    assert red / red.sum() == pytest.approx(img[20, 40] / img[20, 40].sum())  # colour kept
    d = _uniform_sphere(g, 5000)
    # (the maps keep float32 texels: the sum rounds in their last bits)
    assert base.radiance(d) + peak.radiance(d) == pytest.approx(full.radiance(d), rel=1e-6, abs=1e-9)
    # a map without texels above the bound has no peak, and its base is itself
    calm_base, calm_peak = EnvironmentMap(0.5 + g.random((16, 32, 3))).peak_split(16.0)
    assert calm_peak is None and calm_base.image.max() < 2
