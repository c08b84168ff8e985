"""The VPL gather (Wald et al. 2002 §4, the first sum): end points × VPLs, fused.

Three steps per chunk of end points, none with an (end points × VPLs) temporary:

1. :func:`pair_weights` — for every (end point x, VPL y) pair: geometry, the clamped
   1/max(d², c) term, emitter cosine, spot falloff, path-length limit, Lambertian receiver
   cos/π and the MIS weight of emitter samples against the BSDF ray; pairs that can carry
   light are written, in row-major order, straight into Embree's float32 shadow-ray arrays.
   :func:`roulette_row` thins each row's pairs before they are written: those whose
   unshadowed contribution is small against their end point's mean (Russian roulette on
   shadow rays: kept pairs count 1/p; a glossy end point's guess of its pairs' light takes
   the shape of its lobe, :func:`lobe_rows`).
2. Embree's occlusion query on that batch (outside: it releases the GIL itself).
3. :func:`accumulate` — the unoccluded pairs' weight × VPL colour (× per-pair BSDF factors
   for glossy receivers or senders, computed by the caller on the compact pair list) summed
   per end point.

Where the shadow BVH is an Embree packet scene, :func:`gather_packets` does all three in one
pass: the pairs go LANES at a time into an Embree packet traced from inside the kernel
(rtcOccluded8 or 16, the CPU's width: common.kernels.ray_packets) and are summed as they come
back (pairs that need a BSDF factor once their block's factors are known) — the same sums,
with no pair or ray arrays.

Both weigh their rows a block of BLOCK rows at a time (:func:`_stage`: the pairs' weights
staged per row, then thinned by the roulette); pair_weights then writes them row by row,
gather_packets column by column (one VPL's rays from neighbouring end points share a packet).
Each row still sums its pairs in column order, so both give the same sums bit for bit.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.ray_packets import FIELDS, LANES, occlude_lanes, packet_lanes
from igi.common.kernels.shading_normals import exit_ratio
from igi.common.kernels.splitmix import mix32, mix64, unit32

INV_PI = 1.0 / math.pi

# Per-row flags (receiver kind).
ROW_NONE = 0  # absorbs (NULL), or a one-sided surface seen from behind (Lambertian or glossy)
ROW_LAMBERT = 1  # Lambertian: weight carries cos/π, colour is per unit albedo
ROW_GLOSSY = 2  # any other BSDF (all reflect only): emitter factor and cos_x > 0 here, BSDF applied per pair
# A rough plastic's diffuse layer alone (ROUGHPLASTIC_DIFFUSE): Lambertian up to the coat's
# transmittance t(cos θ_o) toward the light, so per unit albedo cos/π · t(cos)/t_avg (a scalar).
ROW_LAYER = 3


@njit(cache=True, nogil=True, error_model="numpy")
def spot_falloff(cos_theta: float, cutoff_deg: float, beam_deg: float) -> float:
    """Mitsuba 3's spot falloff (as common.lights.spot_falloff): 1 in the beam, linear in
    angle to 0 at the cutoff."""
    cutoff = math.radians(cutoff_deg)
    beam = math.radians(min(beam_deg, cutoff_deg))
    if not cos_theta > math.cos(cutoff):
        return 0.0
    c = min(max(cos_theta, -1.0), 1.0)
    ang = math.acos(c)
    if ang <= beam:
        return 1.0
    width = max(cutoff - beam, 1e-12)
    return min(max((cutoff - ang) / width, 0.0), 1.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _to_vpl(x0, x1, x2, vpos, vnormal, directional, j):
    """The unnormalized direction from x to VPL j (a directional one: against its normal), in
    float32."""
    if directional[j]:
        return -vnormal[j, 0], -vnormal[j, 1], -vnormal[j, 2]
    return vpos[j, 0] - x0, vpos[j, 1] - x1, vpos[j, 2] - x2


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _length(d0, d1, d2):
    """Squared length and 1/length of a float32 vector (1/length finite: length ≥ 1e-15)."""
    dd = d0 * d0 + d1 * d1 + d2 * d2
    return dd, np.float32(1.0) / np.float32(math.sqrt(max(dd, np.float32(1e-30))))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ray_end(d0, d1, d2, directional_j, eps2):
    """A shadow ray's unit direction and tfar toward the VPL (d: unnormalized, from the
    origin): just short of the VPL (a directional one: unbounded). One square root and one
    divide a ray (its length and 1/length; the length was 1/(1/length), a second divide on
    each ray's dependency chain, the packet fill's hottest instructions)."""
    length = np.float32(math.sqrt(max(d0 * d0 + d1 * d1 + d2 * d2, np.float32(1e-30))))
    inv_d = np.float32(1.0) / length
    if directional_j:
        t = np.float32(3.0e38)
    else:
        t = max(length * np.float32(1 - 1e-4) - eps2, np.float32(0.0))
    return d0 * inv_d, d1 * inv_d, d2 * inv_d, t


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _write_ray(k, o0, o1, o2, d0, d1, d2, directional_j, eps2, out_o, out_d, out_t):
    """Shadow ray k from the offset origin toward the VPL (:func:`_ray_end`) into the arrays."""
    out_o[k, 0] = o0
    out_o[k, 1] = o1
    out_o[k, 2] = o2
    out_d[k, 0], out_d[k, 1], out_d[k, 2], out_t[k] = _ray_end(d0, d1, d2, directional_j, eps2)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def interior_origin(planes, o0, o1, o2) -> bool:
    """Whether shadow rays from origin o may go to the BVH without the triangles of the
    supporting ``planes`` (common.hull_culling; float32 (K, 4) in the centred frame, their slack
    folded into d) — those toward a column on the planes' inner side too
    (:func:`interior_column`): o on the inner side of every plane (NaN: not). No plane: no."""
    if planes.shape[0] == 0:
        return False
    for p in range(planes.shape[0]):
        if not planes[p, 0] * o0 + planes[p, 1] * o1 + planes[p, 2] * o2 + planes[p, 3] <= 0.0:
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def interior_column(col_out, j) -> bool:
    """Column j on the planes' inner side (``col_out``: the prefix count of columns outside
    one, a directional one among them)."""
    return col_out[j + 1] == col_out[j]


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_origins(pos, ns, ng, wi, center, eps, ulps, out_x, out_ns, out_ng, out_side, out_off) -> None:
    """The end points as the pair kernels take them, float32 in Embree's centred frame: x,
    ns, ng, the eye's side ±1 (wi's z >= 0: +1) and the offset length along ng toward it
    (the scene epsilon plus ``ulps`` of the largest centred coordinate, as
    common.geometry.Geometry.offset_terms)."""
    for i in range(pos.shape[0]):
        a0 = pos[i, 0] - center[0]
        a1 = pos[i, 1] - center[1]
        a2 = pos[i, 2] - center[2]
        out_x[i, 0] = np.float32(a0)
        out_x[i, 1] = np.float32(a1)
        out_x[i, 2] = np.float32(a2)
        for c in range(3):
            out_ns[i, c] = np.float32(ns[i, c])
            out_ng[i, c] = np.float32(ng[i, c])
        s = np.float32(1.0) if wi[i, 2] >= 0 else np.float32(-1.0)
        out_side[i] = s
        m = np.maximum(np.maximum(abs(a0), abs(a1)), abs(a2))
        out_off[i] = np.float32(np.float32(eps + ulps * m) * s)


@njit(cache=True, nogil=True, error_model="numpy")
def receiver_rows(kind, twosided, wi, diffuse, null, layer_kind, out) -> int:
    """out[i] = the ROW_* of end point i (BSDF ``kind``, ``twosided``, eye direction ``wi``
    local): seen from its front (twosided, or wi's z > 0) a ``diffuse`` point is ROW_LAMBERT and
    any other kind but ``null`` ROW_GLOSSY (glossy kinds reflect only); a rough plastic's diffuse
    layer (``layer_kind``) is ROW_NONE here, its rows' plastic layer the caller's; every point
    seen from behind a one-sided surface is ROW_NONE. Returns how many layer points are seen
    from the front."""
    layers = 0
    for i in range(kind.shape[0]):
        k = kind[i]
        front = twosided[i] or wi[i, 2] > 0
        r = ROW_NONE
        if front and k == diffuse:
            r = ROW_LAMBERT
        elif front and k != diffuse and k != null:
            r = ROW_GLOSSY
        if k == layer_kind:
            r = ROW_NONE
            layers += front
        out[i] = r
    return layers


@njit(cache=True, nogil=True, error_model="numpy")
def pair_rays(x, ng, off, vpos, vnormal, directional, eps2, pi, pj, out_o, out_d, out_t):
    """The shadow rays of the listed pairs (row pi[k] of x/ng/off, VPL pj[k]): what
    :func:`pair_weights` writes for them, for callers that trace only a few pairs (the
    scoring's draws, vpl_scoring.scored_draws)."""
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        o0 = x[i, 0] + ng[i, 0] * off[i]
        o1 = x[i, 1] + ng[i, 1] * off[i]
        o2 = x[i, 2] + ng[i, 2] * off[i]
        d0, d1, d2 = _to_vpl(o0, o1, o2, vpos, vnormal, directional, j)
        _write_ray(k, o0, o1, o2, d0, d1, d2, directional[j], eps2, out_o, out_d, out_t)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lambert_terms(d0, d1, d2_, n0, n1, n2, s, wxj, wyj, wzj, md2, cf, vsd, lp, ar, mi, dcount):
    """A pair's terms in the branch-free loops (_stage's SIMD rows, :func:`_lambert_columns`):
    d from the end point (normal n, eye side s) to the column (normal w, min_d2 ``md2``, cosine
    factor ``cf`` on side ``vsd``, light pdf ``lp``, an area sample ``ar``, MIS ``mi``) —
    (n·d·s, cos_x, emitter factor, light pdf, Lambertian MIS-weighted weight), all float32, as the
    pair-by-pair loop computes them (max(a, b) written as Python's: b only where b > a)."""
    f1e30 = np.float32(1e-30)
    f1e7 = np.float32(1e-7)
    zero = np.float32(0.0)
    dot_x = d0 * n0 + d1 * n1 + d2_ * n2
    dd = d0 * d0 + d1 * d1 + d2_ * d2_
    inv_d = np.float32(1.0) / np.float32(math.sqrt(f1e30 if f1e30 > dd else dd))
    cos_x = dot_x * inv_d * s
    cos_y = -(d0 * wxj + d1 * wyj + d2_ * wzj) * inv_d
    em = np.float32(1.0) / (md2 if md2 > dd else dd)
    cv = cos_y * vsd
    em = em * (zero if zero > cv else cv) if cf else em
    pl = lp
    pl = pl * dd / (f1e7 if f1e7 > cos_y else cos_y) if ar else pl
    pl = pl * dcount
    recv = (zero if zero > cos_x else cos_x) * np.float32(INV_PI)
    v = em * recv
    q2 = pl * pl + recv * recv
    v = v * (pl * pl / (f1e30 if f1e30 > q2 else q2)) if mi else v
    return dot_x * s, cos_x, em, pl, v


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _coat_weight(v, cos_x, tables, g, inv_t):
    """A plastic layer's (ROW_LAYER) pair weight: the Lambertian weight ``v`` times the coat's
    transmittance toward the VPL at cos θ_x (common.microfacet.lerp_gather of table ``g``) over
    its mean (``inv_t``: 1/t_avg), in float64, rounded to float32 once."""
    n_tab = tables.shape[1]
    xs = min(float(max(cos_x, 0.0)), 1.0) * (n_tab - 1)
    idx = min(int(xs), n_tab - 2)
    t_o = tables[g, idx] + (tables[g, idx + 1] - tables[g, idx]) * (xs - idx)
    return np.float32(v * t_o * inv_t)


# A glossy row's lobe as its roulette guess takes it (:func:`lobe_rows`): the eye direction
# (world, unit), its |cos θ| to the shading normal, then common.kernels.bsdf.lobe_shape's six.
LOBE_FIELDS = 10
NO_LOBES = np.zeros((0, LOBE_FIELDS), np.float32)  # no glossy row's lobe: the roulette's flat guesses
NO_BOOST = np.zeros(0, np.float32)  # every row's roulette threshold its own mean (:func:`roulette_row`)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def lobe_rows(P, end_row, row, wi, ns, out) -> None:
    """out[i] (float32, LOBE_FIELDS): the lobe of ROW_GLOSSY end point i (BSDF row
    ``end_row[i]`` of P, eye direction ``wi`` local to the float64 shading normal ``ns``) for
    :func:`_lobe_guess`; other rows, and kinds of no lobe shape, α² = 0 (a flat guess)."""
    for i in range(row.shape[0]):
        for f in range(LOBE_FIELDS):
            out[i, f] = 0.0
        if row[i] != ROW_GLOSSY:
            continue
        wix, wiy, wiz = wi[i, 0], wi[i, 1], wi[i, 2]
        a2, spec, diffuse, f0, p_spec, p_diffuse = kb.lobe_shape(P, end_row[i], wix, wiy, wiz)
        ox, oy, oz = shading_frame.to_world(wix, wiy, wiz, ns[i, 0], ns[i, 1], ns[i, 2])
        lobe = (ox, oy, oz, abs(wiz), a2, spec, diffuse, f0, p_spec, p_diffuse)
        if not (math.isfinite(a2) and math.isfinite(spec) and math.isfinite(diffuse) and math.isfinite(p_spec)
                and math.isfinite(p_diffuse) and math.isfinite(ox + oy + oz)):
            continue  # (a NaN eye or BSDF: the flat guess)
        for f in range(LOBE_FIELDS):
            out[i, f] = lobe[f]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lobe_guess(d0, d1, d2_, cos_x, pl, lobes, i):
    """The roulette's guess (float32 > 0) of how much a glossy row's BSDF passes of the light
    from direction d (unnormalized, toward the VPL; ``cos_x`` its cosine to the row's normal on
    the eye's side; ``pl`` the MIS light pdf, 0: no MIS) — f · (MIS weight) by
    common.kernels.bsdf.lobe_shape, relative to the row's other pairs only, so no constant
    factor matters. 1 (flat) where the row has no lobe (``lobes[i]``'s α² = 0) or the guess is
    not finite; never below 1e-30. Unbiased whatever it returns: a pair's 1/p undoes it."""
    one = np.float32(1.0)
    a2 = lobes[i, 4]
    if not a2 > 0.0:
        return one
    _dd, inv_d = _length(d0, d1, d2_)
    e = (d0 * lobes[i, 0] + d1 * lobes[i, 1] + d2_ * lobes[i, 2]) * inv_d  # cos of eye to light
    h2 = max(one + e, np.float32(1e-7))  # |wo + ω|² / 2
    ch = lobes[i, 3] + cos_x  # (wo + ω)·n
    c2 = min(ch * ch / (np.float32(2.0) * h2), one)  # cos² θ_h
    den = c2 * (a2 - one) + one
    dn = a2 * a2 / (den * den)  # GGX's D(h) / D(n)
    u = one - min(np.float32(math.sqrt(np.float32(0.5) * h2)), one)  # 1 - cos θ_d
    u2 = u * u
    fr = lobes[i, 7] + (one - lobes[i, 7]) * (u2 * u2 * u)
    f = lobes[i, 5] * fr * dn + lobes[i, 6] * cos_x
    pb = lobes[i, 8] * dn + lobes[i, 9] * cos_x
    pl2 = pl * pl
    m = pl2 / (pl2 + pb * pb) if pl > 0.0 else one
    g = f * m
    if not g < np.float32(np.inf):
        return one
    return max(g, np.float32(1e-30))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _guessed(w, g):
    """A glossy pair's weight ``w`` times its guess ``g`` (:func:`_lobe_guess`) as the roulette
    weighs it, and the guess that gives (1 where the product would not be finite)."""
    wg = w * g
    if not wg < np.float32(np.inf):
        return w, np.float32(1.0)
    return wg, g


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _roulette_pair(w, lj, key, ck, t):
    """A weighed pair's weight after :func:`roulette_row`'s draw (row key ``key``, column key
    ``ck``, threshold ``t``, the column's float32 luminance ``lj``): kept as it is, dropped
    (_NO_RAY) or counted at the threshold (c / p)."""
    c = w * lj
    u = pair_draw(key, ck)
    small = (w >= 0.0) & (c < t)  # (a dead pair, w < 0, stays as it is)
    kept = _NO_RAY if u * t >= c else t / lj
    return kept if small else w


# Rows staged per block: their pairs are weighed row by row, then emitted. The gather's rays
# go to Embree column by column within a block (one VPL from 256 neighbouring end points: more
# coherent packets, 12% less time than row by row on cornell-box-sphere).
BLOCK = 256
_NO_RAY = np.float32(-1.0)  # a staged pair that traces no ray (dead, or dropped by the roulette)
# Depths (light-path segments) past this compare as this in the int32 depth test (_columns_soa,
# _stage): real ones are far below it.
_DEPTH_CAP = 1 << 30


# No reference counting (_nrt=False, as pair_factors): what it inlines takes the columns'
# arrays per pair, and counting their references would cost more than the pairs' geometry.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _stage(b0, nb, x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi,
           vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis, light_pdf,
           area, direct_count, lum, fraction, seed, base, lobes, boost, totals, planes, col_out, sw, spl, so, sin, vx,
           vy, vz, wx, wy, wz, vd, col_keys, block) -> None:
    """Weigh the pairs of rows [b0, b0 + nb) (the arguments as :func:`pair_weights` takes
    them): sw[a, b] the weight of row b0 + b with column col_lo + a (_NO_RAY: no pair), spl the
    MIS light pdf of glossy-row pairs, so the row's offset shadow-ray origin, sin whether it
    lies on the inner side of the supporting ``planes`` (:func:`interior_origin`). Every row then
    goes through :func:`roulette_row` (``fraction`` > 0; ``col_keys``: the columns'
    :func:`column_key`), a glossy row's pairs weighed there by its ``lobes`` (:func:`lobe_rows`,
    :func:`_lobe_guess`; no rows: a flat guess), its threshold raised by ``boost[i]`` (no rows:
    1). ``fraction`` < 0: the pairs weighed as for a roulette (glossy rows by their lobes), none
    drawn; ``totals`` (rows: n) gets each row's unshadowed Σ weight · lum of those weights.
    vx … wz, vd: the columns' positions and normals per coordinate and their depths as int32
    (:func:`_columns_soa`; empty: every row weighed pair by pair), for the Lambertian rows'
    branch-free loops; ``block``: :func:`_staging`'s scratch.

    Where every row of the block takes the same columns (the gather's rows do), its Lambertian
    rows are weighed and thinned column by column, each column over the block's rows in SIMD
    lanes (:func:`_lambert_columns`); the other rows (and every row of a block whose rows take
    different columns) one by one, their row in ``block``'s row buffers, then copied in."""
    f1e30 = np.float32(1e-30)
    zero = np.float32(0.0)
    inf32 = np.float32(np.inf)
    dcount = np.float32(direct_count)
    vector = vx.shape[0] > 0  # (the columns' SoA coordinates given: no spot column)
    uniform = vector and _same_columns(b0, nb, col_lo, col_hi)
    if uniform:
        _lambert_columns(b0, nb, x, ns, side, row, vmax, tables, row_tab, inv_tavg, max(col_lo[b0], 0),
                         col_hi[b0], directional, min_d2, cos_factor, vside, mis, light_pdf, area, dcount, lum,
                         fraction, seed, base, lobes, boost, totals, sw, spl, vx, vy, vz, wx, wy, wz, vd, col_keys,
                         block)
    rb, rpl = block[13], block[14]  # (1, width): one row's weights and light pdfs
    sg = block[18]  # the glossy pairs' roulette guesses (as sw)
    guess = fraction != 0.0 and lobes.shape[0] > 0
    boosted = boost.shape[0] > 0
    record = totals.shape[0] > 0
    for b in range(nb):
        i = b0 + b
        r = row[i]
        lo = max(col_lo[i], 0)  # (>= 0 known to the compiler: no negative-index wraparound per access)
        width = col_hi[i] - lo
        if r == ROW_NONE:
            for a in range(width):
                sw[a, b] = _NO_RAY
            sin[b] = False
            continue
        xi0, xi1, xi2 = x[i, 0], x[i, 1], x[i, 2]
        n0, n1, n2 = ns[i, 0], ns[i, 1], ns[i, 2]
        s = side[i]
        lim = vmax[i]
        so[b, 0] = xi0 + ng[i, 0] * off[i]
        so[b, 1] = xi1 + ng[i, 1] * off[i]
        so[b, 2] = xi2 + ng[i, 2] * off[i]
        sin[b] = interior_origin(planes, so[b, 0], so[b, 1], so[b, 2])
        if uniform:
            continue  # weighed (and thinned) by _lambert_columns
        q = 0
        total = 0.0
        # (int32 as vd: 64-bit lanes would halve the loop's SIMD width)
        lim32 = np.int32(min(max(lim, -1), _DEPTH_CAP))
        if r == ROW_LAMBERT and vector:
            # The common row, branch-free so the compiler runs it in SIMD lanes: every candidate
            # weighed in full, the dead ones marked after (the same float32 operations as below
            # for every live pair; max(a, b) written as Python's: b only where b > a).
            for a in range(width):
                j = lo + a
                dr = directional[j]
                d0 = -wx[j] if dr else vx[j] - xi0
                d1 = -wy[j] if dr else vy[j] - xi1
                d2_ = -wz[j] if dr else vz[j] - xi2
                front, _cos_x, em, _pl, v = _lambert_terms(d0, d1, d2_, n0, n1, n2, s, wx[j], wy[j], wz[j], min_d2[j],
                                                           cos_factor[j], vside[j], light_pdf[j], area[j], mis[j],
                                                           dcount)
                live = (vd[j] <= lim32) & (front > zero) & (em > zero) & (v > zero) & (v < inf32)
                rb[0, a] = v if live else _NO_RAY
            for a in range(width):
                w = rb[0, a]
                if w >= 0.0:
                    total += np.float64(w) * lum[lo + a]
                    q += 1
        for a in range(width if not (r == ROW_LAMBERT and vector) else 0):
            j = lo + a
            w = _NO_RAY
            if vdepth[j] <= lim:
                d0, d1, d2_ = _to_vpl(xi0, xi1, xi2, vpos, vnormal, directional, j)
                dot_x = d0 * n0 + d1 * n1 + d2_ * n2
                if dot_x * s > 0.0:  # (not behind the receiver: cos_x > 0, and not NaN)
                    dd, inv_d = _length(d0, d1, d2_)
                    cos_x = dot_x * inv_d * s
                    cos_y = -(d0 * vnormal[j, 0] + d1 * vnormal[j, 1] + d2_ * vnormal[j, 2]) * inv_d
                    em = np.float32(1.0) / max(dd, min_d2[j])
                    if cos_factor[j]:
                        em *= max(cos_y * vside[j], np.float32(0.0))
                    if spot_cutoff[j] >= 0.0:
                        em *= np.float32(spot_falloff(cos_y, spot_cutoff[j], spot_beam[j]))
                    if em > 0.0:
                        pl = np.float32(0.0)
                        if mis[j]:
                            pl = light_pdf[j]
                            if area[j]:
                                pl = pl * dd / max(cos_y, np.float32(1e-7))
                            pl = pl * np.float32(direct_count)
                        v = np.float32(0.0)
                        if r == ROW_LAMBERT or r == ROW_LAYER:
                            recv = max(cos_x, np.float32(0.0)) * np.float32(INV_PI)  # also the cosine pdf
                            v = em * recv
                            if mis[j]:
                                v *= pl * pl / max(pl * pl + recv * recv, f1e30)
                            if r == ROW_LAYER:
                                v = _coat_weight(v, cos_x, tables, row_tab[i], inv_tavg[i])
                        elif cos_x > 0.0:  # every glossy kind reflects only: below the horizon f = 0
                            v = em
                            rpl[0, a] = pl
                            if guess:  # the roulette weighs the pair by its lobe; undone below
                                v, sg[a, b] = _guessed(v, _lobe_guess(d0, d1, d2_, cos_x, pl, lobes, i))
                        if v > 0.0 and math.isfinite(v):
                            w = v
                            total += np.float64(v) * lum[j]
                            q += 1
            rb[0, a] = w
        if record:
            totals[i] = total
        if q > 0 and fraction > 0.0:
            roulette_row(rb, 0, width, lo, q, total, lum, fraction, seed, base + i, col_keys,
                         boost[i] if boosted else 1.0)
        unguess = guess and r == ROW_GLOSSY
        for a in range(width):
            w = rb[0, a]
            sw[a, b] = w / sg[a, b] if unguess and w >= 0.0 else w
            spl[a, b] = rpl[0, a]


# (a call of its own: numba inlines no call of more than 30 arguments; no reference counting, as _stage)
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _lambert_columns(b0, nb, x, ns, side, row, vmax, tables, row_tab, inv_tavg, lo, hi, directional, min_d2,
                     cos_factor, vside, mis, light_pdf, area, dcount, lum, fraction, seed, base, lobes, boost, totals,
                     sw, spl, vx, vy, vz, wx, wy, wz, vd, col_keys, block) -> None:
    """:func:`_stage`'s rows of a block whose rows all take columns [lo, hi): each column over
    the block's rows (their x, ns, side, depth limit and kind copied out per coordinate,
    ``block``), so the compiler runs the rows in SIMD lanes with no per-row remainder loop — the
    same float32 operations per pair as the row-by-row loop (a glossy pair's weight its emitter
    factor, its light pdf in ``spl``; a plastic layer's its Lambertian weight times the coat's
    :func:`_coat_weight`, applied to the column's live layer pairs after the lanes; a glossy
    pair's weight times its roulette guess, :func:`_lobe_guess`, likewise, and divided out
    after the draws), each row's total summed in column order, then :func:`roulette_row`'s
    draws column by column. A ROW_NONE row is left _NO_RAY."""
    rx0, rx1, rx2, rn0, rn1, rn2, rs, rl, rk, tot, qq, tt, rkey = block[:13]
    cx, layers = block[15], block[16]  # a column's cos θ_x per row; the block's layer rows
    glossies, sg = block[17], block[18]  # the block's glossy rows (when guessed); their guesses
    guess = fraction != 0.0 and lobes.shape[0] > 0
    zero = np.float32(0.0)
    inf32 = np.float32(np.inf)
    n_layers = 0
    n_glossy = 0
    for b in range(nb):
        i = b0 + b
        rx0[b], rx1[b], rx2[b] = x[i, 0], x[i, 1], x[i, 2]
        rn0[b], rn1[b], rn2[b] = ns[i, 0], ns[i, 1], ns[i, 2]
        rs[b] = side[i]
        rl[b] = np.int32(min(max(vmax[i], -1), _DEPTH_CAP))
        rk[b] = row[i]
        tot[b] = 0.0
        qq[b] = 0
        layers[n_layers] = b
        n_layers += row[i] == ROW_LAYER
        glossies[n_glossy] = b
        n_glossy += guess and row[i] == ROW_GLOSSY
    for a in range(hi - lo):
        j = lo + a
        dr, cx_, cy, cz, nx, ny, nz = directional[j], vx[j], vy[j], vz[j], wx[j], wy[j], wz[j]
        md2, cf, vsd, lp, ar, mi, dj, lj = min_d2[j], cos_factor[j], vside[j], light_pdf[j], area[j], mis[j], vd[j], \
            lum[j]
        for b in range(nb):
            d0 = -nx if dr else cx_ - rx0[b]
            d1 = -ny if dr else cy - rx1[b]
            d2_ = -nz if dr else cz - rx2[b]
            front, cos_x, em, pl, v = _lambert_terms(d0, d1, d2_, rn0[b], rn1[b], rn2[b], rs[b], nx, ny, nz, md2, cf,
                                                     vsd, lp, ar, mi, dcount)
            # a glossy row: the emitter factor, its BSDF (every glossy kind reflects only, so
            # cos_x > 0) and MIS weight the caller's
            glossy = rk[b] == ROW_GLOSSY
            v = em if glossy else v
            kind_live = (rk[b] == ROW_LAMBERT) | (rk[b] == ROW_LAYER) | (glossy & (cos_x > zero))
            live = kind_live & (dj <= rl[b]) & (front > zero) & (em > zero) & (v > zero) & (v < inf32)
            sw[a, b] = v if live else _NO_RAY
            spl[a, b] = pl if mi else zero
            cx[b] = cos_x
        # the layer rows' coat, out of the lanes (a table look-up in float64 per pair); a pair
        # it leaves at 0 or not finite carries nothing, as in the row-by-row loop
        for t in range(n_layers):
            b = layers[t]
            w = sw[a, b]
            if w >= 0.0:
                i = b0 + b
                v = _coat_weight(w, cx[b], tables, row_tab[i], inv_tavg[i])
                sw[a, b] = v if v > 0.0 and math.isfinite(v) else _NO_RAY
        # the glossy rows' roulette guesses, out of the lanes too (as the row-by-row loop
        # makes them: the same direction, cosine and light pdf)
        for t in range(n_glossy):
            b = glossies[t]
            w = sw[a, b]
            if w >= 0.0:
                d0 = -nx if dr else cx_ - rx0[b]
                d1 = -ny if dr else cy - rx1[b]
                d2_ = -nz if dr else cz - rx2[b]
                sw[a, b], sg[a, b] = _guessed(w, _lobe_guess(d0, d1, d2_, cx[b], spl[a, b], lobes, b0 + b))
        # the rows' sums in a loop of their own: float64 lanes here would halve the weighing's
        # SIMD width (+0.0 for a dead pair: each row sums its live pairs in column order, as
        # roulette_row's caller does)
        for b in range(nb):
            w = sw[a, b]
            tot[b] += np.float64(w) * lj if w >= 0.0 else 0.0
            qq[b] += w >= 0.0
    for b in range(nb if totals.shape[0] > 0 else 0):
        totals[b0 + b] = tot[b]
    if fraction > 0.0:  # (< 0: weighed only, nothing drawn)
        no_roulette = np.float32(-np.inf)  # (c < -inf never: the row's pairs stay as they are)
        for b in range(nb):
            tt[b] = no_roulette
            rkey[b] = np.uint32(0)
            if qq[b] > 0:
                threshold = fraction * tot[b] * (boost[b0 + b] if boost.shape[0] > 0 else 1.0) / qq[b]
                if threshold > 0.0:
                    tt[b] = np.float32(threshold)
                    rkey[b] = row_key(seed, base + b0 + b)
        for a in range(hi - lo):
            j = lo + a
            lj32 = np.float32(lum[j])
            ck = col_keys[j]
            for b in range(nb):
                sw[a, b] = _roulette_pair(sw[a, b], lj32, rkey[b], ck, tt[b])
    for t in range(n_glossy):  # the guesses out of the kept pairs' weights (none unless guessed)
        b = glossies[t]
        for a in range(hi - lo):
            w = sw[a, b]
            if w >= 0.0:
                sw[a, b] = w / sg[a, b]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _columns_soa(vpos, vnormal, spot_cutoff, vdepth):
    """The columns' positions and normals one coordinate per array and their depths as int32
    (at most _DEPTH_CAP), for :func:`_stage`'s branch-free rows; empty where a column is a spot (its
    falloff is weighed pair by pair)."""
    m = vpos.shape[0]
    for j in range(m):
        if spot_cutoff[j] >= 0.0:
            m = 0
    out = (np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m, np.float32),
           np.empty(m, np.float32), np.empty(m, np.float32))
    depth = np.empty(m, np.int32)
    for j in range(m):
        for c in range(3):
            out[c][j] = vpos[j, c]
            out[3 + c][j] = vnormal[j, c]
        depth[j] = np.int32(min(vdepth[j], _DEPTH_CAP))
    return out[0], out[1], out[2], out[3], out[4], out[5], depth


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _staging(n, col_lo, col_hi, vpos, vnormal, spot_cutoff, vdepth):
    """The staging of :func:`_stage` for blocks of up to BLOCK of the n rows: (rows a block
    holds, (weights and light pdfs (columns × rows), origins, the columns' coordinates and
    depths, their roulette keys, the rows' scratch))."""
    width = 0
    for i in range(n):
        width = max(width, col_hi[i] - col_lo[i])
    rows = max(1, min(BLOCK, n))
    return rows, staging_for(rows, width, vpos, vnormal, spot_cutoff, vdepth)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def staging_for(rows, width, vpos, vnormal, spot_cutoff, vdepth):
    """:func:`_stage`'s staging for blocks of up to ``rows`` rows of up to ``width`` columns
    (:func:`_staging`; vpl_scoring.scored_draws weighs whole runs of rows)."""
    vx, vy, vz, wx, wy, wz, vd = _columns_soa(vpos, vnormal, spot_cutoff, vdepth)
    f32 = np.float32
    block = (np.empty(rows, f32), np.empty(rows, f32), np.empty(rows, f32), np.empty(rows, f32), np.empty(rows, f32),
             np.empty(rows, f32), np.empty(rows, f32), np.empty(rows, np.int32), np.empty(rows, np.int8),
             np.empty(rows), np.empty(rows, np.int32), np.empty(rows, f32), np.empty(rows, np.uint32),
             np.empty((1, width), f32), np.zeros((1, width), f32), np.empty(rows, f32), np.empty(rows, np.int64),
             np.empty(rows, np.int64), np.empty((width, rows), f32))
    return (np.empty((width, rows), f32), np.empty((width, rows), f32), np.zeros((rows, 3), f32),
            np.empty(rows, np.bool_), vx, vy, vz, wx, wy, wz, vd, column_keys(vpos.shape[0]), block)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _weigh(b0, nb, weighed, staging) -> None:
    """:func:`_stage` of a block, its arguments as the callers hold them: (rows, columns,
    roulette) tuples and the staging (numba inlines no call of more than 30 single arguments)."""
    rows, columns, roulette, cull = weighed
    x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi = rows
    (vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis, light_pdf, area,
     direct_count) = columns
    lum, fraction, seed, base, lobes, boost, totals = roulette
    planes, col_out = cull
    sw, spl, so, sin, vx, vy, vz, wx, wy, wz, vd, col_keys, block = staging
    _stage(b0, nb, x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi, vpos, vnormal,
           directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis, light_pdf, area,
           direct_count, lum, fraction, seed, base, lobes, boost, totals, planes, col_out, sw, spl, so, sin, vx, vy,
           vz, wx, wy, wz, vd, col_keys, block)


