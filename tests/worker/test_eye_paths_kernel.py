"""The compiled eye paths (worker.kernels.eye_paths.trace_eye: first hits, their split at
mirrors and glass, the chains behind) give worker.shading.trace_eye exactly what its numpy form
gives, on a glass ball with and without a sky, at path-length limits, and in a room without glass."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from igi.bench.stress_scenes import load_shared
from igi.common.geometry import Geometry


def _eye(monkeypatch, compiled: bool, max_depth: int, sky: bool, name: str = "cornell-box-sphere",
         light_mis=None, scene=None):
    """worker.shading.trace_eye through ``name`` (96×72; cornell-box-sphere: the light seen in
    the glass ball): its result and the next draw of its generator, traced by
    kernels.eye_paths.trace_eye — first hits, then the chains by specular_chain.eye_chains —
    (``compiled``) or by the numpy form; ``scene`` instead of ``name``'s."""
    from igi.common.camera import camera_rays, resolve_camera
    from igi.common.lights import LightSampler
    from igi.worker.shading import trace_eye

    scene = load_shared(name) if scene is None else scene
    geom = Geometry(scene)
    lights = LightSampler(scene, geom)
    if not compiled:
        monkeypatch.setattr(geom, "closest_terms", lambda: None)
    if sky:
        monkeypatch.setattr(lights, "environment", lambda: np.array([0.5, 0.4, 0.3]))
    cam, fov, w, h = resolve_camera(scene, None, 96, 72)
    ys, xs = np.divmod(np.arange(w * h), w)
    o, d = camera_rays(cam, fov, w, h, xs, ys)
    g = np.random.default_rng(4)
    eye = trace_eye(scene, geom, lights, o, d, max_depth, 8, g, 0.3, light_mis)
    return eye, g.random(), geom.counters["intersect_rays"]


@pytest.mark.parametrize("max_depth", [-1, 3, 1])
@pytest.mark.parametrize("sky", [False, True])
def test_compiled_eye_paths_equal_the_numpy_eye_paths(monkeypatch, max_depth, sky):
    """kernels.eye_paths.trace_eye gives trace_eye what its numpy form gave, bit for bit: the end
    points (and their surfaces), the unfiltered light, depth and normals, the draws, the rays."""
    got, got_next, got_rays = _eye(monkeypatch, True, max_depth, sky)
    monkeypatch.undo()
    want, want_next, want_rays = _eye(monkeypatch, False, max_depth, sky)
    assert (got_next, got_rays) == (want_next, want_rays)
    for name in ("unfiltered", "depth", "normal"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    for name in ("pixel", "position", "ns", "ng", "wi", "throughput", "segments", "main", "distance"):
        np.testing.assert_array_equal(getattr(got.end, name), getattr(want.end, name), err_msg=name)
    for name in ("kind", "diffuse", "alpha"):
        np.testing.assert_array_equal(getattr(got.end.sp, name), getattr(want.end.sp, name), err_msg=name)
    chained = got.end.segments > 1
    if max_depth == 1:  # no chain may start
        assert not chained.any()
        return
    assert chained.sum() > 100  # end points seen through the ball
    if max_depth < 0:  # the light seen in the ball
        assert got.unfiltered[np.unique(got.end.pixel[chained])].max() > 1.0


def test_compiled_eye_paths_of_a_room_without_glass_equal_the_numpy_eye_paths(monkeypatch):
    got = _eye(monkeypatch, True, -1, False, "cornell-box")
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, "cornell-box")
    assert got[1:] == want[1:]
    for name in ("pixel", "position", "ns", "wi", "distance"):
        np.testing.assert_array_equal(getattr(got[0].end, name), getattr(want[0].end, name), err_msg=name)
    np.testing.assert_array_equal(got[0].unfiltered, want[0].unfiltered)
    assert len(got[0].end) > 0.9 * 96 * 72  # (the box is closed: nearly every pixel ends on a wall)


