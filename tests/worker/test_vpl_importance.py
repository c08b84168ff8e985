"""Importance-sampled VPLs (worker.vpl_importance, Georgiev & Slusallek 2010): the acceptance
probabilities, unbiasedness against plain instant radiosity, lower variance where light comes
through a gap, and determinism across workers."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.camera import camera_rays
from igi.common.params import make_params
from igi.common.sobol_stream import rng
from tests.support.scenes_synthetic import furnace_box, two_rooms
from igi.worker.renderer import Renderer, clamp_distance2
from igi.worker.shading import gather_vpls, trace_eye
from igi.worker.vpl import build_vpl_set
from igi.worker.vpl_importance import (View, acceptance, build_importance_vpl_set, effective_share)


def _view(scene) -> View:
    c = scene.camera
    return View(tuple(np.asarray(c.to_world, np.float64).ravel()), c.fov_x, c.width, c.height)


def _end_points(r: Renderer, w=24, h=18):
    cam = r.scene.camera
    ys, xs = np.mgrid[0:h, 0:w]
    o, d = camera_rays(cam.to_world, cam.fov_x, w, h, xs.ravel() * cam.width / w, ys.ravel() * cam.height / h)
    return trace_eye(r.scene, r.geom, r.lights, o, d, -1, 8, rng(0, 7)).end


def test_acceptance_sums_to_target_within_floor_and_one():
    g = np.random.default_rng(3)
    phi = np.concatenate([g.lognormal(0, 3, 200), np.zeros(50)])
    for mix in (1.0, 0.5):
        p = acceptance(phi, 30.0, mix)
        assert abs(p.sum() - 30.0) < 1e-6 * 30
        assert np.all(p <= 1.0) and np.all(p > 0)
        assert p.min() >= (1 - mix) * 30 / len(phi) - 1e-12  # the defensive floor
        order = np.argsort(phi)
        assert np.all(np.diff(p[order]) >= -1e-12)  # more contribution, never less likely
    assert np.allclose(acceptance(np.zeros(10), 4.0), 0.4)  # nothing in view: uniform
    assert np.all(acceptance(phi[:5], 10.0) == 1.0)  # fewer candidates than wanted: keep all


def test_systematic_acceptance_keeps_each_candidate_with_its_probability():
    from igi.worker.vpl_importance import systematic_keep

    p = np.random.default_rng(3).random(200) ** 3 * 1.3  # some above 1: always kept
    us = (np.arange(4000) + 0.5) / 4000
    keeps = np.array([systematic_keep(p, u) for u in us])
    np.testing.assert_allclose(keeps.mean(axis=0), np.minimum(p, 1.0), atol=1e-3)
    counts = keeps.sum(axis=1)
    total = np.minimum(p, 1.0).sum()
    assert counts.min() >= np.floor(total) and counts.max() <= np.ceil(total)


def test_effective_share():
    assert effective_share(np.ones(10)) == pytest.approx(1.0)
    assert effective_share(np.array([1.0, 0, 0, 0])) == pytest.approx(0.25)


def _totals(r, end, params, importance, seeds):
    c2 = clamp_distance2(params, r.geom.diagonal)
    view = _view(r.scene)
    out = []
    for s in seeds:
        if importance:
            v, _ = build_importance_vpl_set(r.scene, r.geom, r.lights, s, 0, 0, 18, 4, view, 8, c2, -1, 8)
        else:
            v = build_vpl_set(r.scene, r.geom, r.lights, s, 0, 0, 18, 4)
        albedo, irr = gather_vpls(r.geom, end, v, c2, -1)
        out.append(float((albedo * irr).sum()))
    return np.array(out)


def test_importance_sampling_is_unbiased_and_less_noisy_through_a_door():
    r = Renderer(two_rooms())
    end = _end_points(r)
    params = make_params()
    seeds = range(120)
    plain = _totals(r, end, params, False, seeds)
    imp = _totals(r, end, params, True, seeds)
    assert plain.mean() > 0
    se = np.sqrt(plain.var(ddof=1) / len(plain) + imp.var(ddof=1) / len(imp))
    assert abs(plain.mean() - imp.mean()) < 4 * se  # same expectation (indirect light only)
    assert imp.std() < 0.7 * plain.std()  # VPLs where the camera looks: less noise


def test_importance_sampled_furnace_matches_plain_expectation():
    r = Renderer(furnace_box(0.5, 1.0))
    end = _end_points(r, 12, 12)
    params = make_params()
    seeds = range(40)
    plain = _totals(r, end, params, False, seeds)
    imp = _totals(r, end, params, True, seeds)
    se = np.sqrt(plain.var(ddof=1) / len(plain) + imp.var(ddof=1) / len(imp))
    assert abs(plain.mean() - imp.mean()) < 4 * se + 1e-9 * plain.mean()


def test_every_worker_builds_the_same_importance_set():
    scene = two_rooms()
    params = make_params(vpl_importance=1)
    a = Renderer(scene).vpl_set(5, 3, params, view=_view(scene))
    b = Renderer(scene).vpl_set(5, 3, params, view=_view(scene))
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.power, b.power)


def test_auto_mode_turns_on_behind_a_door_and_says_why():
    scene = two_rooms()
    r = Renderer(scene)
    assert r.importance_on(make_params(), _view(scene))
    assert "vpl_importance" in r.importance_notes and "ON" in r.importance_notes
    assert not r.importance_on(make_params(vpl_importance=0), _view(scene))


def _direct_frames(scene, seeds, by_view: bool, monkeypatch) -> np.ndarray:
    from igi.master.inprocess import render_local

    with monkeypatch.context() as m:
        if not by_view:
            m.setattr(Renderer, "emitter_pmf", lambda self, params, view: None)
        return np.stack([render_local(scene, {"max_depth": 2, "seed": s, "vpl_importance": 1, "direct_vpls": 1},
                                      1, width=32, height=24) for s in seeds])


def test_emitter_samples_chosen_by_the_view_favour_the_lamp_the_view_sees():
    from tests.support.scenes_synthetic import panel_and_lamp

    scene = panel_and_lamp()
    r = Renderer(scene)
    # no more emitters than a set's emitter samples: stratified counts beat any other choice
    assert r.emitter_pmf(make_params(max_depth=2, direct_vpls=2), _view(scene)) is None
    view_pmf = r.emitter_pmf(make_params(max_depth=2, direct_vpls=1), _view(scene))
    assert view_pmf is not None
    assert abs(view_pmf.sum() - 1.0) < 1e-9
    assert view_pmf[1] > 1.15 * r.lights.pmf[1]  # the lamp by the wall gains
    assert np.all(view_pmf >= 0.5 * r.lights.pmf - 1e-12)  # the defensive half by power
    assert "emitter choice" in r.emitter_notes
    # one emitter: nothing to choose
    assert Renderer(two_rooms()).emitter_pmf(make_params(), _view(two_rooms())) is None


def test_emitter_choice_by_the_view_is_unbiased_and_steadies_frames(monkeypatch):
    """Direct light (emitter samples with their MIS against BSDF rays, which must use the same
    choice of emitter): the mean over frames matches the choice by power; single frames vary
    less, since the lamp that lights the wall is drawn more often."""
    from tests.support.scenes_synthetic import panel_and_lamp

    scene = panel_and_lamp()
    power = _direct_frames(scene, range(32), False, monkeypatch)
    view = _direct_frames(scene, range(32), True, monkeypatch)
    m_p, m_v = power.mean(axis=0), view.mean(axis=0)
    assert abs(m_v.mean() / m_p.mean() - 1) < 0.02
    blocks = lambda a: a.reshape(6, 4, 8, 4, 3).mean(axis=(1, 3))  # noqa: E731 - 4×4 blocks
    np.testing.assert_allclose(blocks(m_v), blocks(m_p), rtol=0.1, atol=0.01)
    assert view.mean(axis=(1, 2, 3)).var() < 0.8 * power.mean(axis=(1, 2, 3)).var()


def test_mis_reads_the_emitter_choice_the_samples_were_drawn_with():
    """The BSDF ray's MIS weight needs the pdf with which the set's emitter samples would have
    drawn the point it hits: with a view's choice of emitter, that choice, not the power's."""
    from tests.support.scenes_synthetic import panel_and_lamp
    from igi.worker.shading import LightMIS, emitter_pdf

    scene = panel_and_lamp()
    r = Renderer(scene)
    pmf = r.emitter_pmf(make_params(direct_vpls=1), _view(scene))
    vpls = build_vpl_set(scene, r.geom, r.lights, 5, 0, 64, 0, 1, emitter_pmf=pmf)
    assert vpls.emitter_pmf is pmf
    x = np.array([1.0, 0.5, 1.0])
    to_y = vpls.position - x
    dist = np.linalg.norm(to_y, axis=1)
    d = to_y / dist[:, None]
    hits = r.geom.intersect(np.repeat(x[None], len(d), axis=0), d)
    hit_sample = hits.valid & (np.abs(hits.t - dist) < 1e-4)
    assert hit_sample.sum() > 32
    cos_y = np.abs(np.einsum("ij,ij->i", d, hits.ns))
    expected = vpls.light_pdf * dist ** 2 / cos_y  # the sample's own pdf, per solid angle
    for mis_pmf, same in ((pmf, True), (None, False)):
        got = emitter_pdf(r.lights, hits, hits.valid, d, LightMIS(1, None, mis_pmf))
        close = np.isclose(got[hit_sample], expected[hit_sample], rtol=1e-6)
        assert close.all() if same else not close.all()


def test_sampled_visibility_scores_are_unbiased_estimates_of_the_exact_scores():
    """contribution_per_vpl with a few shadow rays per VPL (drawn by unshadowed light): the mean
    over draws equals the all-pairs score, VPLs nobody sees score 0, each draw is within the
    VPL's unshadowed bound."""
    from igi.worker.shading import contribution_per_vpl

    r = Renderer(two_rooms())
    end = _end_points(r)
    c2 = clamp_distance2(make_params(), r.geom.diagonal)
    v = build_vpl_set(r.scene, r.geom, r.lights, 3, 0, 0, 64, 4)
    exact = contribution_per_vpl(r.geom, end, v, c2, -1)
    assert (exact > 0).sum() >= 8
    draws = np.stack([contribution_per_vpl(r.geom, end, v, c2, -1, 0.0, rng(9, s), 8) for s in range(60)])
    assert np.all(draws[:, exact == 0] == 0)
    lit = exact > 0.01 * exact.max()
    mean = draws.mean(axis=0)
    se = draws.std(axis=0, ddof=1) / np.sqrt(len(draws))
    assert np.all(np.abs(mean - exact)[lit] <= 4 * se[lit] + 1e-9 * exact[lit])
    assert np.abs(mean.sum() / exact.sum() - 1) < 0.05