@njit(cache=True, nogil=True, error_model="numpy")
def pair_weights(x, ns, ng, off, side, row, vmax,
                 vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam,
                 vdepth, mis, light_pdf, area, direct_count, eps2,
                 tables, row_tab, inv_tavg, col_lo, col_hi, lum, fraction, seed, base, lobes, boost, planes, col_out,
                 out_i, out_j, out_w, out_pl, out_o, out_d, out_t, out_in):
    """Fill the live pairs of rows x (n, 3) × VPL columns [col_lo[i], col_hi[i]), row by row
    (row-major); returns how many were written (the out arrays hold at least Σ (col_hi - col_lo)).

    x, ns, ng: float32 (n, 3) end points in Embree's centred frame; off: float32 (n,) offset
    length along ng, signed to the eye's side (``side``); row: ROW_* per end point; vmax: the
    deepest VPL (light-path depth) the row may take — the path-length limit, and 0 for points
    that take emitter samples only. Per column: vpos/vnormal float32 (m, 3), directional/cos_factor/mis/area bool,
    min_d2/vside/light_pdf float32, spot_cutoff/spot_beam degrees (cutoff < 0: not a spot),
    vdepth int. ROW_LAYER rows read their coat-transmittance table ``tables[row_tab[i]]`` and
    1/t_avg ``inv_tavg[i]``. out_pl: the MIS light pdf of glossy-row pairs (0 elsewhere) — their BSDF pdf
    is the caller's, so their MIS weight is applied by the caller. ``fraction`` > 0: each row's
    pairs go through :func:`roulette_row` (``lum``, ``seed``, ``base``) once the row is
    weighed (0: every live pair is kept), glossy rows' pairs weighed by their ``lobes``
    (float32 (n, LOBE_FIELDS), :func:`lobe_rows`; (0, LOBE_FIELDS): flat guesses), each row's
    threshold raised by ``boost`` (float32 (n,), worker.shading._pixel_boost; (0,): none). out_in:
    whether the pair's ray may skip the triangles of the supporting ``planes`` (its origin and
    column on their inner side: :func:`interior_origin`, :func:`interior_column`).
    """
    n = x.shape[0]
    rows_per_block, staging = _staging(n, col_lo, col_hi, vpos, vnormal, spot_cutoff, vdepth)
    sw, spl, so, sin = staging[0], staging[1], staging[2], staging[3]
    weighed = ((x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi),
               (vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis,
                light_pdf, area, direct_count), (lum, fraction, seed, base, lobes, boost, np.zeros(0)),
               (planes, col_out))
    k = 0
    for b0 in range(0, n, rows_per_block):
        nb = min(rows_per_block, n - b0)
        _weigh(b0, nb, weighed, staging)
        for b in range(nb):
            i = b0 + b
            lo = max(col_lo[i], 0)  # (as _stage: j >= 0 known, no wraparound per access)
            for a in range(col_hi[i] - lo):
                w = sw[a, b]
                if w < 0.0:
                    continue
                j = lo + a
                out_i[k] = i
                out_j[k] = j
                out_w[k] = w
                out_pl[k] = spl[a, b] if row[i] == ROW_GLOSSY else np.float32(0.0)
                out_in[k] = sin[b] and interior_column(col_out, j)
                d0, d1, d2_ = _to_vpl(so[b, 0], so[b, 1], so[b, 2], vpos, vnormal, directional, j)
                _write_ray(k, so[b, 0], so[b, 1], so[b, 2], d0, d1, d2_, directional[j], eps2, out_o, out_d,
                           out_t)
                k += 1
    return k


