"""The eye path is split at the first hit per BSDF component (Wald et al. 2002 §4): smooth
rough plastics become a diffuse-layer end point (filtered) plus one traced glossy-lobe branch,
smooth rough conductors a traced branch only; rougher surfaces stay single end points."""
from __future__ import annotations

import numpy as np

from igi.bench.stress_scenes import load_shared
from igi.common.camera import camera_rays
from igi.common.scene import ROUGHPLASTIC, ROUGHPLASTIC_DIFFUSE
from igi.common.sobol_stream import rng
from igi.worker.renderer import Renderer
from igi.worker.shading import trace_eye


def _eye(r, alpha, w=32, h=24):
    cam = r.scene.camera
    ys, xs = np.mgrid[0:h, 0:w]
    o, d = camera_rays(cam.to_world, cam.fov_x, w, h, xs.ravel() * cam.width / w, ys.ravel() * cam.height / h)
    return trace_eye(r.scene, r.geom, r.lights, o, d, -1, 8, rng(0, 3), alpha)


def test_smooth_rough_plastic_splits_into_diffuse_layer_and_lobe_branch():
    r = Renderer(load_shared("cornell-box-glossy"))  # floor alpha 0.156, sphere 0.2425
    whole = _eye(r, 0.0).end
    split = _eye(r, 0.3).end
    assert np.any(whole.sp.kind == ROUGHPLASTIC) and not np.any(whole.sp.kind == ROUGHPLASTIC_DIFFUSE)
    layer = split.sp.kind == ROUGHPLASTIC_DIFFUSE
    first = layer & (split.segments == 1)
    assert first.any() and np.all(split.main[first])  # the diffuse layer is the filtered main end point
    lobe_pixels = set(split.pixel[~split.main])
    assert set(split.pixel[layer]) <= lobe_pixels | set()  # every split pixel also traced its lobe
    assert np.all(split.segments[~split.main] >= 2)
    # a threshold below every alpha splits nothing
    none = _eye(r, 0.1).end
    assert not np.any(none.sp.kind == ROUGHPLASTIC_DIFFUSE)


def test_smooth_rough_conductor_floor_has_no_vpl_lit_end_point():
    r = Renderer(load_shared("veach-ajar"))  # floor: roughconductor alpha 0.1
    from igi.common.scene import ROUGHCONDUCTOR

    whole = _eye(r, 0.0).end
    split = _eye(r, 0.3).end
    first = lambda e: e.main & (e.segments == 1)  # noqa: E731
    assert np.any(whole.sp.kind[first(whole)] == ROUGHCONDUCTOR)
    smooth_first = first(split) & (split.sp.kind == ROUGHCONDUCTOR) & (split.sp.alpha < 0.3)
    assert not smooth_first.any()


def _frames(scene, n, params=None, renderer=None):
    """Per-frame images of a consistent accumulation (seeds 0..n-1)."""
    from igi.master.inprocess import render_local

    frames, prev = [], None

    def keep(i, img):
        nonlocal prev
        cur = img.astype(np.float64)
        frames.append(cur * (i + 1) - (prev * i if prev is not None else 0.0))
        prev = cur

    render_local(scene, params, n, on_frame=keep, renderer=renderer)
    return np.stack(frames)


