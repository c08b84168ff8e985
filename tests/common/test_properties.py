"""Property tests (hypothesis) for the numerical kernels (issue 8).

- BSDFs: for random materials and directions (grazing ones and back faces included) every
  sample is finite, non-delta samples satisfy weight == eval/pdf and pdf == pdf(wi, wo), and
  eval/pdf are finite and non-negative everywhere.
- Wire codec: octahedral normals round-trip within 1e-4 rad, float16 quantization within its
  half-ulp bound (clamped, NaN -> 0), a whole tile through encode/decode equals the per-field
  quantization exactly.
- Hashed photon grid: query pairs equal brute force, with points and queries on cell borders.
- Sobol stream: blocks are disjoint pieces whose union is the prefix of the sequence.
"""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from igi.common import bsdf
from igi.common.codec import decode, encode, oct_decode, oct_encode, to_f16
from igi.common.frame import TileBuffers
from igi.common.scene import (CONDUCTOR, DIELECTRIC, DIFFUSE, PLASTIC, ROUGHCONDUCTOR, ROUGHPLASTIC,
                          THINDIELECTRIC, Material, Texture)
from igi.common.sobol_stream import SobolStream
from igi.worker.hash_grid import HashGrid

SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])

unit = st.floats(0.0, 1.0, allow_nan=False, exclude_max=True)
rgb = st.tuples(unit, unit, unit)


# ------------------------------------------------------------------------------------- BSDFs

@st.composite
def materials(draw):
    kind = draw(st.sampled_from([DIFFUSE, ROUGHCONDUCTOR, PLASTIC, ROUGHPLASTIC, CONDUCTOR, DIELECTRIC,
                                 THINDIELECTRIC]))
    twosided = draw(st.booleans())
    diffuse = Texture.constant(draw(rgb))
    specular = Texture.constant(draw(st.tuples(*[st.floats(0.0, 1.0)] * 3)))
    if kind == ROUGHPLASTIC:
        # Each new (alpha, eta, distribution) costs a ~1-2 s table build: two fixed ones.
        dist = draw(st.sampled_from(["ggx", "beckmann"]))
        return Material("rp", kind, diffuse=diffuse, specular=specular, alpha=0.3, int_ior=1.5, ext_ior=1.0,
                        distribution=dist, nonlinear=draw(st.booleans()), twosided=twosided)
    alpha = draw(st.floats(1e-3, 1.0))
    int_ior = draw(st.floats(1.0, 3.0))
    ext_ior = draw(st.sampled_from([1.0, 1.000277, 1.33, 2.0]))
    eta = np.array(draw(st.tuples(*[st.floats(0.0, 4.0)] * 3)))
    k = np.array(draw(st.tuples(*[st.floats(0.0, 6.0)] * 3)))
    return Material("m", kind, diffuse=diffuse, specular=specular,
                    specular_transmittance=Texture.constant(draw(rgb)), alpha=alpha, int_ior=int_ior,
                    ext_ior=ext_ior, eta=eta, k=k, distribution=draw(st.sampled_from(["ggx", "beckmann"])),
                    nonlinear=draw(st.booleans()), twosided=twosided)


# cos(theta) from exactly grazing (0, 1e-7) to normal incidence, on both sides
cos_theta = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([0.0, 1e-7, -1e-7, 1e-4, 1.0, -1.0, 0.999999]))
direction = st.tuples(cos_theta, st.floats(0.0, 2 * np.pi))


def _dirs(pairs) -> np.ndarray:
    c = np.array([p[0] for p in pairs], np.float64)
    phi = np.array([p[1] for p in pairs], np.float64)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    return np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=1)


@settings(max_examples=150, **SETTINGS)
@given(mat=materials(), wi=st.lists(direction, min_size=1, max_size=8),
       u=st.lists(st.tuples(unit, unit, unit), min_size=8, max_size=8))