@njit(cache=True, nogil=True, error_model="numpy")
def row_totals(x, ns, ng, off, side, row, vmax, vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff,
               spot_beam, vdepth, mis, light_pdf, area, direct_count, tables, row_tab, inv_tavg, col_lo, col_hi, lum,
               lobes, out) -> None:
    """out[i] (float64): row i's unshadowed Σ weight · lum[column] over its live pairs, weighed
    as :func:`roulette_row` weighs them (a glossy row's pairs by its ``lobes``), the arguments as
    :func:`pair_weights` takes them; no ray made, nothing drawn (worker.shading._pixel_boost)."""
    n = x.shape[0]
    m = vpos.shape[0]
    rows_per_block, staging = _staging(n, col_lo, col_hi, vpos, vnormal, spot_cutoff, vdepth)
    weighed = ((x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi),
               (vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis,
                light_pdf, area, direct_count),
               (lum, -1.0, np.int64(0), np.int64(0), lobes, np.zeros(0, np.float32), out),
               (np.zeros((0, 4), np.float32), np.zeros(m + 1, np.int64)))
    for b0 in range(0, n, rows_per_block):
        _weigh(b0, min(rows_per_block, n - b0), weighed, staging)


@njit(cache=True, nogil=True, error_model="numpy")
def gather_packets(scene, inner, x, ns, ng, off, side, row, vmax,
                   vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam,
                   vdepth, mis, light_pdf, area, direct_count, eps2,
                   tables, row_tab, inv_tavg, col_lo, col_hi, lum, fraction, seed, base, lobes, boost, planes, col_out,
                   color, out, factors):
    """Steps 1-3 of the module in one pass: :func:`pair_weights`' pairs go LANES at a time straight
    into an Embree packet (``scene``: the shadow BVH's RTCScene handle, see
    common.kernels.ray_packets; ``inner``: the BVH without the triangles of the supporting
    ``planes``, for the pairs whose origin and column lie on their inner side), a block's column
    by column, and the unoccluded ones are summed into ``out`` (n, 3) as :func:`accumulate` sums
    them: each row's pairs in column order per BVH, the inner BVH's pairs apart and added last,
    so the same sums bit for bit, with no pair or ray arrays. Returns the number of shadow rays
    traced.

    ``factors`` None: no pair needs a BSDF factor (no ROW_GLOSSY row, no glossy column);
    else :func:`pair_factors`' arguments past ``base`` (P_end, end_row, wi, ns, albedo,
    glossy_col, P_vpl, vpl_row, vwi, vframes), applied to each block's unoccluded pairs
    before they are summed."""
    n = x.shape[0]
    rows_per_block, staging = _staging(n, col_lo, col_hi, vpos, vnormal, spot_cutoff, vdepth)
    sw, spl, so, sin = staging[0], staging[1], staging[2], staging[3]
    weighed = ((x, ns, ng, off, side, row, vmax, tables, row_tab, inv_tavg, col_lo, col_hi),
               (vpos, vnormal, directional, min_d2, cos_factor, vside, spot_cutoff, spot_beam, vdepth, mis,
                light_pdf, area, direct_count), (lum, fraction, seed, base, lobes, boost, np.zeros(0)),
               (planes, col_out))
    # one LANES-ray packet per BVH, side by side: [0] the full scene's, [1] the inner one's
    packets = _two_packets()
    ray, lane_i, lane_j, lane_w, lane_pl, _valid = packets
    handles = (scene, inner)
    fill = np.zeros(2, np.int64)  # lanes filled per packet
    # the sums per BVH: a row's pairs go to either, each BVH's in column order
    sums = (out, np.zeros((n if planes.shape[0] > 0 else 0, 3)))
    width = sw.shape[0]
    # factors: a block's traced pairs, kept until its factors are known
    cap = rows_per_block * width if factors is not None else 0
    held = (np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.float32), np.empty(cap, np.float32),
            np.empty((cap, 3), np.float32), np.empty(cap, np.bool_), np.empty((cap, 3)), np.empty(cap, np.int64))
    traced = 0
    live = np.empty(rows_per_block, np.int64)
    # a block whose rows all take the same columns: its origins per coordinate, and each
    # column's rays from all of them made at once (SIMD lanes), before the live ones are packed
    f32 = np.float32
    sox, soy, soz = np.zeros(rows_per_block, f32), np.zeros(rows_per_block, f32), np.zeros(rows_per_block, f32)
    rdx, rdy, rdz, rtf = (np.empty(rows_per_block, f32), np.empty(rows_per_block, f32),
                          np.empty(rows_per_block, f32), np.empty(rows_per_block, f32))
    for b0 in range(0, n, rows_per_block):
        nb = min(rows_per_block, n - b0)
        _weigh(b0, nb, weighed, staging)
        uniform = _same_columns(b0, nb, col_lo, col_hi)
        for b in range(nb if uniform else 0):
            sox[b], soy[b], soz[b] = so[b, 0], so[b, 1], so[b, 2]
        count = 0  # pairs held
        for a in range(width):
            # the column's live rows listed first, without a branch: most pairs are dead or
            # dropped by the roulette, in no pattern a branch predictor could follow (a row past
            # its own width reads a stale weight, never used)
            nl = 0
            for b in range(nb):
                i = b0 + b
                live[nl] = b
                nl += (a < col_hi[i] - col_lo[i]) & (not (sw[a, b] < 0.0))
            ic = False
            if uniform and nl > 0:
                j = max(col_lo[b0], 0) + a
                ic = interior_column(col_out, j)
                _column_rays(nb, sox, soy, soz, vpos, vnormal, directional, j, eps2, rdx, rdy, rdz, rtf)
            for t in range(nl):
                b = live[t]
                i = b0 + b
                j = max(col_lo[i], 0) + a  # (as _stage: j >= 0 known, no wraparound per access)
                # aimed from the offset origin: the ray ends short of the VPL, never past its surface
                if uniform:
                    s = 1 if sin[b] and ic else 0
                    ox, oy, oz = sox[b], soy[b], soz[b]
                    e0, e1, e2, tf = rdx[b], rdy[b], rdz[b], rtf[b]
                else:
                    s = 1 if sin[b] and interior_column(col_out, j) else 0
                    ox, oy, oz = so[b, 0], so[b, 1], so[b, 2]
                    d0, d1, d2_ = _to_vpl(ox, oy, oz, vpos, vnormal, directional, j)
                    e0, e1, e2, tf = _ray_end(d0, d1, d2_, directional[j], eps2)
                k = fill[s]
                ray[s, k] = ox
                ray[s, LANES + k] = oy
                ray[s, 2 * LANES + k] = oz
                ray[s, 4 * LANES + k] = e0
                ray[s, 5 * LANES + k] = e1
                ray[s, 6 * LANES + k] = e2
                ray[s, 8 * LANES + k] = tf
                lane_i[s, k] = i
                lane_j[s, k] = j
                lane_w[s, k] = sw[a, b]
                lane_pl[s, k] = spl[a, b] if row[i] == ROW_GLOSSY else np.float32(0.0)
                k += 1
                if k == LANES:
                    if factors is None:
                        _flush(handles[s], _lanes_of(packets, s), LANES, color, sums[s])
                    else:
                        count = _hold(handles[s], s, _lanes_of(packets, s), LANES, held, count)
                    traced += LANES
                    k = 0
                fill[s] = k
        if factors is not None:
            for s in range(2):
                if fill[s] > 0:  # a block's pairs are summed with the block: its last packets go now
                    count = _hold(handles[s], s, _lanes_of(packets, s), fill[s], held, count)
                    traced += fill[s]
                    fill[s] = 0
            _sum_held(count, held, row, factors, color, sums)
    for s in range(2):
        if fill[s] > 0:
            _flush(handles[s], _lanes_of(packets, s), fill[s], color, sums[s])
            traced += fill[s]
    _add_rows(sums[1], out)
    _finite_rows(n, out)
    return traced


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_rows(part, out) -> None:
    """out += part, where ``part`` has rows (the inner BVH's sums: added after the full one's)."""
    for i in range(part.shape[0]):
        for c in range(3):
            out[i, c] += part[i, c]


