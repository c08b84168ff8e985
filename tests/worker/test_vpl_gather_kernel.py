"""The compiled VPL gather (worker.kernels.vpl_gather via worker.shading.gather_vpls) equals
the numpy implementation it replaced (tests/oracle_vpl_gather.py) on real and hostile inputs:
glossy receivers and senders, spots, points on a surface, VPLs coincident with end points,
grazing eyes, NaN/Inf end points, path-length limits and empty inputs."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.support.oracle_vpl_gather import gather_vpls_numpy, lobe_guesses_numpy, shadow_roulette
from igi.bench.stress_scenes import (eye_end_points, grazing_camera, load_shared, merge_vpl_sets, vpls_at,
                                     with_extra_lights, with_nonfinite_positions)
from igi.common.lights import LUMINANCE_WEIGHTS
from igi.worker.renderer import Renderer
from igi.worker.shading import gather_vpls
from igi.worker.vpl import build_vpl_set

CLAMP = 1e-3


def _agree(renderer, end, vpls, max_depth=-1, force_general=False):
    c2 = CLAMP * renderer.geom.diagonal ** 2
    a1, i1 = gather_vpls(renderer.geom, end, vpls, c2, max_depth, force_general=force_general)
    a2, i2 = gather_vpls_numpy(renderer.geom, end, vpls, c2, max_depth, force_general=force_general)
    assert i1.shape == i2.shape
    assert np.all(np.isfinite(i1))
    np.testing.assert_array_equal(a1, a2)
    # Radiance (albedo × irradiance): where an albedo channel is 0 the diffuse-layer rows'
    # scalar irradiance is not the oracle's per-channel 0/ε, but nothing of it is seen.
    r1, r2 = a1 * i1, a2 * i2
    scale = max(float(np.abs(r2).max()), 1e-12) if r2.size else 1.0
    # float32 pair geometry in both; only the summation order differs.
    # (the oracle swaps colours for glossy VPLs by subtraction: a cancellation residue of ~1e-7
    # of the VPL's colour, up to ~1e-4 of the image's largest value where a bright VPL's lobe
    # gives an end point exactly 0)
    np.testing.assert_allclose(r1, r2, rtol=1e-4, atol=max(1e-4 * scale, 1e-5))
    return i1


def _set(renderer, k=0, direct=4, indirect=18):
    return build_vpl_set(renderer.scene, renderer.geom, renderer.lights, 0, k, direct, indirect, 4)


def _scene_columns(scene_name, width, height, k, glossy_split_alpha=0.0):
    """(renderer, eye end points of a width × height image, set k, its gather columns at CLAMP)."""
    from igi.worker import shading

    r = Renderer(load_shared(scene_name))
    end = eye_end_points(r, width, height, glossy_split_alpha=glossy_split_alpha)
    vpls = _set(r, k)
    return r, end, vpls, shading.vpl_columns(vpls, r.geom, CLAMP * r.geom.diagonal ** 2)


@pytest.mark.parametrize("name", ["cornell-box-sphere", "cornell-box-glossy", "veach-ajar", "grey-white-room"])
@pytest.mark.parametrize("force_general", [False, True])
def test_kernel_matches_numpy_on_shared_scenes(name, force_general):
    r = Renderer(load_shared(name))
    end = eye_end_points(r, 32, 24)
    for k in (0, 4):
        out = _agree(r, end, _set(r, k), force_general=force_general)
        assert out.sum() > 0  # something is lit: the comparison is not vacuous


@pytest.mark.parametrize("force_general", [False, True])
def test_kernel_matches_numpy_on_normal_and_bump_mapped_surfaces(force_general):
    """tests/data/bump: end points and VPLs on a normal-mapped floor and a bump-mapped rough
    plastic wall, whose VPLs radiate through their true surface (design note 44)."""
    from igi.common.loader import load_scene
    from tests.support.paths import ROOT

    r = Renderer(load_scene(ROOT / "tests" / "data" / "bump" / "bump.xml"))
    end = eye_end_points(r, 32, 24)
    for k in (0, 4):
        vpls = _set(r, k)
        assert r.geom.bumped(vpls.surface.material_rows()).any()  # VPLs on the mapped surfaces
        out = _agree(r, end, vpls, force_general=force_general)
        assert out.sum() > 0


def test_kernel_matches_numpy_with_spots_points_on_surfaces_and_zero_power_lights():
    r = Renderer(with_extra_lights(load_shared("cornell-box")))
    end = eye_end_points(r, 24, 24)
    _agree(r, end, _set(r, 1, direct=16))


@pytest.mark.parametrize("max_depth", [2, 3, 4])
def test_kernel_respects_path_length_like_numpy(max_depth):
    r = Renderer(load_shared("cornell-box"))
    end = eye_end_points(r, 24, 24)
    _agree(r, end, _set(r, 2), max_depth=max_depth)


def test_kernel_matches_numpy_for_vpls_coincident_with_end_points():
    r = Renderer(load_shared("cornell-box-glossy"))
    end = eye_end_points(r, 16, 16)
    rows = np.arange(0, len(end), 17)
    vpls = merge_vpl_sets(vpls_at(end, rows), _set(r, 3))
    _agree(r, end, vpls)


def test_kernel_matches_numpy_for_a_grazing_eye():
    r = Renderer(grazing_camera(load_shared("cornell-box")))
    end = eye_end_points(r, 24, 24)
    assert len(end) > 0
    _agree(r, end, _set(r, 5))


def test_nonfinite_end_points_give_zero_not_nan():
    r = Renderer(load_shared("cornell-box"))
    bad = with_nonfinite_positions(eye_end_points(r, 12, 12), 5, 7)
    out = _agree(r, bad, _set(r, 6))
    assert np.all(out[::5] == 0)


def test_empty_inputs():
    r = Renderer(load_shared("cornell-box"))
    end = eye_end_points(r, 8, 8)
    vpls = _set(r, 0)
    empty_end = end.subset(np.zeros(0, np.int64))
    a, irr = gather_vpls(r.geom, empty_end, vpls, 1e-3, -1)
    assert irr.shape == (0, 3)
    no_vpls = _set(r, 0, direct=0, indirect=0)
    a, irr = gather_vpls(r.geom, end, no_vpls, 1e-3, -1)
    assert irr.shape == (len(end), 3) and not irr.any()


def test_kernel_matches_numpy_on_split_diffuse_layers():
    """End points of a rough plastic's diffuse layer alone (the first-hit split of smooth
    glossy surfaces) take the kernel's scalar path; the oracle evaluates their BSDF per pair."""
    from igi.common.camera import camera_rays
    from igi.common.scene import ROUGHPLASTIC_DIFFUSE
    from igi.common.sobol_stream import rng
    from igi.worker.shading import trace_eye

    for name in ("cornell-box-glossy", "grey-white-room"):
        r = Renderer(load_shared(name))
        cam = r.scene.camera
        ys, xs = np.mgrid[0:24, 0:32]
        o, d = camera_rays(cam.to_world, cam.fov_x, 32, 24, xs.ravel() * cam.width / 32, ys.ravel() * cam.height / 24)
        end = trace_eye(r.scene, r.geom, r.lights, o, d, -1, 8, rng(0, 2), 0.3).end
        assert np.any(end.sp.kind == ROUGHPLASTIC_DIFFUSE)
        lit = sum(_agree(r, end, _set(r, k))[end.sp.kind == ROUGHPLASTIC_DIFFUSE].sum() for k in range(4))
        assert lit > 0  # not vacuous: some set lights the layers


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
def test_shadow_roulette_is_unbiased_and_traces_fewer_rays(name):
    """Russian roulette on the small pairs' shadow rays (glossy receivers' too): over many seeds
    the mean of the gathered light equals the gather that traces every pair (per end point,
    within its standard error), with fewer shadow rays."""
    r = Renderer(load_shared(name))
    end = eye_end_points(r, 16, 16)
    vpls = _set(r, 2)
    c2 = CLAMP * r.geom.diagonal ** 2
    before = r.geom.counters["occluded_rays"]
    _, exact = gather_vpls(r.geom, end, vpls, c2, -1)
    all_rays = r.geom.counters["occluded_rays"] - before
    runs = []
    before = r.geom.counters["occluded_rays"]
    for seed in range(400):
        runs.append(gather_vpls(r.geom, end, vpls, c2, -1, shadow_roulette=0.5, seed=seed)[1])
    rays = (r.geom.counters["occluded_rays"] - before) / 400
    runs = np.array(runs)
    assert rays < 0.9 * all_rays
    mean, se = runs.mean(axis=0), runs.std(axis=0) / np.sqrt(len(runs))
    assert np.any(se > 0)  # some pairs were rouletted: the comparison is not vacuous
    if name == "cornell-box-glossy":  # glossy receivers' pairs (BSDF factor after the ray) too
        from igi.worker import shading
        from igi.worker.kernels import vpl_gather as vg

        cols = shading.vpl_columns(vpls, r.geom, c2)
        pairs = [shading._pair_rays(r.geom, end, slice(0, len(end)), vpls, cols, -1, roulette=rr)
                 for rr in (None, (0.5, 7))]
        glossy = [np.sum(p[3][p[0]] == vg.ROW_GLOSSY) for p in pairs]
        assert 0 < glossy[1] < glossy[0]
    z = np.abs(mean - exact) / np.maximum(se, 1e-12 * np.abs(exact).max())
    assert np.mean(z > 4) < 0.002
    assert abs(mean.sum() / exact.sum() - 1) < 0.005
    # A different seed draws other pairs; the same seed the same ones.
    a = gather_vpls(r.geom, end, vpls, c2, -1, shadow_roulette=0.5, seed=7)[1]
    np.testing.assert_array_equal(a, runs[7])
    assert not np.array_equal(a, runs[8])