def test_bsdf_sample_eval_pdf_consistency(mat, wi, u):
    n = len(wi)
    sp = bsdf.SurfacePoints.constant(mat, n)
    w_in = _dirs(wi)
    uu = np.array(u[:n], np.float64)
    wo, weight, p, delta = bsdf.sample(sp, w_in, uu[:, 0], uu[:, 1:])
    assert np.all(np.isfinite(wo)) and np.all(np.isfinite(weight)) and np.all(np.isfinite(p))
    assert np.all(weight >= 0) and np.all(p >= 0)
    ok = (p > 0) | delta
    assert np.all(weight[~ok] == 0)  # failed samples carry nothing
    np.testing.assert_allclose(np.linalg.norm(wo[ok], axis=1), 1.0, atol=1e-6)
    nd = ~delta & (p > 0)
    if nd.any():
        sub = sp.subset(nd)
        ev = bsdf.eval(sub, w_in[nd], wo[nd])
        pp = bsdf.pdf(sub, w_in[nd], wo[nd])
        np.testing.assert_allclose(pp, p[nd], rtol=1e-6, atol=0)
        # weight == eval / pdf; atol relative to the weight scale (eval near 0 at grazing wo)
        np.testing.assert_allclose(ev / pp[:, None], weight[nd], rtol=1e-6, atol=1e-9 * (1 + weight[nd].max()))
    # eval / pdf of arbitrary direction pairs: finite, non-negative; delta kinds have none
    wo2 = _dirs(list(reversed(wi)))
    ev2 = bsdf.eval(sp, w_in, wo2)
    pp2 = bsdf.pdf(sp, w_in, wo2)
    assert np.all(np.isfinite(ev2)) and np.all(ev2 >= 0) and np.all(np.isfinite(pp2)) and np.all(pp2 >= 0)
    if mat.kind in (CONDUCTOR, DIELECTRIC, THINDIELECTRIC):
        assert not ev2.any() and not pp2.any()
    alb = bsdf.albedo(sp, w_in)
    assert np.all(np.isfinite(alb)) and np.all(alb >= 0)


@settings(max_examples=60, **SETTINGS)
@given(eta=st.floats(1.01, 4.0), c=st.floats(0.0, 1.0), phi=st.floats(0.0, 2 * np.pi), u1=unit)
def test_dielectric_total_internal_reflection_and_index_matched_interface(eta, c, phi, u1):
    """From inside (cos < 0), beyond the critical angle every sample reflects with weight 1;
    an index-matched interface (eta = 1) transmits straight through with weight 1."""
    wi = _dirs([(-c, phi)])
    mat = Material("g", DIELECTRIC, int_ior=eta, ext_ior=1.0)
    sp = bsdf.SurfacePoints.constant(mat, 1)
    wo, w, p, d = bsdf.sample(sp, wi, np.array([u1]), np.array([[0.5, 0.5]]), mode="importance")
    assert d.all() and np.all(np.isfinite(w))
    sin_t = np.sqrt(max(0.0, 1 - c * c)) * eta  # Snell from inside: sin_t = eta sin_i
    if sin_t > 1 + 1e-9:
        np.testing.assert_allclose(wo, wi * [-1, -1, 1], atol=1e-12)  # mirror, stays inside
        np.testing.assert_allclose(w, 1.0, rtol=1e-12)
    matched = bsdf.SurfacePoints.constant(Material("m", DIELECTRIC, int_ior=1.0, ext_ior=1.0), 1)
    wo, w, p, d = bsdf.sample(matched, wi, np.array([u1]), np.array([[0.5, 0.5]]), mode="radiance")
    # u1 == 0 picks the R = 0 lobe (u1 <= R, as Mitsuba): a failed sample. Below cos ~ 1e-8,
    # 1 - cos² rounds to 1 in float64 and the refracted cosine has no digits left.
    if c > 1e-7 and u1 > 0:
        np.testing.assert_allclose(wo, -wi, atol=1e-9)  # straight through
        np.testing.assert_allclose(w, 1.0, rtol=1e-9)


# ------------------------------------------------------------------------------------- codec

normal_vec = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: sum(x * x for x in v) > 1e-12)