@njit(cache=True, nogil=True, inline="always")
def _same_columns(b0, nb, col_lo, col_hi) -> bool:
    """Whether rows [b0, b0 + nb) all take the same columns (the gather's rows do)."""
    for b in range(1, nb):
        if col_lo[b0 + b] != col_lo[b0] or col_hi[b0 + b] != col_hi[b0]:
            return False
    return nb > 0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _column_rays(nb, ox, oy, oz, vpos, vnormal, directional, j, eps2, out_x, out_y, out_z, out_t) -> None:
    """The shadow rays from origins (ox, oy, oz)[:nb] toward column j (:func:`_to_vpl`,
    :func:`_ray_end`: the same float32 operations), per coordinate, the rows in SIMD lanes."""
    dr = directional[j]
    px, py, pz = vpos[j, 0], vpos[j, 1], vpos[j, 2]
    nx, ny, nz = -vnormal[j, 0], -vnormal[j, 1], -vnormal[j, 2]
    for b in range(nb):
        d0 = nx if dr else px - ox[b]
        d1 = ny if dr else py - oy[b]
        d2_ = nz if dr else pz - oz[b]
        out_x[b], out_y[b], out_z[b], out_t[b] = _ray_end(d0, d1, d2_, dr, eps2)


@njit(cache=True, nogil=True, inline="always")
def _two_packets():
    """Two occlusion packets side by side, their fixed fields set (common.kernels.ray_packets
    .packet_lanes): (rays (2, FIELDS × LANES) float32, then per packet and lane the pair's row, column,
    weight and light pdf, and the valid masks (2, LANES)), each packet 64-byte aligned."""
    ray, _bits, valid = packet_lanes(2)
    return (ray.reshape((2, FIELDS * LANES)), np.empty((2, LANES), np.int64), np.empty((2, LANES), np.int64),
            np.empty((2, LANES), np.float32), np.empty((2, LANES), np.float32), valid.reshape((2, LANES)))


