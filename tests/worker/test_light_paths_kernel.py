"""The compiled bounce of light walks and caustic photons (worker.kernels.light_paths via
worker.light_paths.continue_paths) continues exactly the paths the numpy bounce did
(tests/support/oracle_light_paths.py): every BSDF kind, textured points, Russian roulette
(including its NaN weights), grazing and NaN directions, zero and Inf flux, empty selections."""
from __future__ import annotations

import numpy as np
import pytest

from igi.bench.stress_scenes import load_shared
from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.loader import load_scene
from igi.common.scene import (CONDUCTOR, DIELECTRIC, DIFFUSE, PLASTIC, ROUGHCONDUCTOR, ROUGHPLASTIC, THINDIELECTRIC,
                              Material, Texture)
from igi.worker.light_paths import continue_paths
from tests.support.oracle_light_paths import continue_paths_numpy
from tests.support.paths import ROOT

BUMP = ROOT / "tests" / "data" / "bump" / "bump.xml"

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN inputs


def _materials():
    img = np.random.default_rng(5).random((4, 4, 3)).astype(np.float32)
    return [Material("wall", DIFFUSE, diffuse=Texture.constant([0.7, 0.5, 0.3])),
            Material("mirror", CONDUCTOR), Material("glass", DIELECTRIC, int_ior=1.5),
            Material("thin", THINDIELECTRIC), Material("varnish", PLASTIC),
            Material("brushed", ROUGHCONDUCTOR, alpha=0.2), Material("coat", ROUGHPLASTIC, alpha=0.3),
            Material("poster", DIFFUSE, diffuse=Texture(image=img))]