@settings(max_examples=200, **SETTINGS)
@given(st.lists(normal_vec, min_size=1, max_size=32))
def test_octahedral_normals_round_trip(vs):
    n = np.array(vs, np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    q = oct_encode(n)
    assert q.dtype == np.int16
    m = oct_decode(q).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-6)
    # atan2(|n x m|, n.m): arccos near 1 would turn float32 normalization error into 1e-4 rad
    def angle(a, b):
        return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))

    assert angle(n, m).max() < 1e-4
    # Repeated transfers do not drift (the -z pole has several codes, so compare directions).
    m2 = m
    for _ in range(3):
        m2 = oct_decode(oct_encode(m2)).astype(np.float64)
    assert angle(n, m2).max() < 1e-4


f16_values = st.one_of(
    st.floats(-70000.0, 70000.0, allow_nan=False, width=32),
    st.floats(-2.0 ** -13, 2.0 ** -13, width=32),  # float16 subnormals and the smallest normals
    st.sampled_from([np.nan, np.inf, -np.inf, 65504.0, 65520.0, -65519.0, 6.1e-5, 5.96e-8, 2.98e-8, 0.0, -0.0]),
)


@settings(max_examples=200, **SETTINGS)
@given(st.lists(f16_values, min_size=1, max_size=64))
def test_float16_quantization_bound(vals):
    x = np.array(vals, np.float32)
    h = to_f16(x)
    assert h.dtype == np.float16
    y = h.astype(np.float64)
    assert np.all(np.isfinite(y))
    xf = np.nan_to_num(x.astype(np.float64), nan=0.0, posinf=np.inf, neginf=-np.inf)
    clamped = np.clip(xf, -65504.0, 65504.0)
    # round to nearest: half an ulp of float16 (2^-11 relative; 2^-25 absolute for subnormals)
    bound = np.maximum(np.abs(clamped) * 2.0 ** -11, 2.0 ** -25)
    assert np.all(np.abs(y - clamped) <= bound), (x, y)
    # the table-free fast path agrees with numpy's own float16 rounding
    np.testing.assert_array_equal(h.view(np.uint16), clamped.astype(np.float32).astype(np.float16).view(np.uint16))


@settings(max_examples=60, **SETTINGS)
@given(p=st.integers(0, 200), seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-6, 1.0, 1e3, 1e6]))
def test_tile_buffers_round_trip_equals_field_quantization(p, seed, scale):
    rng = np.random.default_rng(seed)

    def rgb_(k):
        a = (rng.random((p, 3)) * scale).astype(np.float32)
        if p:
            a[rng.random((p, 3)) < 0.05] = np.nan
            a[rng.random((p, 3)) < 0.05] = np.inf
        return a

    n = rng.normal(size=(p, 3)).astype(np.float32)
    if p:
        n[rng.random(p) < 0.1] = 0.0
    depth = (rng.random(p) * 100).astype(np.float32)
    if p:
        depth[rng.random(p) < 0.1] = np.inf
        depth[rng.random(p) < 0.05] = np.nan
    b = TileBuffers(reflectance=rgb_(0), irradiance=rgb_(1), unfiltered=rgb_(2), depth=depth, normal=n)
    out = decode(encode(b), p)
    for name in ("reflectance", "irradiance", "unfiltered"):
        got = getattr(out, name)
        assert np.all(np.isfinite(got))
        np.testing.assert_array_equal(got, to_f16(getattr(b, name)).astype(np.float32))
    np.testing.assert_array_equal(out.depth, np.where(np.isnan(depth), np.float32(np.inf), depth))
    np.testing.assert_array_equal(out.normal, oct_decode(oct_encode(n)))


# ------------------------------------------------------------------------------- hash grid

def _brute(points, queries, r):
    d = points[None, :, :] - queries[:, None, :]
    q, p = np.nonzero(np.einsum("qpk,qpk->qp", d, d) <= r * r)
    return set(zip(q.tolist(), p.tolist()))


@st.composite
def grid_case(draw):
    r = draw(st.one_of(st.sampled_from([0.25, 0.5, 1.0, 2.0 ** -10]), st.floats(1e-3, 10.0)))
    # lattice coordinates k * r/2: on cell borders (cell = 2r), cell centres and between
    lattice = st.integers(-12, 12).map(lambda k: k * r / 2)
    anywhere = st.floats(-8 * r, 8 * r)
    coord = st.one_of(lattice, anywhere)
    point = st.tuples(coord, coord, coord)
    pts = draw(st.lists(point, min_size=1, max_size=60))
    qs = draw(st.lists(point, min_size=1, max_size=40))
    offset = draw(st.sampled_from([0.0, 0.0, 1e5, -3e7]))
    return np.array(pts) + offset, np.array(qs) + offset, r