@njit(cache=True, nogil=True, inline="always")
def _lanes_of(packets, s):
    """Packet s of :func:`_two_packets`: (ray, row, column, weight, light pdf, valid mask)."""
    ray, lane_i, lane_j, lane_w, lane_pl, valid = packets
    return ray[s], lane_i[s], lane_j[s], lane_w[s], lane_pl[s], valid[s]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _hold(scene, stream, pk, count, held, at):
    """Trace the first ``count`` lanes of packet ``pk`` (:func:`_lanes_of`) and keep each pair
    (row, column, weight, light pdf, direction, blocked, the packet's ``stream``) in ``held``
    from position ``at`` on; returns the next position."""
    ray, lane_i, lane_j, lane_w, lane_pl, valid = pk
    hi, hj, hw, hpl, hd, hb, _hf, hs = held
    tfar = occlude_lanes(scene, ray, valid, count)
    for q in range(count):
        hi[at] = lane_i[q]
        hj[at] = lane_j[q]
        hw[at] = lane_w[q]
        hpl[at] = lane_pl[q]
        for c in range(3):
            hd[at, c] = ray[(4 + c) * LANES + q]
        hb[at] = tfar[q] < 0.0
        hs[at] = stream
        at += 1
    return at


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sum_held(count, held, row, factors, color, sums) -> None:
    """Add the held unoccluded pairs' weight × VPL colour × BSDF factor (:func:`pair_factors`)
    to their rows of ``sums[stream]`` (the BVH each was traced on), in the order held."""
    hi, hj, hw, hpl, hd, hb, hf, hs = held
    P_end, end_row, wi, ns, albedo, glossy_col, P_vpl, vpl_row, vwi, vframes = factors
    pair_factors(hi[:count], hj[:count], hd[:count], hpl[:count], hb[:count], row, np.int64(0), P_end, end_row, wi, ns,
                 albedo, glossy_col, P_vpl, vpl_row, vwi, vframes, hf[:count])
    for q in range(count):
        if hb[q]:
            continue
        i = hi[q]
        j = hj[q]
        wq = np.float64(hw[q])
        acc = sums[hs[q]]
        for c in range(3):
            acc[i, c] += wq * color[j, c] * hf[q, c]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _flush(scene, pk, count, color, acc) -> None:
    """Trace the first ``count`` lanes of packet ``pk`` (:func:`_lanes_of`) and add each
    unoccluded pair's weight × VPL colour to its row of ``acc``."""
    ray, lane_i, lane_j, lane_w, _pl, valid = pk
    tfar = occlude_lanes(scene, ray, valid, count)
    for k in range(count):
        if tfar[k] < 0.0:  # blocked
            continue
        i = lane_i[k]
        j = lane_j[k]
        wk = np.float64(lane_w[k])
        for c in range(3):
            acc[i, c] += wk * color[j, c]


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_GOLDEN32 = np.uint32(0x9E3779B9)