def _same_eye(got, want) -> None:
    assert got[1:] == want[1:]
    for name in ("unfiltered", "depth", "normal"):
        np.testing.assert_array_equal(getattr(got[0], name), getattr(want[0], name), err_msg=name)
    for name in ("pixel", "position", "ns", "ng", "wi", "throughput", "segments", "main", "distance", "direct_only"):
        np.testing.assert_array_equal(getattr(got[0].end, name), getattr(want[0].end, name), err_msg=name)
    for name in ("kind", "diffuse", "specular", "alpha"):
        np.testing.assert_array_equal(getattr(got[0].end.sp, name), getattr(want[0].end.sp, name), err_msg=name)


@pytest.mark.parametrize("name", ["cornell-box-glossy", "veach-bidir"])
@pytest.mark.parametrize("light_samples", [0, 4])
def test_split_smooth_glossy_hits_equal_the_numpy_eye_paths(monkeypatch, name, light_samples):
    """Smooth glossy hits split into the diffuse layer (an end point) and one sampled lobe ray,
    the lobes' light-sample points (direct-only, with ``light_samples`` emitter samples) and the
    MIS weight of the emission a lobe ray meets: the compiled eye paths equal the numpy form."""
    from igi.worker.shading import LightMIS

    mis = LightMIS(light_samples) if light_samples else None
    got = _eye(monkeypatch, True, -1, False, name, mis)
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, name, mis)
    _same_eye(got, want)
    end = got[0].end
    assert (end.direct_only is not None) == (light_samples > 0)
    if light_samples:
        assert end.direct_only.sum() > 100  # the glossy surfaces' lobes took light samples


@pytest.mark.parametrize("light_samples", [0, 4])
def test_smooth_plastics_split_into_layer_and_mirror_ray_equal_the_numpy_eye_paths(monkeypatch, light_samples):
    """A smooth plastic tile, seen directly and in a mirror beside it:
    its layer an end point, its coat one mirror ray (no MIS, no light-sample points) — at the
    first hit and along chains, the compiled eye paths equal the numpy form."""
    from igi.common.scene import PLASTIC
    from igi.worker.shading import LightMIS
    from tests.support.scenes_synthetic import plastic_tile_in_furnace

    scene = plastic_tile_in_furnace(0.5, 1.0, diffuse=0.3, width=96, height=72, mirror_side=True)
    mis = LightMIS(light_samples) if light_samples else None
    got = _eye(monkeypatch, True, -1, False, light_mis=mis, scene=scene)
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, light_mis=mis, scene=scene)
    _same_eye(got, want)
    end = got[0].end
    layers = end.sp.kind == PLASTIC
    assert np.any(layers & (end.segments == 1)) and np.any(layers & (end.segments == 2))  # direct and mirrored
    np.testing.assert_array_equal(end.sp.specular[layers], 0.0)
    assert end.direct_only is None  # a mirror takes no light samples