@settings(max_examples=200, **SETTINGS)
@given(grid_case())
# a photon just outside the ball (z = -3.9e-22 under a query at r = 0.25) whose rounded distance
# is r: inside by the distance test, in a cell below floor((x - r) / 2r)
@example((np.array([[0.0, 0.0, -3.88129073e-22]]), np.array([[0.0, 0.0, 0.25]]), 0.25))
def test_hash_grid_query_equals_brute_force(case):
    pts, qs, r = case
    assume(np.all(np.isfinite(pts)))
    pidx, qidx = HashGrid(pts, r).query(qs)
    got = list(zip(qidx.tolist(), pidx.tolist()))
    assert len(got) == len(set(got)), "a photon reported twice for one query"
    assert np.all(np.diff(qidx) >= 0), "pairs must be grouped by ascending query"
    assert set(got) == _brute(pts, qs, r)


# ----------------------------------------------------------------------------------- Sobol

@settings(max_examples=40, **SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), bs=st.integers(1, 64), nblocks=st.integers(1, 6),
       dims=st.integers(1, 9), counts=st.lists(st.integers(0, 64), min_size=6, max_size=6))
def test_sobol_blocks_are_disjoint_and_their_union_is_the_prefix(seed, bs, nblocks, dims, counts):
    s = SobolStream(seed, dims)
    prefix = s.points(0, nblocks * bs)
    # full blocks in order are exactly the prefix
    full = np.concatenate([s.block(k, bs, bs) for k in range(nblocks)])
    np.testing.assert_array_equal(full, prefix)
    # partial blocks are the first rows of their block: disjoint row ranges, no shared point
    parts = [s.block(k, min(counts[k], bs), bs) for k in range(nblocks)]
    for k, part in enumerate(parts):
        np.testing.assert_array_equal(part, prefix[k * bs:k * bs + len(part)])
    rows = [tuple(r) for part in parts for r in part]
    assert len(rows) == len(set(rows))
    # padded replications: group 0 is a plain prefix, every other group's block is a
    # permutation of that group's rows of the block, so blocks still partition the prefix
    total = max(dims, 5)
    whole = s.padded(0, nblocks * bs, nblocks * bs, total)
    blocks = [s.padded(k, bs, bs, total) for k in range(nblocks)]
    np.testing.assert_array_equal(np.concatenate([b[:, :4] for b in blocks]), whole[:, :4])
    for g0 in range(4, total, 4):
        for k, b in enumerate(blocks):
            got = b[:, g0:g0 + 4]
            want = SobolStream(seed, dims).padded(k, bs, bs, total)[:, g0:g0 + 4]
            np.testing.assert_array_equal(got, want)  # deterministic
            # the same rows as the group's own (unshuffled) sequence over this block's range
            eng = _group_rows(s, g0 // 4, min(4, total - g0), k * bs, bs)
            assert sorted(map(tuple, got)) == sorted(map(tuple, eng))
        # and the whole padded prefix holds each group's first nblocks*bs rows exactly once
        eng_all = _group_rows(s, g0 // 4, min(4, total - g0), 0, nblocks * bs)
        assert sorted(map(tuple, whole[:, g0:g0 + 4])) == sorted(map(tuple, eng_all))
        assert sorted(map(tuple, np.concatenate([b[:, g0:g0 + 4] for b in blocks]))) == sorted(map(tuple, eng_all))


def _group_rows(stream: SobolStream, g: int, d: int, start: int, count: int) -> np.ndarray:
    """Rows [start, start+count) of padded group g's own Sobol' instance (unshuffled)."""
    from igi.common.sobol_stream import _TAG_GROUP, _draw, _scrambling

    return _draw(_scrambling(d, stream.seed, _TAG_GROUP, g), start, count)