@njit(cache=True, nogil=True, inline="always")
def row_key(seed, i):
    """Row i's share of its pairs' key under ``seed`` (:func:`pair_uniform`): 32 well-mixed
    bits of the two (made once per row, so the 64-bit mix costs nothing per pair)."""
    return np.uint32(mix64(np.uint64(seed) ^ (np.uint64(i) * _GOLDEN)) >> np.uint64(32))


@njit(cache=True, nogil=True, inline="always")
def column_key(j):
    """Column j's share of its pairs' key (:func:`pair_uniform`)."""
    return np.uint32(np.uint32(j) * _GOLDEN32)


@njit(cache=True, nogil=True, inline="always")
def column_keys(m):
    """The :func:`column_key` of columns 0 … m-1 (uint32 (m,)), as roulette_row takes them."""
    out = np.empty(m, np.uint32)
    for j in range(m):
        out[j] = column_key(j)
    return out


@njit(cache=True, nogil=True, inline="always")
def pair_draw(row, column):
    """The float32 uniform in [0, 1) of the pair whose row and column keys are ``row``
    (:func:`row_key`) and ``column`` (:func:`column_key`): a 32-bit mix of the two."""
    return unit32(mix32(np.uint32(row ^ column)))


@njit(cache=True, nogil=True)
def pair_uniform(seed, i, j):
    """The :func:`pair_draw` of pair (i, j) under ``seed``: the same in every thread and
    process, no generator state."""
    return pair_draw(row_key(seed, i), column_key(j))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def roulette_row(sw, b, width, lo, q, total, lum, fraction, seed, row_id, col_keys, boost=1.0) -> None:
    """Russian roulette on the shadow rays of one row's weighed pairs, in place: sw[b, a] the
    weight of its pair with column lo + a (_NO_RAY: none), ``q`` of them live, ``total`` =
    Σ weight · lum[column].

    A pair whose unshadowed contribution c = w · lum[j] is below ``fraction`` of the row's mean
    keeps its shadow ray with probability p = c / (fraction · mean) and then counts 1/p
    (unbiased; the added variance per end point is at most fraction · boost · mean · Σc); a dropped pair
    becomes _NO_RAY. A glossy column's lum[j] is a guess (a Lambertian sender of its albedo), and
    so is a glossy row's w (its emitter factor times its lobe's :func:`_lobe_guess`, divided out
    after the draws: the receiver's BSDF is applied after the ray): their true light, applied
    later by the BSDF factors, only makes p less apt, never the estimate biased (modern-hall:
    the roulette on glossy rows 11% fewer shadow rays a frame; their lobes' shape ~30x less of
    the variance it adds than a flat guess). Pair (row, j) draws
    pair_uniform(seed, row_id, j) (``col_keys``: every column's :func:`column_key`). A row of no
    light (or of negative luminance) has no threshold: every pair is kept as it is. The draw,
    c and the threshold are float32 (c < threshold and u · threshold >= c compared there).
    ``boost`` (≥ 1) raises the threshold: a row that carries a small share of its pixel's light
    is thinned against the pixel's light, not its own (worker.shading._pixel_boost)."""
    threshold = fraction * total * boost / q
    if not threshold > 0.0:
        return
    # Branch-free and all 32-bit, so the compiler runs it in 8 SIMD lanes (half the weighing's
    # time was this loop's branches; 64-bit hashing and float64 ran it 4 wide): every pair's
    # draw made, its new weight selected after.
    t = np.float32(threshold)
    key = row_key(seed, row_id)
    for a in range(width):
        j = lo + a
        sw[b, a] = _roulette_pair(sw[b, a], np.float32(lum[j]), key, col_keys[j], t)