def test_lobe_light_samples_cut_the_noise_of_a_lamp_seen_in_a_smooth_floor(monkeypatch):
    # All the image is the lamp's reflection in a smooth floor (alpha 0.05). The lobe's traced
    # ray alone finds the small lamp rarely and then hugely; with the lobe's own light samples,
    # MIS-weighted against the ray (one-sample MIS, Veach), the frames are far less noisy and
    # estimate the same image.
    import igi.worker.renderer as renderer
    from tests.support.scenes_synthetic import glossy_floor_lamp

    scene = glossy_floor_lamp()
    params = {"photons": 0, "indirect_vpls": 0, "filter_window": 1}
    with_mis = _frames(scene, 16, params)
    monkeypatch.setattr(renderer, "LightMIS", lambda *a: None)  # the lobe ray alone
    alone = _frames(scene, 16, params)
    lit = with_mis.mean(axis=(0, 3)) > 0.01  # the reflection's pixels
    assert lit.mean() > 0.05
    var_mis = with_mis.var(axis=0).mean(axis=-1)[lit].mean()
    var_alone = alone.var(axis=0).mean(axis=-1)[lit].mean()
    assert var_mis < 0.2 * var_alone, (var_mis, var_alone)
    # the same image: totals over the reflection agree within the ray-alone estimate's noise
    se = np.sqrt(var_alone * lit.sum() / len(alone)) / lit.sum()
    m_mis, m_alone = with_mis.mean(axis=(0, 3))[lit].mean(), alone.mean(axis=(0, 3))[lit].mean()
    assert abs(m_mis - m_alone) < 4 * se + 0.02 * m_alone, (m_mis, m_alone, se)


def test_a_lobe_taking_fewer_emitter_samples_estimates_the_same_image_with_fewer_rays():
    # 16 emitter samples per set; the split lobe takes the first 4 (reweighted, MIS counting
    # 4): the same reflection in expectation, with fewer shadow rays.
    from igi.worker.renderer import Renderer
    from tests.support.scenes_synthetic import glossy_floor_lamp

    scene = glossy_floor_lamp()
    frames, rays = {}, {}
    for samples in (0, 4):
        r = Renderer(scene)
        params = {"photons": 0, "indirect_vpls": 0, "filter_window": 1, "direct_vpls": 16,
                  "lobe_light_samples": samples}
        frames[samples] = _frames(scene, 24, params, renderer=r)
        rays[samples] = r.geom.counters["occluded_rays"]
    assert rays[4] < 0.5 * rays[0]
    lit = frames[0].mean(axis=(0, 3)) > 0.01
    assert lit.mean() > 0.05
    means = {s: f.mean(axis=(0, 3))[lit].mean() for s, f in frames.items()}
    se = np.sqrt(sum(f.mean(axis=-1)[:, lit].mean(axis=1).var() / len(f) for f in frames.values()))
    assert abs(means[4] - means[0]) < 4 * se + 0.01 * means[0], (means, se)


def _tile_pixels_and_fresnel(scene):
    """Pixels whose centre and four neighbours' centres see the furnace's plastic tile (mesh 6),
    and the coat's Fresnel reflectance along each centre's eye ray."""
    from igi.common.fresnel import fresnel_dielectric

    cam, tile = scene.camera, scene.meshes[6]
    w, h = cam.width, cam.height
    ys, xs = np.mgrid[0:h, 0:w]
    o, d = camera_rays(cam.to_world, cam.fov_x, w, h, xs.ravel(), ys.ravel())
    v = tile.vertices
    n = np.cross(v[1] - v[0], v[2] - v[0])
    n /= np.linalg.norm(n)
    t = ((v[0] - o) @ n) / (d @ n)
    p = o + t[:, None] * d - v[0]
    e1, e2 = v[1] - v[0], v[3] - v[0]
    a, b = p @ e1 / (e1 @ e1), p @ e2 / (e2 @ e2)
    hit = ((a > 0) & (a < 1) & (b > 0) & (b < 1)).reshape(h, w)
    inner = hit.copy()
    inner[1:-1, 1:-1] &= hit[:-2, 1:-1] & hit[2:, 1:-1] & hit[1:-1, :-2] & hit[1:-1, 2:]
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    f = fresnel_dielectric(-(d @ n), scene.materials[1].int_ior / scene.materials[1].ext_ior)[0]
    return inner, f.reshape(h, w)


