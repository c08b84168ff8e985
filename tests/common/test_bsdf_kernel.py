"""The compiled BSDF kernels (common.kernels.bsdf, through common.bsdf) give the values of the
numpy BSDFs they replaced (tests/support/oracle_bsdf.py) on random and edge-case inputs.

Tolerance: rtol 1e-5. Both compute in float64, but the oracle multiplies some float32 point
parameters in float32 before widening (eta², a conductor's eta² - k² - sin², where the
cancellation of textured IORs brings its ~6e-8 rounding up to ~1e-6 relative); and the
Beckmann sampler inverts erf with scipy there and with a Halley-refined polynomial here
(agreeing to ~1e-15, amplified to ~1e-11 in the sampled direction near grazing incidence).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import erfinv as scipy_erfinv

from igi.common import bsdf, coat_tables
from igi.common.fresnel import fresnel_diffuse_reflectance
from igi.common.kernels import bsdf as kb
from igi.common.microfacet import rough_plastic_tables
from igi.common.scene import (
    CONDUCTOR,
    DIELECTRIC,
    DIFFUSE,
    KIND_NAMES,
    NULL,
    PLASTIC,
    ROUGHCONDUCTOR,
    ROUGHDIELECTRIC,
    ROUGHPLASTIC,
    ROUGHPLASTIC_DIFFUSE,
    ROUGHPLASTIC_LOBE,
    THINDIELECTRIC,
    Material,
    Texture,
)
from tests.support import oracle_bsdf as oracle

RTOL = 1e-5
ATOL = 1e-12
# the oracle's numpy warns on the NaN, Inf and grazing inputs (the kernels do not)
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
KINDS = (DIFFUSE, CONDUCTOR, ROUGHCONDUCTOR, DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC, PLASTIC, ROUGHPLASTIC,
         ROUGHPLASTIC_DIFFUSE, ROUGHPLASTIC_LOBE, NULL)
SPLIT = (ROUGHPLASTIC_DIFFUSE, ROUGHPLASTIC_LOBE)  # internal kinds: parts of a rough plastic


def _unit(rng, n):
    w = rng.normal(size=(n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def _directions(rng, n=400):
    """(wi, wo) pairs: random on the sphere (above and below the horizon), grazing on either
    side (|cos| = 1e-6, 1e-9, 0), exactly normal incidence and exit (both sides), wi == wo and
    wo == -wi."""
    pairs = [(_unit(rng, n), _unit(rng, n))]
    for z in (1e-6, -1e-6, 1e-9, 0.0):
        g = _unit(rng, n)
        g[:, :2] /= np.linalg.norm(g[:, :2], axis=1, keepdims=True) / math.sqrt(1 - z * z)
        g[:, 2] = z
        pairs += [(g, _unit(rng, n)), (_unit(rng, n), g)]
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    pairs += [(up, _unit(rng, n)), (_unit(rng, n), up), (up, up), (-up, up), (up, -up)]
    w = _unit(rng, n)
    pairs += [(w, w.copy()), (w, -w)]
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


def _randoms(rng, n):
    u1, u2 = rng.random(n), rng.random((n, 2))
    u1[::37] = 0.0
    u2[::41] = 0.0
    u2[::43, 1] = 1.0 - 1e-16
    return u1, u2


def _material(kind, dist="ggx", twosided=False, alpha=0.3, int_ior=1.5):
    base = ROUGHPLASTIC if kind in SPLIT else kind
    return Material(f"{KIND_NAMES.get(kind, kind)}_{dist}", base, diffuse=Texture.constant([0.6, 0.3, 0.1]),
                    alpha=alpha, distribution=dist, twosided=twosided, int_ior=int_ior, ext_ior=1.0,
                    eta=np.array([0.2, 0.9, 1.1]), k=np.array([3.0, 2.4, 1.8]))


def _textured(sp, rng, vary_coat=False):
    """Per-point varying parameters, as textures give: colours, conductor IORs, the plastics'
    sampling weight and nonlinearity; roughness and eta too, except (unless ``vary_coat``) for
    rough plastics, whose coat tables are per material."""
    n = len(sp)
    f32 = np.float32
    rough = np.isin(sp.kind, (ROUGHPLASTIC, *SPLIT)) & (not vary_coat)
    alpha = np.where(rough, sp.alpha, rng.uniform(0.02, 0.9, n)).astype(f32)
    eta = np.where(rough, sp.eta, rng.choice([1.2, 1.5, 2.4, 1 / 1.33, 1.0], n)).astype(f32)
    return dataclasses.replace(
        sp, diffuse=rng.random((n, 3)).astype(f32), specular=rng.random((n, 3)).astype(f32),
        transmittance=rng.random((n, 3)).astype(f32), cond_eta=rng.uniform(0, 3, (n, 3)).astype(f32),
        cond_k=rng.uniform(0, 4, (n, 3)).astype(f32), alpha=alpha, eta=eta,
        nonlinear=rng.random(n) < 0.5, spec_weight=rng.random(n).astype(f32),
        coat_row=None if vary_coat else sp.coat_row)


def _points(materials, n, rng, relabel_diffuse_layer=0.0, part=ROUGHPLASTIC_DIFFUSE):
    sp = bsdf.gather(materials, rng.integers(0, len(materials), n), None)
    if relabel_diffuse_layer:
        kind = sp.kind.copy()
        sel = (kind == ROUGHPLASTIC) & (rng.random(n) < relabel_diffuse_layer)
        kind[sel] = part
        sp = dataclasses.replace(sp, kind=kind)
    return sp


def _close(got, want, what):
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    assert got.shape == want.shape, what
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL, err_msg=what)


def _assert_all_functions_match_the_oracle(sp, wi, wo, u1, u2):
    _close(bsdf.eval(sp, wi, wo), oracle.eval(sp, wi, wo), "eval")
    _close(bsdf.pdf(sp, wi, wo), oracle.pdf(sp, wi, wo), "pdf")
    for mode in ("radiance", "importance"):
        got = bsdf.sample(sp, wi, u1, u2, mode=mode)
        want = oracle.sample(sp, wi, u1, u2, mode=mode)
        for name, g, w in zip(("wo", "weight", "pdf"), got[:3], want[:3]):
            _close(g, w, f"sample {mode} {name}")
        np.testing.assert_array_equal(got[3], want[3], err_msg=f"sample {mode} delta")
        got = bsdf.specular_components(sp, wi, mode=mode, u2=u2)
        want = oracle.specular_components(sp, wi, mode=mode, u2=u2)
        for c in range(2):
            _close(got[c][0], want[c][0], f"specular {c} wo")
            _close(got[c][1], want[c][1], f"specular {c} weight")
            np.testing.assert_array_equal(got[c][2], want[c][2], err_msg=f"specular {c} valid")
    for name, g, w in zip(("wo", "weight"), bsdf.sample_lobe(sp, wi, u2), oracle.sample_lobe(sp, wi, u2)):
        _close(g, w, f"sample_lobe {name}")
    _close(bsdf.albedo(sp, wi), oracle.albedo(sp, wi), "albedo")


# ------------------------------------------------------------------------------- per kind


@pytest.mark.parametrize("twosided", [False, True], ids=["onesided", "twosided"])
@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("kind", KINDS, ids=[KIND_NAMES.get(k, str(k)) for k in KINDS])
def test_every_kind_matches_the_numpy_oracle_front_back_and_grazing(kind, dist, twosided):
    rng = np.random.default_rng(kind * 4 + (dist == "beckmann") * 2 + twosided)
    wi, wo = _directions(rng)
    n = len(wi)
    sp = _points([_material(kind, dist, twosided)], n, rng, relabel_diffuse_layer=float(kind in SPLIT), part=kind)
    u1, u2 = _randoms(rng, n)
    _assert_all_functions_match_the_oracle(sp, wi, wo, u1, u2)
    # the same with per-point (textured) parameters
    _assert_all_functions_match_the_oracle(_textured(sp, rng), wi, wo, u1, u2)


def test_mixed_kinds_and_several_rough_plastics_in_one_call_match_the_oracle():
    rng = np.random.default_rng(100)
    mats = [_material(k, d, t) for k in KINDS if k not in SPLIT
            for d in ("ggx", "beckmann") for t in (False, True)]
    mats += [_material(ROUGHPLASTIC, d, alpha=a, int_ior=e)
             for d, a, e in (("ggx", 0.05, 1.3), ("beckmann", 0.15, 1.5), ("ggx", 0.6, 2.0), ("beckmann", 0.9, 1.1))]
    wi, wo = _directions(rng, 300)
    n = len(wi)
    sp = _points(mats, n, rng, relabel_diffuse_layer=0.3)
    assert len(np.unique(sp.coat_row)) >= 7  # distinct coats in one call (row 0: the others)
    u1, u2 = _randoms(rng, n)
    _assert_all_functions_match_the_oracle(sp, wi, wo, u1, u2)
    _assert_all_functions_match_the_oracle(_textured(sp, rng), wi, wo, u1, u2)


def test_rough_plastics_without_gathered_coat_rows_match_the_oracle():
    """Hand-built points (no coat_row) with per-point roughness and eta: looked up per call."""
    rng = np.random.default_rng(101)
    wi, wo = _directions(rng, 100)
    n = len(wi)
    mats = [_material(ROUGHPLASTIC, d) for d in ("ggx", "beckmann")]
    sp = _textured(_points(mats, n, rng, relabel_diffuse_layer=0.5), rng, vary_coat=True)
    # a few distinct coats (each new one is a table computation)
    sp.alpha = rng.choice(np.array([0.3, 0.4], np.float32), n)
    sp.eta = np.full(n, 1.5, np.float32)
    assert sp.coat_row is None
    u1, u2 = _randoms(rng, n)
    _assert_all_functions_match_the_oracle(sp, wi, wo, u1, u2)
    # points relabelled to a rough plastic after gather (their gathered row is 0) are looked up too
    d = _points([_material(DIFFUSE)], n, rng)
    d = dataclasses.replace(d, kind=np.full(n, ROUGHPLASTIC, np.int8), alpha=np.full(n, 0.4, np.float32),
                            eta=np.full(n, 1.5, np.float32))
    assert not d.coat_row.any()
    _assert_all_functions_match_the_oracle(d, wi, wo, u1, u2)


def test_coat_transmittance_tables_and_means_match_the_oracle():
    rng = np.random.default_rng(102)
    mats = [_material(ROUGHPLASTIC, "beckmann"), _material(ROUGHPLASTIC, "ggx", alpha=0.05, int_ior=1.3),
            _material(DIFFUSE)]
    sp = _points(mats, 500, rng, relabel_diffuse_layer=0.5)
    rough = np.isin(sp.kind, (ROUGHPLASTIC, *SPLIT))
    tabs, rows, t_avg = bsdf.coat_transmittance(sp)
    o_tabs, o_rows, o_avg = oracle.coat_transmittance(sp.subset(rough))
    _close(tabs[rows[rough]], o_tabs[o_rows], "tables")
    _close(t_avg[rough], o_avg, "t_avg")
    np.testing.assert_array_equal(rows[~rough], 0)
    np.testing.assert_array_equal(tabs[0], 1.0)  # the others read an all-ones table


# ------------------------------------------------------------------------------- edge cases


@pytest.mark.parametrize("kind", KINDS, ids=[KIND_NAMES.get(k, str(k)) for k in KINDS])
def test_nan_and_inf_directions_give_finite_results_and_match_the_oracle_where_it_runs(kind):
    """NaN/Inf components give finite (mostly zero) results, as the oracle's; where the oracle
    itself fails (rough plastics with a NaN cos θ: its table lookup indexes with NaN and raises
    IndexError), the kernel gives weight 0."""
    rng = np.random.default_rng(103)
    good = _unit(rng, 8)
    good[:, 2] = np.abs(good[:, 2])
    bad = np.array([[np.nan, 0, 1], [0, 0, np.nan], [np.inf, 0, 1], [0, 0, np.inf], [0, 0, -np.inf],
                    [np.nan] * 3, [1, 1, np.inf], [-np.inf, np.inf, 0.5]])
    sp = _points([_material(kind, "beckmann", twosided=True)], 8, rng,
                 relabel_diffuse_layer=float(kind == ROUGHPLASTIC_DIFFUSE))
    u1, u2 = _randoms(rng, 8)
    for wi, wo in ((bad, good), (good, bad), (bad, bad)):
        res = [bsdf.eval(sp, wi, wo), bsdf.pdf(sp, wi, wo), *bsdf.sample(sp, wi, u1, u2)[1:3],
               bsdf.sample_lobe(sp, wi, u2)[1], bsdf.albedo(sp, wi)]
        res += [c[1] for c in bsdf.specular_components(sp, wi, u2=u2)]
        for r in res:
            assert np.all(np.isfinite(r))
        for i in range(8):  # one point at a time: the oracle's failure on one does not hide the others
            _assert_point_matches_where_the_oracle_runs(sp.subset(slice(i, i + 1)), wi[i:i + 1], wo[i:i + 1],
                                                        u1[i:i + 1], u2[i:i + 1])


def _assert_point_matches_where_the_oracle_runs(one, wi, wo, u1, u2):
    """Every function's outputs equal the oracle's, except where the oracle raises: there the
    parts a caller accumulates (values, weights, pdfs) are 0. Entries: (name, call, those parts)."""
    checks = (("eval", lambda m: [m.eval(one, wi, wo)], slice(None)),
              ("pdf", lambda m: [m.pdf(one, wi, wo)], slice(None)),
              ("sample", lambda m: list(m.sample(one, wi, u1, u2)), slice(1, 3)),
              ("sample_lobe", lambda m: list(m.sample_lobe(one, wi, u2)), slice(1, 2)),
              ("albedo", lambda m: [m.albedo(one, wi)], slice(None)),
              ("specular", lambda m: [x for c in m.specular_components(one, wi, u2=u2) for x in c], slice(None)))
    for name, call, weights in checks:
        got = call(bsdf)
        try:
            want = call(oracle)
        except IndexError:  # the oracle's rough-plastic table lookup at a NaN cosine
            assert one.kind[0] in (ROUGHPLASTIC, ROUGHPLASTIC_DIFFUSE), name
            assert np.isnan(wi[0, 2]) or np.isnan(wo[0, 2]) or np.isnan(got[0]).any(), name
            for g in got[weights]:
                np.testing.assert_array_equal(g, 0.0, err_msg=name)
            continue
        for g, w in zip(got, want):
            _close(g, w, name)


def test_empty_inputs_give_empty_outputs_of_the_input_dtype():
    for dt in (np.float32, np.float64):
        sp = _points([_material(ROUGHPLASTIC)], 0, np.random.default_rng(0))
        z3, z2, z1 = np.zeros((0, 3), dt), np.zeros((0, 2), dt), np.zeros(0, dt)
        assert bsdf.eval(sp, z3, z3).shape == (0, 3) and bsdf.eval(sp, z3, z3).dtype == dt
        assert bsdf.pdf(sp, z3, z3).shape == (0,)
        wo, w, p, d = bsdf.sample(sp, z3, z1, z2)
        assert wo.shape == w.shape == (0, 3) and p.shape == d.shape == (0,) and w.dtype == dt and d.dtype == bool
        assert [a.shape for a in bsdf.sample_lobe(sp, z3, z2)] == [(0, 3), (0, 3)]
        assert bsdf.albedo(sp, z3).shape == (0, 3)
        assert all(c[0].shape == (0, 3) and c[2].shape == (0,) for c in bsdf.specular_components(sp, z3))


def test_mismatched_direction_count_is_rejected():
    sp = _points([_material(DIFFUSE)], 3, np.random.default_rng(0))
    with pytest.raises(ValueError):
        bsdf.eval(sp, np.zeros((2, 3)), np.zeros((2, 3)))


# ------------------------------------------------------------------------ the packed layout


def test_packed_tuple_has_the_documented_order_dtypes_and_shapes():
    """The layout other compiled code is written against (common.kernels.bsdf docstring)."""
    rng = np.random.default_rng(104)
    mats = [_material(ROUGHPLASTIC, "beckmann"), _material(PLASTIC), _material(DIFFUSE)]
    sp = _points(mats, 50, rng)
    P = sp.packed()
    n, g = 50, len(coat_tables.tables()[0])
    layout = [("kind", np.int8, (n,)), ("diffuse", np.float64, (n, 3)), ("specular", np.float64, (n, 3)),
              ("transm", np.float64, (n, 3)), ("alpha", np.float64, (n,)), ("eta", np.float64, (n,)),
              ("cond_eta", np.float64, (n, 3)), ("cond_k", np.float64, (n, 3)), ("beck", np.bool_, (n,)),
              ("nonlin", np.bool_, (n,)), ("twos", np.bool_, (n,)), ("spec_weight", np.float64, (n,)),
              ("rtabs", np.float64, (g, 64)), ("rrefl", np.float64, (g, 64)), ("rrow", np.int64, (n,)),
              ("fdr_int", np.float64, (n,)), ("tavg", np.float64, (n,))]
    assert len(P) == len(layout)
    for a, (name, dt, shape) in zip(P, layout):
        assert a.dtype == dt and a.shape == shape and a.flags.c_contiguous, name
    np.testing.assert_array_equal(P[1], sp.diffuse.astype(np.float64))
    rough = sp.kind == ROUGHPLASTIC
    plastic = sp.kind == PLASTIC
    np.testing.assert_array_equal(P[14], sp.coat_row)
    assert np.all(P[14][rough] > 0) and np.all(P[14][~rough] == 0)
    _, r_int, _ = rough_plastic_tables(0.3, 1.5, True)
    np.testing.assert_allclose(P[15][rough], r_int)
    np.testing.assert_allclose(P[15][plastic], fresnel_diffuse_reflectance(1.0 / sp.eta[plastic].astype(float)))
    np.testing.assert_allclose(P[16][rough], coat_tables.cosine_mean(P[12][P[14][rough]]))
    np.testing.assert_allclose(P[16][~rough], 1.0)


def test_gathered_coat_rows_survive_subset_and_equal_the_looked_up_ones():
    rng = np.random.default_rng(105)
    mats = [_material(ROUGHPLASTIC, "beckmann"), _material(ROUGHPLASTIC, "ggx", alpha=0.4), _material(DIFFUSE)]
    sp = _points(mats, 200, rng)
    sub = sp.subset(np.arange(0, 200, 3))
    np.testing.assert_array_equal(sub.coat_row, sp.coat_row[::3])
    looked_up = dataclasses.replace(sp, coat_row=None).packed()
    for a, b in zip(sp.packed(), looked_up):
        np.testing.assert_array_equal(a, b)


def test_erfinv_matches_scipy_to_float64_precision_including_the_tails():
    y = np.concatenate([np.linspace(-1, 1, 20001), 1 - np.logspace(-16, -1, 300), -1 + np.logspace(-16, -1, 300),
                        np.logspace(-300, -1, 50), [1.5, -1.5, np.nan]])
    got = np.array([kb.erfinv(v) for v in y])
    want = scipy_erfinv(y)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    fin = np.isfinite(want)
    np.testing.assert_array_equal(got[~fin & ~np.isnan(want)], want[~fin & ~np.isnan(want)])  # ±inf at ±1
    np.testing.assert_allclose(got[fin], want[fin], rtol=4e-15, atol=0)



@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.02, 0.15, 0.6])
@pytest.mark.parametrize("kind", (ROUGHCONDUCTOR, ROUGHPLASTIC, ROUGHPLASTIC_LOBE, PLASTIC),
                         ids=lambda k: KIND_NAMES.get(k, str(k)))
def test_lobe_shape_guesses_the_bsdf_positive_and_never_far_below_it(kind, alpha, dist):
    """kb.lobe_shape's guess of f(wi, wo)|cos θ_o| — spec · F(cos θ_d) · Dn(h) + diffuse · cos θ_o
    (the shadow roulette's guess of a glossy row's pairs, worker.kernels.vpl_gather._lobe_guess)
    — is positive wherever f is and above half of it (its luminance) at random directions above
    the horizon, grazing ones included, textured parameters too: the roulette never keeps a
    bright pair of a lobe with a tiny probability."""
    rng = np.random.default_rng(107)
    n = 3000
    sp = _points([_material(kind, dist, alpha=alpha)], n, rng, relabel_diffuse_layer=kind == ROUGHPLASTIC_LOBE,
                 part=ROUGHPLASTIC_LOBE)
    if kind != ROUGHPLASTIC_LOBE:  # (a rough plastic's coat tables are per material: only its colours vary)
        sp = _textured(sp, rng) if kind != ROUGHPLASTIC else dataclasses.replace(
            sp, diffuse=rng.random((n, 3)).astype(np.float32), specular=rng.random((n, 3)).astype(np.float32))
    wi, wo = _unit(rng, n), _unit(rng, n)
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi[::7, 2] *= 1e-3  # grazing eyes
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    # half of them in and around the lobe: wi mirrored about normals spread by ~2α
    m = np.column_stack([2 * alpha * rng.normal(size=(n, 2)), np.ones(n)])
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    mirror = 2 * np.sum(wi * m, axis=1, keepdims=True) * m - wi
    near = (np.arange(n) % 2 == 0) & (mirror[:, 2] > 0)
    wo[near] = mirror[near]
    f = bsdf.eval(sp, wi, wo) @ np.array([0.212671, 0.715160, 0.072169])
    P = sp.packed()
    guess = np.empty(n)
    for i in range(n):
        a2, spec, diffuse, f0, _ps, _pd = kb.lobe_shape(P, i, *wi[i])
        h = (wi[i] + wo[i]) / np.linalg.norm(wi[i] + wo[i])
        dn = a2 * a2 / (h[2] ** 2 * (a2 - 1) + 1) ** 2
        fresnel = f0 + (1 - f0) * (1 - min(h @ wo[i], 1.0)) ** 5
        guess[i] = spec * fresnel * dn + diffuse * wo[i, 2]
    lit = f > 1e-12
    assert lit.sum() > n // 3  # not vacuous
    assert np.all(guess[lit] > 0)
    assert np.all(f[lit] <= 2.0 * guess[lit])