def test_camera_pool_draws_are_deterministic_subsets_that_vary_by_set():
    from igi.worker.vpl_importance import camera_pool

    scene = two_rooms()
    r = Renderer(scene)
    pool = camera_pool(r.scene, r.geom, r.lights, _view(scene), -1, 8, paths=512)
    a, b, c = pool.draw(4, 1, 64), pool.draw(4, 1, 64), pool.draw(4, 2, 64)
    np.testing.assert_array_equal(a.position, b.position)  # every worker draws the same points
    assert not np.array_equal(np.unique(a.pixel), np.unique(c.pixel))
    assert len(np.unique(a.pixel)) <= 64 and set(a.pixel) <= set(pool.end.pixel)
    # a path's end points come whole (a split path keeps all its branches)
    for p in np.unique(a.pixel)[:10]:
        assert (a.pixel == p).sum() == (pool.end.pixel == p).sum()
    assert set(pool.first(100).pixel) <= set(range(100))


def test_drawing_every_set_at_once_gives_each_set_its_own_draw():
    """CameraPool.draw_sets (one copy out of the pool for a frame's sets) hands each set exactly
    the end points draw() gives it alone, in order, and all of them concatenated."""
    from igi.worker.vpl_importance import camera_pool

    scene = two_rooms()
    r = Renderer(scene)
    pool = camera_pool(r.scene, r.geom, r.lights, _view(scene), -1, 8, paths=512)
    ks = [3, 0, 7]
    drawn, ends = pool.draw_sets(9, ks, 64)
    assert len(drawn) == sum(len(e) for e in ends) > 0
    row = 0
    for k, e in zip(ks, ends):
        alone = pool.draw(9, k, 64)
        for name in ("pixel", "position", "ns", "ng", "wi", "throughput", "segments", "main", "distance"):
            np.testing.assert_array_equal(getattr(e, name), getattr(alone, name))
            np.testing.assert_array_equal(getattr(drawn, name)[row:row + len(e)], getattr(alone, name))
        np.testing.assert_array_equal(e.sp.kind, alone.sp.kind)
        row += len(e)