def test_shadow_roulette_keeps_the_big_pairs_and_counts_a_kept_small_one_at_the_threshold():
    """Pairs at or above the fraction of their row's mean always trace, with their weight
    unchanged; a kept small pair counts the threshold and survives with probability
    c/threshold; a dropped one traces no ray; pairs that had none stay without."""
    from igi.worker.kernels import vpl_gather as vg

    w = np.array([10.0, 0.1, -1.0, 0.1, 0.1, 0.1], np.float32)  # column 2: no pair
    lum = np.ones(6)
    live = w >= 0
    total = float(np.sum(w[live].astype(np.float64) * lum[live]))
    threshold = 0.5 * total / 5
    kept = []
    for seed in range(200):
        sw = np.stack([np.full(6, 7.0, np.float32), w])  # row 1 of a staged block
        vg.roulette_row(sw, 1, 6, 0, 5, total, lum, 0.5, seed, 7, vg.column_keys(6))
        assert np.all(sw[0] == 7.0)  # other rows untouched
        row = sw[1]
        assert row[0] == np.float32(10.0) and row[2] == vg._NO_RAY  # the big pair; no pair
        small = row[[1, 3, 4, 5]]
        assert np.all((small == vg._NO_RAY) | np.isclose(small, threshold, rtol=1e-6))
        kept.append(int(np.sum(small >= 0)))
        # the same draws in any block position: a pair's uniform is its (row, column)'s
        again = w[None].copy()
        vg.roulette_row(again, 0, 6, 0, 5, total, lum, 0.5, seed, 7, vg.column_keys(6))
        np.testing.assert_array_equal(again[0], row)
    # each small pair survives with p = 0.1 / threshold
    assert np.mean(kept) / 4 == pytest.approx(0.1 / threshold, abs=0.05)