def test_rough_glass_takes_light_samples_through_the_lobe_facing_out_as_the_numpy_eye_paths(monkeypatch):
    """With the set's emitter samples (LightMIS), each hit on rough glass, first or along a
    chain, is also a direct-only point whose BSDF is its lobe facing the outside: seen from
    outside its reflection (ROUGHDIELECTRIC_R), from inside its refraction out
    (ROUGHDIELECTRIC_T); the emission a ray leaving through that lobe meets is MIS-weighted
    against those samples. The compiled eye paths equal the numpy form, draws included, and the
    traced rays that meet the lamp give it less than their whole light."""
    from igi.common.camera import camera_rays, resolve_camera
    from igi.common.mitsuba_xml import load_mitsuba
    from igi.common.scene import ROUGHDIELECTRIC, ROUGHDIELECTRIC_R, ROUGHDIELECTRIC_T
    from igi.worker.shading import LightMIS
    from tests.support.paths import ROOT

    import igi.worker.shading as shading

    scene = load_mitsuba(ROOT / "tests/data/roughglass/roughglass.xml")
    kernel, ran = shading.ek.trace_eye, []
    monkeypatch.setattr(shading.ek, "trace_eye", lambda *a: ran.append(kernel(*a)) or ran[-1])
    got = _eye(monkeypatch, True, -1, False, scene=scene, light_mis=LightMIS(4))
    assert len(ran) == 1 and ran[0][0] > 0  # the kernel's own end points, not the numpy form's
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, scene=scene, light_mis=LightMIS(4))
    _same_eye(got, want)
    plain = _eye(monkeypatch, True, -1, False, scene=scene)[0]  # (the light-sample points draw nothing)
    end = got[0].end
    out = end.direct_only & (end.sp.kind == ROUGHDIELECTRIC_R)
    through = end.direct_only & (end.sp.kind == ROUGHDIELECTRIC_T)
    assert np.all(end.wi[out, 2] > 0) and np.all(end.wi[through, 2] <= 0)
    # at the first hits: one a pixel whose first hit is rough glass (from outside), at that hit
    cam, fov, w, h = resolve_camera(scene, None, 96, 72)
    ys, xs = np.divmod(np.arange(w * h), w)
    o, d = camera_rays(cam, fov, w, h, xs, ys)
    hits = Geometry(scene).intersect(o, d)
    kind = np.array([m.kind for m in scene.materials] + [-1])[hits.material]
    on_glass = np.flatnonzero(hits.valid & (kind == ROUGHDIELECTRIC))
    assert len(on_glass) > 300
    first = out & (end.segments == 1)
    np.testing.assert_array_equal(np.sort(end.pixel[first]), on_glass)
    np.testing.assert_allclose(end.distance[first], hits.t[end.pixel[first]])
    # along the chains: leaving the balls and the pane from inside, reflected off them outside
    assert np.count_nonzero(through) > 300 and np.all(end.segments[through] > 1)
    assert np.count_nonzero(out & (end.segments > 1)) > 0
    rough = [m for m in scene.materials if m.kind == ROUGHDIELECTRIC]
    np.testing.assert_allclose(np.unique(end.sp.alpha[out | through]), sorted(m.alpha for m in rough), rtol=1e-6)
    # same paths, same draws: the MIS weights only take light away from the traced rays
    assert np.all(got[0].unfiltered <= plain.unfiltered + 1e-12)
    assert got[0].unfiltered[on_glass].sum() < 0.9 * plain.unfiltered[on_glass].sum()
    # the gather lights both kinds as glossy rows, a refraction point from the far side of its eye
    from igi.worker.kernels import vpl_gather as vg
    x, _ns, ng, side, off, row, *_ = shading._receivers(Geometry(scene), end, slice(0, len(end)))
    assert np.all(row[out | through] == vg.ROW_GLOSSY)
    np.testing.assert_array_equal(side[out], 1.0)
    np.testing.assert_array_equal(side[through], 1.0)  # its eye inside (wi's z < 0), lit from outside
    assert np.all(off[out | through] > 0)  # shadow rays leave on the outside


def test_rough_glass_crossed_at_drawn_microfacets_equals_the_numpy_eye_paths(monkeypatch):
    """tests/data/roughglass (a frosted pane, a satin and a milky glass ball): each first hit on
    rough glass split at one drawn microfacet normal, the chains behind sampling theirs — the
    compiled eye paths equal the numpy form, draws included, and the pixels behind the pane see
    through it at scattered places (the pixels' chains do not end where smooth glass's would)."""
    from igi.common.mitsuba_xml import load_mitsuba
    from igi.common.scene import DIELECTRIC, ROUGHDIELECTRIC
    from tests.support.paths import ROOT

    scene = load_mitsuba(ROOT / "tests/data/roughglass/roughglass.xml")
    assert sum(m.kind == ROUGHDIELECTRIC for m in scene.materials) == 3
    got = _eye(monkeypatch, True, -1, False, scene=scene)
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, scene=scene)
    _same_eye(got, want)
    end = got[0].end
    assert np.count_nonzero(end.segments > 2) > 300  # through the balls and the pane
    # the same glass, smooth (new Material objects: materials are immutable, their tables cached)
    scene.materials = [dataclasses.replace(m, kind=DIELECTRIC) if m.kind == ROUGHDIELECTRIC else m
                       for m in scene.materials]
    smooth = _eye(monkeypatch, True, -1, False, scene=scene)[0].end
    pos = np.full((2, 96 * 72, 3), np.nan)
    for k, e in enumerate((end, smooth)):
        sel = e.main & (e.segments > 2)
        pos[k, e.pixel[sel]] = e.position[sel]
    both = np.isfinite(pos[:, :, 0]).all(axis=0)
    assert both.sum() > 100
    assert np.median(np.linalg.norm(pos[0, both] - pos[1, both], axis=1)) > 1e-3