def test_a_renderer_keeps_the_per_view_results_of_recent_views_only():
    from igi.worker import renderer as rmod

    scene = two_rooms()
    r = Renderer(scene)
    params = make_params(vpl_importance=1)
    base = _view(scene)
    for i in range(3 * rmod.MAX_VIEW_ENTRIES):
        view = View(base.to_world[:3] + (base.to_world[3] + 1e-3 * i,) + base.to_world[4:], base.fov_x, 16, 12)
        r.camera_pool(params, view)
    assert len(r._views) == rmod.MAX_VIEW_ENTRIES


def test_importance_sets_built_together_equal_each_built_alone():
    """Scored in one batch (each set's candidates against its own camera points only), every
    set is bit for bit what it is built alone: acceptance, weights and statistics."""
    from igi.worker.vpl_importance import build_importance_vpl_sets

    scene = two_rooms()
    r = Renderer(scene)
    view = _view(scene)
    c2 = clamp_distance2(make_params(), r.geom.diagonal)
    ks = [4, 1, 6]
    together = build_importance_vpl_sets(r.scene, r.geom, r.lights, 2, ks, 2, 18, 4, view, 8, c2, -1, 8,
                                         roulette=True)
    for k, (s, st) in zip(ks, together):
        alone, st1 = build_importance_vpl_set(r.scene, r.geom, r.lights, 2, k, 2, 18, 4, view, 8, c2, -1, 8,
                                              roulette=True)
        assert st == st1 and st.candidates > 0 and st.accepted > 0
        for name in ("kind", "position", "power", "depth", "light_pdf"):
            np.testing.assert_array_equal(getattr(s, name), getattr(alone, name), err_msg=name)