def test_shadow_roulette_keeps_a_row_of_no_or_negative_light_as_it_is():
    """A row whose mean light is not positive (a black row, or a VPL colour of negative
    luminance from a hostile scene) has no threshold: every pair keeps its ray and weight."""
    from igi.worker.kernels import vpl_gather as vg

    for lum in (np.array([-1.0, -1.0, -2.0]), np.array([1.0, -1.0, -3.0]), np.zeros(3)):
        w = np.array([[0.5, 0.2, 0.1]], np.float32)
        total = float(np.sum(w[0].astype(np.float64) * lum))
        sw = w.copy()
        vg.roulette_row(sw, 0, 3, 0, 3, total, lum, 1.0, 5, 0, vg.column_keys(3))
        np.testing.assert_array_equal(sw, w)


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
def test_roulette_while_writing_the_pairs_equals_the_separate_pass(name):
    """pair_weights applies the shadow roulette per row as it writes the pairs: the same
    pairs, weights and rays as writing them all and then running the roulette over them
    (tests/support/oracle_vpl_gather.py: shadow_roulette, plain Python), glossy rows' pairs
    drawn by their lobes' guesses (lobe_guesses_numpy)."""
    from igi.worker import shading

    r, end, vpls, cols = _scene_columns(name, 32, 24, 3)
    sl = slice(5, len(end))  # a chunk not starting at row 0: base offsets the pair uniforms
    plain = shading._pair_rays(r.geom, end, sl, vpls, cols, -1)
    pi, pj, w, row, pl, o, d, t, inner = (a.copy() for a in plain)
    x, ns, _ng, side, *_ = shading._receivers(r.geom, end, sl)
    lobes = shading._lobes(row, shading._Receivers(end, None), sl, (0.5, 11))
    guess = lobe_guesses_numpy(x, ns, side, lobes, cols.pos, cols.normal, cols.directional, pi, pj, pl) \
        if len(lobes) else None
    if name == "cornell-box-glossy":  # glossy rows guessed by their lobes: not vacuous
        assert np.sum(guess != 1.0) > 100
    k = shadow_roulette(len(pi), pi, pj, w, pl, o, d, t, row, cols.lum, 0.5, 11, sl.start, guess)
    fused = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=(0.5, 11))
    assert 0 < k < len(plain[0])  # some pairs were dropped: not vacuous
    for a, b in zip((pi[:k], pj[:k], w[:k], row, pl[:k], o[:k], d[:k], t[:k]), fused):
        np.testing.assert_array_equal(a, b)
    # the BVH choice is the row's (Geometry.interior_bvh): a kept pair keeps its row's
    by_row = np.zeros(len(row), bool)
    by_row[plain[0]] = plain[8]
    np.testing.assert_array_equal(fused[8], by_row[fused[0]])