@njit(cache=True, nogil=True, error_model="numpy")
def accumulate(n, pi, pj, w, blocked, color, factor, inner, out):
    """out[i] += w · colour_j (· factor, when factor has rows) over the unoccluded pairs; those
    traced on the inner BVH (``inner``, when it has rows) summed apart and added last, as
    :func:`gather_packets` sums them."""
    use_factor = factor.shape[0] > 0
    apart = inner.shape[0] > 0
    part = np.zeros((n if apart else 0, 3))
    for k in range(pi.shape[0]):
        if blocked[k]:
            continue
        i = pi[k]
        j = pj[k]
        wk = np.float64(w[k])
        for c in range(3):
            v = wk * color[j, c]
            if use_factor:
                v *= factor[k, c]
            if apart and inner[k]:
                part[i, c] += v
            else:
                out[i, c] += v
    _add_rows(part, out)
    _finite_rows(n, out)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _finite_rows(n, out) -> None:
    """A non-finite sum (an Inf or NaN weight) lights nothing: 0."""
    for i in range(n):
        for c in range(3):
            if not math.isfinite(out[i, c]):
                out[i, c] = 0.0


# No reference counting (_nrt=False, as common.kernels.bsdf): the BSDF helpers it inlines take
# the 17 arrays of P, and counting their references on each of them cost ~160 ns a pair.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def pair_factors(pi, pj, d, pl, blocked, row, base, P_end, end_row, wi, ns, albedo,
                 glossy_col, P_vpl, vpl_row, vwi, vframes, out):
    """Per-pair RGB factors of the unoccluded pairs (``out`` (k, 3), 1 elsewhere): a glossy
    receiver's f_x(wi, ω)/albedo with its MIS weight against the emitter sample's light pdf
    ``pl``, times a glossy VPL's f_y(ω_in, y→x) in place of its Lambertian colour.

    Rows ``pi`` are chunk-relative: end point ``base + i`` of wi / ns / albedo, whose BSDF is
    row ``end_row[base + i]`` of P_end. VPL column j's BSDF is row ``vpl_row[j]`` of P_vpl, in
    the frame of its shading normal ``vframes[j, :3]``; its light leaves through its geometric
    normal ``vframes[j, 3:]`` (common.kernels.shading_normals.exit_ratio).
    Returns whether any
    pair needed a factor (False: the caller may drop ``out``)."""
    any_factor = False
    for k in range(pi.shape[0]):
        out[k, 0] = 1.0
        out[k, 1] = 1.0
        out[k, 2] = 1.0
        if blocked[k]:
            continue
        i = pi[k]
        j = pj[k]
        dx, dy, dz = np.float64(d[k, 0]), np.float64(d[k, 1]), np.float64(d[k, 2])
        if row[i] == ROW_GLOSSY:
            e = base + i
            lx, ly, lz = shading_frame.to_local(dx, dy, dz, ns[e, 0], ns[e, 1], ns[e, 2])
            r, g, b, pb = kb.eval_pdf(P_end, end_row[e], wi[e, 0], wi[e, 1], wi[e, 2], lx, ly, lz)
            out[k, 0] = r / max(albedo[e, 0], 1e-6)
            out[k, 1] = g / max(albedo[e, 1], 1e-6)
            out[k, 2] = b / max(albedo[e, 2], 1e-6)
            p = np.float64(pl[k])
            if p > 0.0:
                m = p * p / max(p * p + pb * pb, 1e-30)
                out[k, 0] *= m
                out[k, 1] *= m
                out[k, 2] *= m
            any_factor = True
        if glossy_col[j]:
            q = vpl_row[j]
            sx, sy, sz = vframes[j, 0], vframes[j, 1], vframes[j, 2]
            lx, ly, lz = shading_frame.to_local(-dx, -dy, -dz, sx, sy, sz)
            r, g, b, _p = kb.eval_pdf(P_vpl, q, vwi[j, 0], vwi[j, 1], vwi[j, 2], lx, ly, lz)
            a = exit_ratio(-dx, -dy, -dz, sx, sy, sz, vframes[j, 3], vframes[j, 4], vframes[j, 5])
            out[k, 0] *= r * a
            out[k, 1] *= g * a
            out[k, 2] *= b * a
            any_factor = True
    return any_factor