def test_a_smooth_plastics_coat_mirrors_the_light_of_lit_surfaces_not_only_of_emitters():
    # A black-bodied smooth plastic tile in a furnace whose walls emit Le and reflect half:
    # every wall shines Le / (1 - 1/2) = 2 Le, so the tile shows F(θ) × 2 Le — its coat's mirror
    # image of the walls. Left whole, the tile's end point could only see the walls' emission
    # through its BSDF rays (F × Le: half), and that through the filter.
    from igi.master.inprocess import render_local
    from tests.support.scenes_synthetic import plastic_tile_in_furnace

    scene = plastic_tile_in_furnace(0.5, 1.0)
    img = render_local(scene, {"photons": 0}, 12).astype(np.float64).mean(axis=-1)
    inner, fresnel = _tile_pixels_and_fresnel(scene)
    assert inner.sum() > 60
    walls = np.median(img[~inner & (img > 1.0)])
    assert abs(walls - 2.0) < 0.15, walls  # the furnace's own answer, up to the tile's shadow
    ratio = img[inner] / (fresnel[inner] * walls)
    assert abs(np.median(ratio) - 1.0) < 0.08, np.median(ratio)
    assert np.all(np.abs(ratio - 1.0) < 0.3), (ratio.min(), ratio.max())


def test_a_smooth_plastic_splits_into_its_diffuse_layer_and_its_coats_mirror_ray():
    from igi.common.scene import PLASTIC
    from tests.support.scenes_synthetic import plastic_tile_in_furnace

    scene = plastic_tile_in_furnace(0.5, 1.0, diffuse=0.6)
    r = Renderer(scene)
    inner, _f = _tile_pixels_and_fresnel(scene)
    tile_pixels = np.flatnonzero(inner.ravel())
    for alpha in (0.3, 0.0):
        end = _eye(r, alpha, scene.camera.width, scene.camera.height).end
        on_tile = np.isin(end.pixel, tile_pixels)
        first = on_tile & (end.segments == 1)
        assert set(end.pixel[first]) == set(tile_pixels)
        assert np.all(end.sp.kind[first] == PLASTIC) and np.all(end.main[first])
        if alpha > 0:
            # the layer: no coat (it never samples the mirror); the mirror's hits on the walls:
            # one more end point per tile pixel, not the pixel's main one
            np.testing.assert_array_equal(end.sp.specular[first], 0.0)
            np.testing.assert_array_equal(end.sp.sampling_weight()[first], 0.0)
            mirrored = on_tile & (end.segments == 2)
            assert sorted(end.pixel[mirrored]) == sorted(tile_pixels)
            assert not np.any(end.main[mirrored])
            np.testing.assert_array_equal(end.sp.kind[mirrored], 0)  # DIFFUSE walls
        else:  # not split: the whole plastic, its coat included
            assert np.all(end.sp.specular[first] > 0) and not np.any(on_tile & (end.segments > 1))


def test_a_smooth_plastic_behind_a_dim_mirror_ray_ends_the_path_unsplit():
    # In a box of smooth plastics every coat's mirror ray meets another: split again each time,
    # a pixel gathered ~9 end points. Along a chain a smooth plastic splits only while its path
    # carries a quarter of the light (common.bsdf.SPLIT_THROUGHPUT); a dimmer one is an end point
    # whole, its coat intact.
    from igi.common.bsdf import SPLIT_THROUGHPUT
    from igi.common.lights import luminance
    from igi.common.scene import PLASTIC
    from tests.support.scenes_synthetic import plastic_box

    scene = plastic_box(48, 48)
    r = Renderer(scene)
    end = _eye(r, 0.3, 48, 48).end
    deep = (end.sp.kind == PLASTIC) & (end.segments >= 2)
    assert deep.sum() > 1000
    split = np.all(end.sp.specular == 0, axis=1)
    np.testing.assert_array_equal(split[deep], luminance(end.throughput[deep]) >= SPLIT_THROUGHPUT)
    assert len(end) < 2.6 * 48 * 48  # (a bright chain's plastic still splits: test_eye_paths_kernel's mirror)