def _guesses(r, end, sl, cols, pi, pj, pl, row, seed):
    """The roulette's lobe guesses of the listed pairs (None: no glossy row)."""
    from igi.worker import shading

    x, ns, _ng, side, *_ = shading._receivers(r.geom, end, sl)
    lobes = shading._lobes(row, shading._Receivers(end, None), sl, (1.0, seed))
    return (lobe_guesses_numpy(x, ns, side, lobes, cols.pos, cols.normal, cols.directional, pi, pj, pl)
            if len(lobes) else None), lobes


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
def test_a_boosted_roulette_while_writing_the_pairs_equals_the_separate_pass(name):
    """A row's roulette threshold raised by its boost (vpl_gather.roulette_row): pair_weights
    drops and reweighs the pairs as the plain-Python pass does with that boost, and a boost of
    1 draws as no boost does."""
    from igi.worker import shading

    r, end, vpls, cols = _scene_columns(name, 32, 24, 3)
    sl = slice(5, len(end))
    plain = shading._pair_rays(r.geom, end, sl, vpls, cols, -1)
    pi, pj, w, row, pl, o, d, t, _inner = (a.copy() for a in plain)
    guess, _lobes = _guesses(r, end, sl, cols, pi, pj, pl, row, 11)
    boost = np.random.default_rng(4).uniform(1.0, 40.0, len(row)).astype(np.float32)
    k = shadow_roulette(len(pi), pi, pj, w, pl, o, d, t, row, cols.lum, 0.5, 11, sl.start, guess, boost)
    fused = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=(0.5, 11), boost=boost)
    unboosted = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=(0.5, 11))
    assert 0 < k < len(unboosted[0]) < len(plain[0])  # the boost dropped more: not vacuous
    for a, b in zip((pi[:k], pj[:k], w[:k], row, pl[:k], o[:k], d[:k], t[:k]), fused):
        np.testing.assert_array_equal(a, b)
    ones = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=(0.5, 11),
                              boost=np.ones(len(row), np.float32))
    for a, b in zip(ones, unboosted):
        np.testing.assert_array_equal(a, b)


def test_a_pixels_end_points_share_one_roulette_unbiased_with_far_fewer_rays():
    """A split surface gives a pixel several end points (grey-white-room's smooth plastics: the
    diffuse layer, the lobe's light samples, the lobe ray's next surface), each gathering every
    VPL. Weighed together (gather_vpls' ``pixel``), the faint ones are thinned against their
    pixel's weight: far fewer shadow rays; each end point's light still unbiased over seeds, and
    the light the pixels show (weighted by throughput × albedo) about as noisy; a pixel of one end
    point draws as it did alone."""
    from igi.common import bsdf

    r = Renderer(load_shared("grey-white-room"))
    end = eye_end_points(r, 24, 18, glossy_split_alpha=0.3)
    assert np.bincount(end.pixel).max() >= 3  # several end points a pixel: not vacuous
    vpls = _set(r, 1)
    c2 = CLAMP * r.geom.diagonal ** 2
    _, exact = gather_vpls(r.geom, end, vpls, c2, -1)
    eye = end.throughput * bsdf.albedo(end.sp, end.wi)
    rays, runs, seen = {}, {}, {}
    for grouped in (False, True):
        before = r.geom.counters["occluded_rays"]
        runs[grouped] = np.array([gather_vpls(r.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=seed,
                                              pixel=end.pixel if grouped else None)[1] for seed in range(300)])
        rays[grouped] = (r.geom.counters["occluded_rays"] - before) / 300
        seen[grouped] = (runs[grouped] * eye).sum(axis=(1, 2))  # the light toward the eye, all pixels
    assert rays[True] < 0.8 * rays[False]
    mean, se = runs[True].mean(axis=0), runs[True].std(axis=0) / np.sqrt(300)
    z = np.abs(mean - exact) / np.maximum(se, 1e-12 * np.abs(exact).max())
    assert np.mean(z > 4) < 0.005
    want = (exact * eye).sum()
    se_seen = {g: v.std() / np.sqrt(len(v)) for g, v in seen.items()}
    assert abs(seen[True].mean() - want) < 4 * se_seen[True]
    assert se_seen[True] < 1.5 * se_seen[False]
    # one end point a pixel: the same draws as without pixels
    alone = np.arange(len(end))
    kw = dict(shadow_roulette=1.0, seed=5)
    np.testing.assert_array_equal(gather_vpls(r.geom, end, vpls, c2, -1, pixel=alone, **kw)[1],
                                  gather_vpls(r.geom, end, vpls, c2, -1, **kw)[1])