@pytest.mark.parametrize("pair_chunk", [1 << 17, 3000, 17])
def test_scoring_with_column_ranges_equals_scoring_each_set_alone(monkeypatch, pair_chunk):
    """contribution_per_vpl with per-end-point column ranges scores each set's columns only
    against its own end points (the block-diagonal pairs), exactly as separate calls — also
    when the pairs span several chunks (the sampled visibility draws per chunk)."""
    from igi.worker import shading
    from igi.worker.shading import EndPoints, contribution_per_vpl
    from igi.worker.vpl import concat_vpls

    monkeypatch.setattr(shading, "PAIR_CHUNK", pair_chunk)
    scene = two_rooms()
    r = Renderer(scene)
    c2 = clamp_distance2(make_params(), r.geom.diagonal)
    end = _end_points(r)
    halves = [end.subset(np.arange(0, len(end) // 2)), end.subset(np.arange(len(end) // 2, len(end)))]
    sets = [build_vpl_set(r.scene, r.geom, r.lights, s, 0, 0, 40, 4) for s in (1, 2)]
    m0, m1 = len(sets[0]), len(sets[1])
    lo = np.concatenate([np.zeros(len(halves[0]), np.int64), np.full(len(halves[1]), m0)])
    hi = np.concatenate([np.full(len(halves[0]), m0), np.full(len(halves[1]), m0 + m1)])
    both = EndPoints.concat(halves)
    exact = contribution_per_vpl(r.geom, both, concat_vpls(sets), c2, -1, col_range=(lo, hi))
    alone = np.concatenate([contribution_per_vpl(r.geom, h, v, c2, -1) for h, v in zip(halves, sets)])
    np.testing.assert_allclose(exact, alone, rtol=1e-12, atol=0)
    assert exact.sum() > 0
    # sampled visibility: the same draws with the same per-column uniforms
    u = rng(4, 4).random(m0 + m1)
    sampled = contribution_per_vpl(r.geom, both, concat_vpls(sets), c2, -1, 0.0, None, 8, (lo, hi), u)
    sampled_alone = np.concatenate([contribution_per_vpl(r.geom, h, v, c2, -1, 0.0, None, 8, None, uu)
                                    for h, v, uu in zip(halves, sets, (u[:m0], u[m0:]))])
    np.testing.assert_allclose(sampled, sampled_alone, rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", ["grey-white-room", "modern-hall"])
def test_a_views_sets_built_together_equal_each_built_alone_with_portals_guides_and_emitter_choice(name):
    """On real scenes, with what the renderer adds per view — the sky's portals and guided
    environment samples (grey-white-room), the view's emitter choice among 13 lamps
    (modern-hall) — a batch of sets is bit for bit the sets built one by one."""
    from tests.support.paths import SHARED
    from igi.common.loader import load_scene

    scene = load_scene(str(SHARED / "scenes" / name / "scene.xml"))
    r = Renderer(scene)
    params = make_params()
    view = View(tuple(np.asarray(scene.camera.to_world, np.float64).ravel()), scene.camera.fov_x, 160, 120)
    extra = r.portals(params, view) if name == "grey-white-room" else r.emitter_pmf(params, view)
    assert extra is not None  # the view's extra is on: the test is not vacuous
    ks = [7, 2, 11]
    together = r._build_importance(5, ks, params, view, True)
    for k, (s, st) in zip(ks, together):
        alone, st1 = r._build_importance(5, [k], params, view, True)[0]
        assert st == st1
        for f in ("kind", "position", "normal", "power", "depth", "wi_local", "light_pdf"):
            np.testing.assert_array_equal(getattr(s, f), getattr(alone, f), err_msg=f)
        assert (s.env_guide is None) == (alone.env_guide is None)