def _paths(g, n_paths, n_hits, geom):
    rows = np.sort(g.choice(n_paths, n_hits, replace=False))
    pos = geom.center + (g.random((n_hits, 3)) - 0.5) * geom.extent
    ns = g.normal(size=(n_hits, 3))
    ns /= np.linalg.norm(ns, axis=1)[:, None]
    d = g.normal(size=(n_paths, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    graze = rows[::9]
    t = np.cross(ns[::9], g.normal(size=(len(graze), 3)))
    d[graze] = t / np.linalg.norm(t, axis=1)[:, None]
    d[rows[4]] = np.nan
    flux = g.random((n_paths, 3))
    flux[rows[6]] = 0.0
    flux[rows[8]] = [np.inf, 1.0, 1.0]
    o = g.normal(size=(n_paths, 3))
    return rows, pos, ns, ns.copy(), d, o, flux


@pytest.mark.parametrize("roulette", [False, True])
@pytest.mark.parametrize("subset", [False, True])
def test_bounce_equals_the_numpy_bounce(roulette, subset):
    geom = Geometry(load_shared("cornell-box"))
    mats = _materials()
    g = np.random.default_rng(11)
    n_paths, n_hits = 4000, 2500
    rows, pos, ns, ng, d, o, flux = _paths(g, n_paths, n_hits, geom)
    sp = bsdf.gather(mats, g.integers(-1, len(mats), n_hits), g.random((n_hits, 2)))
    sel = np.sort(g.choice(n_hits, 1500, replace=False)) if subset else np.arange(n_hits)
    u = g.random((n_paths, 20))
    survival = g.random((n_paths, 6)) if roulette else None
    got_state = [a.copy() for a in (d, o, flux)]
    want_state = [a.copy() for a in (d, o, flux)]
    got = continue_paths(sp, geom, sel, rows, pos, ns, ng, *got_state, u, 8, survival, 2)
    want = continue_paths_numpy(sp, geom, sel, rows, pos, ns, ng, *want_state, u, 8, survival, 2)
    assert 100 < len(want) < len(sel)
    np.testing.assert_array_equal(got, want)
    for name, a, b in zip(("direction", "origin", "flux"), got_state, want_state):
        np.testing.assert_array_equal(a, b, err_msg=name)


def test_an_empty_selection_changes_nothing():
    geom = Geometry(load_shared("cornell-box"))
    g = np.random.default_rng(1)
    rows, pos, ns, ng, d, o, flux = _paths(g, 50, 20, geom)
    sp = bsdf.gather(_materials(), np.zeros(20, np.int64), None)
    before = [a.copy() for a in (d, o, flux)]
    out = continue_paths(sp, geom, np.zeros(0, np.int64), rows, pos, ns, ng, d, o, flux, g.random((50, 8)), 5)
    assert len(out) == 0
    for a, b in zip((d, o, flux), before):
        np.testing.assert_array_equal(a, b)


def test_state_arrays_that_cannot_be_updated_in_place_are_refused():
    geom = Geometry(load_shared("cornell-box"))
    g = np.random.default_rng(1)
    rows, pos, ns, ng, d, o, flux = _paths(g, 50, 20, geom)
    sp = bsdf.gather(_materials(), np.zeros(20, np.int64), None)
    with pytest.raises(ValueError, match="in place"):
        continue_paths(sp, geom, np.arange(20), rows, pos, ns, ng, d.astype(np.float32), o, flux,
                       g.random((50, 8)), 5)


def _photon_sets(monkeypatch, name: str, compiled: bool) -> list:
    """Four caustic photon sets of shared scene ``name``, traced by
    kernels.light_paths.trace_photons (``compiled``) or by worker.caustics' numpy loop."""
    from igi.common.lights import LightSampler
    from igi.worker.caustics import build_photon_sets

    scene = load_shared(name)
    geom = Geometry(scene)
    if not compiled:
        monkeypatch.setattr(geom, "closest_terms", lambda: None)
    sets = build_photon_sets(scene, geom, LightSampler(scene, geom), 5, [0, 3, 7, 9], 400, 0.01, 8)
    return sets, geom.counters["intersect_rays"]


@pytest.mark.parametrize("name", ["cornell-box-sphere", "cornell-box-water"])
def test_compiled_photon_paths_equal_the_numpy_loop(monkeypatch, name):
    """The photons traced in one compiled call are the numpy loop's, bit for bit and in order:
    positions, flux, directions, normals, depths; the same rays traced."""
    got, got_rays = _photon_sets(monkeypatch, name, True)
    monkeypatch.undo()
    want, want_rays = _photon_sets(monkeypatch, name, False)
    assert got_rays == want_rays
    assert sum(len(s) for s in got) > 200
    # chains past the Sobol numbers' bounces (caustics.QUASI_BOUNCES) draw counter-based ones
    assert max(int(s.depth.max()) for s in got if len(s)) > 3
    for a, b in zip(got, want):
        for field in ("position", "power", "direction", "normal", "depth"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def _walk_sets(monkeypatch, name: str, compiled: bool, roulette: bool):
    from igi.common.lights import LightSampler
    from igi.worker.vpl import build_vpl_sets

    scene = load_scene(BUMP) if name == "bump" else load_shared(name)
    geom = Geometry(scene)
    if not compiled:
        monkeypatch.setattr(geom, "closest_terms", lambda: None)
    sets = build_vpl_sets(scene, geom, LightSampler(scene, geom), 5, [0, 3, 7], 4, 60, 4, roulette=roulette)
    return sets, geom.counters["intersect_rays"]


@pytest.mark.parametrize("name", ["cornell-box-glossy", "cornell-box-sphere", "modern-hall", "grey-white-room", "bump"])
@pytest.mark.parametrize("roulette", [False, True])
def test_compiled_light_walks_equal_the_numpy_loop(monkeypatch, name, roulette):
    """The walks traced in one compiled call (kernels.light_paths.trace_walks) leave the numpy
    loop's VPLs bit for bit and in order — positions, normals, flux, depths, incident
    directions, BSDFs (bitmap-textured floors and walls included) — after the same rays; with
    Russian roulette past the walk length too. ``bump`` (tests/data/bump): normal- and
    bump-mapped surfaces, whose stored flux and bounces take the shading-normal correction."""
    got, got_rays = _walk_sets(monkeypatch, name, True, roulette)
    monkeypatch.undo()
    want, want_rays = _walk_sets(monkeypatch, name, False, roulette)
    assert got_rays == want_rays
    assert sum(len(s) for s in got) > 30
    if roulette and sum(len(s) for s in got) > 100:  # (the window room's sky walks are few and short)
        assert max(int(s.depth.max()) for s in got) > 4  # walks went past their length
    for a, b in zip(got, want):
        for field in ("kind", "position", "normal", "ng", "power", "depth", "wi_local", "light_pdf"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
        assert a.diffuse_only == b.diffuse_only
        for pa, pb in zip(a.surface.packed(), b.surface.packed()):  # every BSDF parameter per VPL
            np.testing.assert_array_equal(pa, pb)


LAMP_ROOM = """<scene version="3.0.0">
  <bsdf type="diffuse" id="wall"><rgb name="reflectance" value="0.7"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale x="3" y="3"/><rotate x="1" angle="-90"/></transform>
    <ref id="wall"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="3" y="2"/><translate y="2" z="-2"/></transform>
    <ref id="wall"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="0.6" y="0.6"/><rotate x="1" angle="90"/>
    <translate x="0.5" y="1.5" z="-0.6"/></transform>LAMP_BSDF
    <emitter type="area"><rgb name="radiance" value="14"/></emitter></shape>
</scene>"""


@pytest.mark.parametrize("compiled", [True, False])
def test_light_walks_leave_no_vpls_on_a_black_lamp(monkeypatch, tmp_path, compiled):
    """A bare area light is black (Mitsuba's default; common.mitsuba_bsdfs.material_index): the
    walks that come back to it end there and leave no VPL (one would cost its shadow rays for
    no light) — where the same lamp reflects (a diffuse given), they leave VPLs on it. Compiled
    and numpy walks alike."""
    from igi.common.lights import LightSampler
    from igi.worker.vpl import build_vpl_sets

    def lamp_vpls(bsdf_xml):
        path = tmp_path / "lamp.xml"
        path.write_text(LAMP_ROOM.replace("LAMP_BSDF", bsdf_xml))
        scene = load_scene(path)
        geom = Geometry(scene)
        if not compiled:
            monkeypatch.setattr(geom, "closest_terms", lambda: None)
        lamp = scene.meshes[scene.emitters[0].mesh].material
        sets = build_vpl_sets(scene, geom, LightSampler(scene, geom), 3, list(range(8)), 0, 64, 4)
        rows = np.concatenate([s.surface.material_rows() for s in sets if len(s)])
        return len(rows), int(np.sum(rows == lamp)), scene.materials[lamp]

    n_black, on_black, black = lamp_vpls("")
    n_grey, on_grey, grey = lamp_vpls('<bsdf type="diffuse"/>')
    assert black.is_black and not grey.is_black
    assert on_grey > 10 and on_black == 0
    assert 0 < n_black <= n_grey - on_grey  # (walks are the same until they meet the lamp)


def test_walks_that_outgrow_the_first_buffer_are_traced_again_whole(monkeypatch):
    """More VPLs than eight per walk (a white furnace: every walk bounces to its length of 12)
    take the second, full-sized buffer: the same VPLs as the numpy loop."""
    from igi.common.lights import LightSampler
    from igi.worker.vpl import build_vpl_sets
    from tests.support.scenes_synthetic import furnace_box

    def walks(compiled):
        scene = furnace_box(0.9, 1.0, 4, 4)
        geom = Geometry(scene)
        if not compiled:
            monkeypatch.setattr(geom, "closest_terms", lambda: None)
        return build_vpl_sets(scene, geom, LightSampler(scene, geom), 1, [0], 0, 48, 12)[0]

    got = walks(True)
    monkeypatch.undo()
    want = walks(False)
    assert len(got) > 8 * 48 / 12  # past the first buffer's eight per walk
    for field in ("position", "power", "depth", "wi_local"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)


def test_roulette_numbers_are_uniform_and_a_function_of_set_walk_bounce_and_number():
    """The walks' numbers past their quasi-random ones (kernels.light_paths.walk_uniform): in
    [0, 1), mean 1/2 and variance 1/12 over 4000 walks, uncorrelated between two sets' keys and
    between bounces, the same for the same (key, walk)."""
    from igi.worker.light_paths import roulette_numbers

    walks = 4000
    keys = np.repeat(np.array([12345, 67890], np.uint64), walks)
    u, s = roulette_numbers(keys, walks, 2, 6, 3)
    assert u.shape == (2 * walks, 12) and s.shape == (2 * walks, 6)
    for a in (u, s):
        assert np.all((a >= 0) & (a < 1))
        assert abs(a.mean() - 0.5) < 0.01 and abs(a.var() - 1 / 12) < 0.005
    assert abs(np.corrcoef(u[:walks, 0], u[walks:, 0])[0, 1]) < 0.05  # two sets
    assert abs(np.corrcoef(s[:walks, 2], s[:walks, 3])[0, 1]) < 0.05  # two bounces
    again, _ = roulette_numbers(keys[:walks], walks, 2, 6, 3)
    np.testing.assert_array_equal(again, u[:walks])


def test_a_bounce_off_a_tilted_shading_normal_carries_veachs_correction():
    """On a normal- or bump-mapped hit (``bumped``) whose shading normal is not the geometric one
    the compiled bounce's flux takes |wi·ns| |wo·ng| / (|wi·ng| |wo·ns|)
    (common.kernels.shading_normals), as the oracle's independent numpy form; elsewhere nothing
    (bit for bit the uncorrected bounce)."""
    geom = Geometry(load_shared("cornell-box"))
    mats = _materials()
    g = np.random.default_rng(12)
    n_paths, n_hits = 3000, 2000
    rows, pos, ns, ng, d, o, flux = _paths(g, n_paths, n_hits, geom)
    tilt = g.normal(scale=0.3, size=ns.shape)
    ng = ns + tilt
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    bumped = np.ones(n_hits, bool)
    bumped[::4] = False  # a quarter not mapped (their interpolated normal stands for the surface)
    sp = bsdf.gather(mats, g.integers(-1, len(mats), n_hits), g.random((n_hits, 2)))
    sel = np.arange(n_hits)
    u = g.random((n_paths, 20))
    got_state = [a.copy() for a in (d, o, flux)]
    want_state = [a.copy() for a in (d, o, flux)]
    plain = [a.copy() for a in (d, o, flux)]
    continue_paths(sp, geom, sel, rows, pos, ns, ng, *got_state, u, 8, bumped=bumped)
    continue_paths_numpy(sp, geom, sel, rows, pos, ns, ng, *want_state, u, 8, bumped=bumped)
    continue_paths(sp, geom, sel, rows, pos, ns, ng, *plain, u, 8)
    fin = np.isfinite(want_state[2]).all(axis=1)
    np.testing.assert_allclose(got_state[2][fin], want_state[2][fin], rtol=1e-9, atol=1e-12)
    flat = rows[::4]
    np.testing.assert_array_equal(got_state[2][flat], plain[2][flat])
    tilted = np.setdiff1d(rows, flat)
    tilted = tilted[(plain[2][tilted] > 0).any(axis=1) & np.isfinite(plain[2][tilted]).all(axis=1)]
    changed = ~np.isclose(got_state[2][tilted], plain[2][tilted]).all(axis=1)
    assert len(tilted) > 300 and changed.mean() > 0.7  # not a no-op where the normals differ