@pytest.mark.parametrize("chunk", [None, 997])
def test_the_packet_gather_equals_the_pair_lists_with_a_pixels_shared_roulette(chunk, monkeypatch):
    """With a pixel's end points weighed together, gather_packets and the pair-list path draw
    the same pairs: the same irradiance bit for bit and the same number of shadow rays — also
    where the pair lists come in many chunks, each taking its rows' boosts."""
    from igi.worker import shading

    if chunk is not None:
        monkeypatch.setattr(shading, "PAIR_CHUNK", chunk)
    r = Renderer(load_shared("grey-white-room"))
    if r.geom.packet_handle() is None:
        pytest.skip("Embree's C API is not at hand: the gather has only the pair-list path")
    end = eye_end_points(r, 24, 18, glossy_split_alpha=0.3)
    vpls = _set(r, 2)
    c2 = CLAMP * r.geom.diagonal ** 2
    r.geom.counters["occluded_rays"] = 0
    i1 = gather_vpls(r.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=3, pixel=end.pixel)[1]
    r2 = Renderer(load_shared("grey-white-room"))
    _pair_list_path(r2.geom)
    i2 = gather_vpls(r2.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=3, pixel=end.pixel)[1]
    assert i1.sum() > 0
    np.testing.assert_array_equal(i1, i2)
    assert r.geom.counters["occluded_rays"] == r2.geom.counters["occluded_rays"] > 0