def test_a_kernel_out_of_room_hands_the_tile_to_the_numpy_form_with_its_draws_untouched(monkeypatch):
    """Where the kernel's end-point arrays run out (-1), trace_eye runs its numpy form from the
    generator's state before the kernel drew: the same result as the numpy form alone."""
    from igi.worker.kernels import eye_paths

    real = eye_paths.trace_eye

    def out_of_room(*args):
        real(*args)  # draws from the generator, writes the buffers
        return -1, 0

    monkeypatch.setattr(eye_paths, "trace_eye", out_of_room)
    got = _eye(monkeypatch, True, -1, False)
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False)
    _same_eye(got, want)


def test_split_plastics_with_textured_diffuse_layers_take_the_kernel_and_equal_the_numpy_eye_paths(monkeypatch):
    """grey-white-room's floor and table are smooth plastics whose diffuse colour is a bitmap:
    the kernel samples only their lobes (specular colour and roughness per material), the diffuse
    layer's colour is looked up per end point afterwards, so the kernel serves them — bit for
    bit the numpy form. A split material whose *specular* colour is a bitmap (veach-ajar's
    floor) still takes the numpy form."""
    from igi.common.bsdf import chain_materials
    from igi.worker.kernels import eye_paths

    calls = []
    real = eye_paths.trace_eye
    monkeypatch.setattr(eye_paths, "trace_eye", lambda *a: calls.append(1) or real(*a))
    got = _eye(monkeypatch, True, -1, False, "grey-white-room")
    assert calls
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, "grey-white-room")
    _same_eye(got, want)
    textured = got[0].end.sp.diffuse
    assert len(np.unique(textured[:, 0])) > 50  # texels, not one colour per material
    assert chain_materials(load_shared("grey-white-room").materials, 0.3) is not None
    assert chain_materials(load_shared("veach-ajar").materials, 0.3) is None


def test_lobe_rays_escaping_to_a_guided_sky_take_the_kernel_and_equal_the_numpy_eye_paths(monkeypatch):
    """grey-white-room's sky, seen through its windows, is sampled by an environment guide
    (worker.env_guide); the smooth floor's and table's lobe rays that escape weigh the sky
    against the guide's q(ω) (kernels.environment_bins.guide_pdf) — in the kernel as in the
    numpy form, bit for bit; and the guide changes what those rays add."""
    from igi.common.camera import resolve_camera
    from igi.common.params import make_params
    from igi.worker.kernels import eye_paths
    from igi.worker.renderer import Renderer
    from igi.worker.shading import LightMIS
    from igi.worker.vpl_importance import View

    scene = load_shared("grey-white-room")
    cam, fov, w, h = resolve_camera(scene, None, 96, 72)
    vpls = Renderer(scene).vpl_set(0, 0, make_params(), view=View.of(cam, fov, w, h))
    assert vpls.env_guide is not None
    mis = LightMIS(4, vpls.env_guide, vpls.emitter_pmf)
    calls = []
    real = eye_paths.trace_eye
    monkeypatch.setattr(eye_paths, "trace_eye", lambda *a: calls.append(1) or real(*a))
    got = _eye(monkeypatch, True, -1, False, "grey-white-room", mis)
    assert calls, "the guided sky kept the tile out of the kernel"
    monkeypatch.undo()
    want = _eye(monkeypatch, False, -1, False, "grey-white-room", mis)
    _same_eye(got, want)
    unguided = _eye(monkeypatch, True, -1, False, "grey-white-room", LightMIS(4, None, vpls.emitter_pmf))
    assert not np.array_equal(got[0].unfiltered, unguided[0].unfiltered)