def test_glossy_rows_drawn_by_their_lobes_trace_fewer_rays_with_less_roulette_variance(monkeypatch):
    """The shadow roulette guesses a glossy row's pairs by the shape of its lobe
    (vpl_gather.lobe_rows, _lobe_guess), not flat: on modern-hall's rough plastics (GGX α 0.1,
    unsplit) and conductors the unshadowed estimate of each glossy end point stays unbiased over
    seeds, with fewer shadow rays and far less variance than the flat guess gives (~30x less)."""
    from igi.common import bsdf
    from igi.worker import shading
    from igi.worker.kernels import vpl_gather as vg

    r, end, vpls, cols = _scene_columns("modern-hall", 24, 18, 1)
    sl = slice(0, len(end))
    receivers = shading._Receivers(end, bsdf.albedo(end.sp, end.wi))
    weights = np.array(LUMINANCE_WEIGHTS)

    def light(roulette):  # each end point's unshadowed light (BSDF factors, no occlusion) and its rays
        pi, pj, w, row, pl, _o, d, *_ = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=roulette)
        factor = shading._bsdf_factors(sl, cols, row, pi, pj, pl, d, np.zeros(len(pi), bool), receivers)
        y = (w[:, None] * cols.color[pj] * factor) @ weights
        return np.bincount(pi, y, len(end)), len(pi), row

    exact, all_rays, row = light(None)
    glossy = row == vg.ROW_GLOSSY
    assert glossy.sum() > 50 and exact[glossy].sum() > 0  # not vacuous
    runs, rays = {}, {}
    for guess in ("lobe", "flat"):
        if guess == "flat":
            monkeypatch.setattr(shading, "_lobes", lambda *_a: shading.vg.NO_LOBES)
        out = [light((1.0, seed)) for seed in range(200)]
        runs[guess] = np.array([o[0] for o in out])[:, glossy]
        rays[guess] = np.mean([o[1] for o in out])
    assert rays["lobe"] < rays["flat"] < all_rays
    # unbiased per end point (the flat guess is too, but its rare kept pairs of a bright lobe
    # carry most of its variance: 200 seeds seldom see them)
    est = runs["lobe"]
    se = est.std(axis=0) / np.sqrt(len(est)) + 1e-9 * exact.max()
    assert np.mean(np.abs(est.mean(axis=0) - exact[glossy]) / se > 4) < 0.01
    assert abs(est.mean(axis=0).sum() / exact[glossy].sum() - 1) < 0.01
    var = {g: float(((est - exact[glossy]) ** 2).mean(axis=0).sum()) for g, est in runs.items()}
    assert var["lobe"] < 0.25 * var["flat"]


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
@pytest.mark.parametrize("roulette", [None, (0.5, 11)])
def test_the_column_by_column_weighing_equals_the_row_by_row_loop_bit_for_bit(name, roulette):
    """A block whose rows all take the same VPLs weighs its rows column by column
    (vpl_gather._lambert_columns, the rows in SIMD lanes, plastic layers' coats after); a block
    whose rows take different VPLs, row by row. Every row both blocks share gives the same
    pairs, weights, rays and roulette draws bit for bit."""
    from igi.worker import shading
    from igi.worker.kernels import vpl_gather as vg

    # (smooth plastics split: a diffuse layer row each)
    r, end, vpls, cols = _scene_columns(name, 40, 30, 3, glossy_split_alpha=0.3)
    n, m = len(end), len(vpls)
    sl = slice(3, n)
    lo, hi = np.zeros(n, np.int64), np.full(n, m, np.int64)
    odd = np.arange(3 + 17, n, vg.BLOCK // 2)  # one row in each block takes one VPL fewer
    hi[odd] = m - 1
    columns = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, roulette=roulette)
    rows = shading._pair_rays(r.geom, end, sl, vpls, cols, -1, col_range=(lo, hi), roulette=roulette)
    assert np.sum(columns[3] == vg.ROW_LAMBERT) > vg.BLOCK  # whole blocks of Lambertian rows
    keep_c = ~np.isin(columns[0] + sl.start, odd)
    keep_r = ~np.isin(rows[0] + sl.start, odd)
    assert keep_c.sum() == keep_r.sum() > 0
    if name == "cornell-box-glossy":  # plastic layers weighed in the lanes too: not vacuous
        assert np.isin(columns[0][keep_c], np.flatnonzero(columns[3] == vg.ROW_LAYER)).sum() > 100
    for a, b in zip(columns[:3] + columns[4:], rows[:3] + rows[4:]):
        np.testing.assert_array_equal(a[keep_c], b[keep_r])


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy"])
def test_the_rays_of_listed_pairs_are_the_rays_the_gather_writes_for_them(name):
    """The importance scoring traces only a few drawn pairs (vpl_scoring.scored_draws) and
    makes their rays afterwards (kernels.vpl_gather.pair_rays): bit for bit the rays the
    gather's array path writes for those pairs, spot and directional columns included."""
    from igi.worker import shading
    from igi.worker.kernels import vpl_gather as vg

    r = Renderer(with_extra_lights(load_shared(name)))
    end = eye_end_points(r, 32, 24)
    vpls = _set(r, 1)
    assert np.any(vpls.kind != 0)  # emitter columns (spot, directional) beside surface VPLs
    c2 = CLAMP * r.geom.diagonal ** 2
    cols = shading.vpl_columns(vpls, r.geom, c2)
    sl = slice(3, len(end))
    full = shading._pair_rays(r.geom, end, sl, vpls, cols, -1)
    pick = np.random.default_rng(1).choice(len(full[0]), 500, replace=False)
    x, _ns, ng, _side, off = shading._shadow_origins(r.geom, end, sl)
    o, d, t = np.empty((500, 3), np.float32), np.empty((500, 3), np.float32), np.empty(500, np.float32)
    vg.pair_rays(x, ng, off, cols.pos, cols.normal, cols.directional, np.float32(2 * r.geom.eps),
                 full[0][pick], full[1][pick], o, d, t)
    np.testing.assert_array_equal(o, full[5][pick])
    np.testing.assert_array_equal(d, full[6][pick])
    np.testing.assert_array_equal(t, full[7][pick])


def test_glossy_rows_trace_no_shadow_ray_below_their_horizon():
    """Every glossy kind reflects only, so a glossy end point's pairs with the VPL below its
    horizon (or seen from behind a one-sided surface) carry f = 0: the gather writes no shadow
    ray for them, and still equals the oracle, which evaluates the BSDF for every pair."""
    from igi.worker import shading
    from igi.worker.kernels import vpl_gather as vg

    r, end, vpls, cols = _scene_columns("cornell-box-glossy", 32, 24, 2)
    sl = slice(0, len(end))
    pi, pj, w, row, pl, o, d, t, _inner = shading._pair_rays(r.geom, end, sl, vpls, cols, -1)
    glossy = row[pi] == vg.ROW_GLOSSY
    assert glossy.sum() > 100  # the sphere and floor are glossy rows: not vacuous
    side = np.where(end.wi[pi, 2] >= 0, 1.0, -1.0)
    cos_x = np.einsum("ij,ij->i", d.astype(np.float64), end.ns[pi]) * side
    assert np.all(cos_x[glossy] > -1e-6)  # (the kernel's test is in float32)
    _agree(r, end, vpls)
    # The same glossy points seen from behind (one-sided: f = 0 for every pair) write no pair.
    g_rows = np.unique(pi[glossy])
    assert not end.sp.twosided[g_rows].any()
    wi = end.wi.copy()
    wi[g_rows, 2] = -np.abs(wi[g_rows, 2])
    behind = dataclasses.replace(end, wi=wi)
    pi2 = shading._pair_rays(r.geom, behind, sl, vpls, cols, -1)[0]
    assert not np.isin(pi2, g_rows).any()
    _agree(r, behind, vpls)


def test_shadow_origins_equal_the_numpy_form_with_grazing_far_and_nan_points():
    """The pair kernels' float32 end points and offsets (vpl_gather.shadow_origins) are the
    numpy form's bit for bit: far from the centre (large ulps), eyes exactly in the tangent
    plane (wi z = ±0: the front side), NaN positions, and an empty chunk."""
    from igi.worker.shading import _shadow_origins
    from tests.support.oracle_vpl_gather import shadow_origins_numpy

    r = Renderer(load_shared("cornell-box"))
    end = eye_end_points(r, 48, 36)
    g = np.random.default_rng(2)
    n = len(end)
    pos = end.position + g.normal(size=(n, 3)) * np.logspace(-3, 3, n)[:, None]
    wi = end.wi.copy()
    wi[::5, 2] = 0.0
    wi[1::5, 2] = -0.0
    pos[7] = np.nan
    end = dataclasses.replace(end, position=pos, wi=wi)
    for sl in (slice(0, n), slice(3, 40), slice(5, 5)):
        for got, want in zip(_shadow_origins(r.geom, end, sl), shadow_origins_numpy(r.geom, end, sl)):
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)


def _pair_list_path(geom):
    """The geometry with the fused packet gather switched off (as under a benchmark's hooks)."""
    geom.packet_handle = lambda: None
    return geom


@pytest.mark.parametrize("name, indirect, general", [("cornell-box-sphere", 18, False), ("cornell-box", 18, False),
                                                     ("cornell-box-glossy", 0, False), ("cornell-box-glossy", 18, False),
                                                     ("grey-white-room", 18, True)])
@pytest.mark.parametrize("roulette", [0.0, 1.0])
def test_the_packet_gather_equals_the_pair_lists_bit_for_bit(name, indirect, general, roulette):
    """gather_packets (pairs straight into Embree packets, summed as they come back) gives the
    pair-list path's irradiance bit for bit and traces the same number of shadow rays, with and
    without the shadow roulette: Lambertian scenes (no BSDF factor), glossy receivers lit by
    emitter samples only, glossy receivers and senders, every surface VPL through its full
    BSDF (force_general)."""
    from igi.worker import shading
    from igi.worker.kernels import vpl_gather as vg

    r = Renderer(load_shared(name))
    if r.geom.packet_handle() is None:
        pytest.skip("Embree's C API is not at hand: the gather has only the pair-list path")
    end = eye_end_points(r, 48, 36)
    vpls = _set(r, 2, indirect=indirect)
    c2 = CLAMP * r.geom.diagonal ** 2
    cols = shading.vpl_columns(vpls, r.geom, c2, force_general=general)
    rows = shading._receivers(r.geom, end, slice(0, len(end)))[5]
    if name == "cornell-box-glossy":
        assert np.any(rows == vg.ROW_GLOSSY) and np.any(rows == vg.ROW_LAMBERT)  # both kinds of row at once
        assert cols.glossy.any() == (indirect > 0)
    r.geom.counters["occluded_rays"] = 0
    a1, i1 = gather_vpls(r.geom, end, vpls, c2, -1, force_general=general, shadow_roulette=roulette, seed=7)
    fused_rays = r.geom.counters["occluded_rays"]
    r2 = Renderer(load_shared(name))
    _pair_list_path(r2.geom)
    a2, i2 = gather_vpls(r2.geom, end, vpls, c2, -1, force_general=general, shadow_roulette=roulette, seed=7)
    assert i1.sum() > 0
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(i1, i2)
    assert fused_rays == r2.geom.counters["occluded_rays"] > 0


def test_the_packet_gather_lights_nothing_through_non_finite_weights():
    """NaN and Inf end points reach the packet kernel too: their rows come back 0 (as the
    pair-list path's accumulate leaves them), every other row equals that path's."""
    r = Renderer(load_shared("cornell-box"))
    if r.geom.packet_handle() is None:
        pytest.skip("Embree's C API is not at hand")
    end = eye_end_points(r, 24, 24)
    pos = end.position.copy()
    pos[::7] = np.nan
    pos[3::7] = np.inf
    end = dataclasses.replace(end, position=pos)
    vpls = _set(r, 4)
    c2 = CLAMP * r.geom.diagonal ** 2
    _a1, i1 = gather_vpls(r.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=3)
    r2 = Renderer(load_shared("cornell-box"))
    _a2, i2 = gather_vpls(_pair_list_path(r2.geom), end, vpls, c2, -1, shadow_roulette=1.0, seed=3)
    assert np.all(np.isfinite(i1)) and np.all(i1[::7] == 0) and np.all(i1[3::7] == 0)
    np.testing.assert_array_equal(i1, i2)


def test_kernel_matches_numpy_with_sky_samples_in_the_simd_rows():
    """Lambertian rows are weighed in SIMD lanes (vpl_gather._stage) when no column is a spot:
    directional sky samples with MIS and surface VPLs there still equal the numpy oracle."""
    from igi.common import bundled
    from igi.common.lights import VPL_DIRECTIONAL, VPL_SPOT
    from igi.common.loader import load_scene

    r = Renderer(load_scene(bundled.resolve("window-room")))
    end = eye_end_points(r, 32, 24)
    vpls = _set(r, 3, direct=8)
    assert np.any(vpls.kind == VPL_DIRECTIONAL) and np.any(vpls.kind == 0)  # sky samples and surface VPLs
    assert not np.any(vpls.kind == VPL_SPOT)  # no spot column: the SIMD rows run
    assert _agree(r, end, vpls).sum() > 0


def test_receiver_rows_equal_the_numpy_form_for_every_kind_side_and_nan_eye():
    """vpl_gather.receiver_rows (the gather's row kinds in one pass) gives what the numpy form
    gave: Lambertian / glossy from the front, nothing from behind a one-sided surface or for the
    NULL kind, plastic layers left to the caller (counted when seen from the front); eyes exactly
    in the tangent plane (±0) and NaN eyes see the back of a one-sided surface."""
    from igi.common.scene import DIFFUSE, NULL, ROUGHPLASTIC_DIFFUSE
    from igi.worker.kernels import vpl_gather as vg

    g = np.random.default_rng(5)
    n = 4000
    kind = g.integers(0, ROUGHPLASTIC_DIFFUSE + 1, n).astype(np.int8)
    twosided = g.random(n) < 0.3
    wi = g.normal(size=(n, 3))
    wi[::7, 2] = 0.0
    wi[1::7, 2] = -0.0
    wi[2::11, 2] = np.nan
    row = np.empty(n, np.int8)
    layers = vg.receiver_rows(kind, twosided, wi, DIFFUSE, NULL, ROUGHPLASTIC_DIFFUSE, row)
    front = twosided | (wi[:, 2] > 0)
    want = np.where((kind == DIFFUSE) & front, vg.ROW_LAMBERT,
                    np.where((kind != DIFFUSE) & (kind != NULL) & front, vg.ROW_GLOSSY, vg.ROW_NONE)).astype(np.int8)
    want[kind == ROUGHPLASTIC_DIFFUSE] = vg.ROW_NONE
    np.testing.assert_array_equal(row, want)
    assert layers == int(np.sum((kind == ROUGHPLASTIC_DIFFUSE) & front)) > 0
    assert set(np.unique(row)) == {vg.ROW_NONE, vg.ROW_LAMBERT, vg.ROW_GLOSSY}  # every outcome met


def test_a_pair_takes_the_inner_bvh_only_from_inside_toward_inside_columns():
    """vpl_gather.interior_origin / interior_column: the origin on the inner side of every
    supporting plane (an origin pushed out through a wall seen from outside, or NaN, is not;
    with no plane nothing is) and a column not outside one (a directional one, a light beyond a
    wall)."""
    from igi.worker.kernels import vpl_gather as vg

    planes = np.array([[0, 1, 0, -1], [0, -1, 0, 0]], np.float32)  # 0 <= y <= 1
    assert vg.interior_origin(planes, 0.0, 0.5, 0.0)
    assert not vg.interior_origin(planes, 0.0, 1.01, 0.0)  # outside y <= 1
    assert not vg.interior_origin(planes, 0.0, -0.01, 0.0)
    assert not vg.interior_origin(planes, np.nan, 0.5, 0.0)
    assert not vg.interior_origin(np.zeros((0, 4), np.float32), 0.0, 0.5, 0.0)
    col_out = np.array([0, 0, 1, 1], np.int64)  # column 1 lies outside
    assert [vg.interior_column(col_out, j) for j in range(3)] == [True, False, True]
