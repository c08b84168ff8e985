"""The numpy VPL gather that the compiled kernel replaced, kept verbatim as a test oracle.

Not part of the product: tests/test_vpl_gather_kernel.py checks worker.kernels.vpl_gather
against it on random inputs.
"""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.geometry import Geometry
from igi.common.lights import VPL_AREA, VPL_DIRECTIONAL, VPL_SPOT, VPL_SURFACE, spot_falloff, to_local, to_world
from igi.worker.vpl import VPLSet
from igi.common.scene import DIFFUSE, NULL


def gather_vpls_numpy(geom, end, vpls, clamp_d2, max_depth, force_general=False):
    e = len(end)
    albedo = bsdf.albedo(end.sp, end.wi).astype(np.float64) if e else np.zeros((0, 3))
    irr = np.zeros((e, 3))
    m = len(vpls)
    if e == 0 or m == 0:
        return albedo, irr
    cols = _VPLColumns(vpls, geom, force_general)
    chunk = max(1, (1 << 18) // m)
    for s in range(0, e, chunk):
        sl = slice(s, min(e, s + chunk))
        irr[sl] = _gather_chunk(geom, end, sl, vpls, cols, clamp_d2, max_depth, albedo[sl])
    return albedo, irr


class _VPLColumns:
    """Per-VPL constants of the gather, computed once per set and call."""

    def __init__(self, vpls: VPLSet, geom: Geometry, force_general: bool = False):
        kind = vpls.kind
        self.directional = kind == VPL_DIRECTIONAL
        self.area = kind == VPL_AREA
        self.spot = kind == VPL_SPOT
        self.surface = kind == VPL_SURFACE
        self.pos = (vpls.position - geom.center).astype(np.float32)
        self.normal = vpls.normal.astype(np.float32)
        color = vpls.power.astype(np.float64).copy()
        self.glossy = np.zeros(len(kind), bool)
        self.surf_rows = np.nonzero(self.surface)[0]
        # Surface VPLs: Lambertian ones fold rho/π into their colour and radiate on the side
        # their light arrived from; the others need their BSDF per pair.
        self.side = np.ones(len(kind), np.float32)
        self.bumped = np.zeros(len(kind), bool)
        if len(self.surf_rows):
            sp = vpls.surface
            # force_general: every surface VPL through the full BSDF (the plan-off baseline).
            lam = (sp.kind == DIFFUSE) & (not force_general)
            rows = self.surf_rows
            self.side[rows] = np.where(vpls.wi_local[rows, 2] >= 0, 1.0, -1.0)
            color[rows[lam]] *= sp.diffuse[lam] / np.pi
            bumped = geom.bumped(sp.material_rows()) if sp.material_rows() is not None else np.zeros(len(rows), bool)
            mapped = rows[lam & bumped]  # mapped: leaves through the true surface, on its side
            self.normal[mapped] = vpls.ng[mapped]
            wi = to_world(vpls.wi_local[mapped], vpls.normal[mapped])
            self.side[mapped] = np.where(np.sum(wi * vpls.ng[mapped], axis=1) >= 0, 1.0, -1.0)
            self.bumped = np.zeros(len(kind), bool)
            self.bumped[rows[bumped]] = True
            self.glossy[rows[~lam]] = True
        self.color = color
        self.spot_params = vpls.wi_local[self.spot]
        lp = vpls.light_pdf if vpls.light_pdf is not None else np.zeros(len(kind))
        self.light_pdf = lp.astype(np.float32)
        # Emitter samples with a non-delta pdf take part in MIS (area lights, environment).
        self.mis = (lp > 0) & (self.area | self.directional) & (vpls.direct_count > 0)
        # Columns whose emission has a cos θ_y factor (area emitters, Lambertian surface VPLs).
        self.cos_y_factor = self.area | (self.surface & ~self.glossy)

    def min_d2(self, clamp_d2: float) -> np.ndarray:
        """Per-column lower bound of the squared distance: the clamp for surface VPLs only
        (clamping emitter samples would bias direct light); directional columns have d² = 1."""
        return np.where(self.surface, np.float32(clamp_d2), np.float32(1e-30)).astype(np.float32)


def _gather_chunk(geom, end, sl, vpls, cols, clamp_d2, max_depth, albedo):
    f32 = np.float32
    x = (end.position[sl] - geom.center).astype(f32)
    ns = end.ns[sl].astype(f32)
    n = len(x)
    m = len(vpls)
    # Pair geometry: end point i (rows) x VPL j (columns).
    dvec = cols.pos[None, :, :] - x[:, None, :]
    if cols.directional.any():
        dvec[:, cols.directional] = -cols.normal[cols.directional][None]
    d2 = np.einsum("ijk,ijk->ij", dvec, dvec)
    inv_d = 1.0 / np.sqrt(np.maximum(d2, f32(1e-30)))
    side = np.where(end.wi[sl, 2] >= 0, f32(1), f32(-1))
    # Cosines straight from the unnormalized offsets: the unit directions are only formed
    # for the pairs that need them (shadow rays, glossy BSDFs).
    cos_x = np.einsum("ijk,ik->ij", dvec, ns) * inv_d * side[:, None]
    cos_y = -np.einsum("ijk,jk->ij", dvec, cols.normal) * inv_d
    # Emitter factor toward x (scalar per pair; the VPL colour multiplies it later), built
    # with per-column vectors so no column gather/scatter copies the (n, m) arrays.
    em = 1.0 / np.maximum(d2, cols.min_d2(clamp_d2)[None, :])
    em *= np.where(cols.cos_y_factor[None, :], np.maximum(cos_y * cols.side[None, :], f32(0)), f32(1))
    if cols.spot.any():
        sp_cols = np.nonzero(cols.spot)[0]
        for jj, j in enumerate(sp_cols):
            em[:, j] *= spot_falloff(cos_y[:, j], cols.spot_params[jj, 2], cols.spot_params[jj, 1]).astype(f32)
    if max_depth >= 0:
        seg = end.segments[sl][:, None] + 1 + vpls.depth[None, :]
        em *= seg <= max_depth
    if end.direct_only is not None:  # emitter samples only
        em *= ~(end.direct_only[sl][:, None] & (vpls.depth[None, :] > 0))
    front_ok = end.sp.twosided[sl] | (end.wi[sl, 2] > 0)
    lam = (end.sp.kind[sl] == DIFFUSE) & front_ok
    gl = (end.sp.kind[sl] != DIFFUSE) & (end.sp.kind[sl] != NULL)
    # Receiver: Lambertian rows take cos/π (per unit albedo), glossy rows their BSDF.
    recv = np.where(lam[:, None], np.maximum(cos_x, 0) * f32(1 / np.pi), f32(0))
    gi = np.nonzero(gl)[0]
    # The pairs' unit directions from the offset shadow-ray origins (the rays aim from there,
    # so they end short of the VPL; the glossy ends' BSDFs take the same directions). Live
    # pairs lie on the side of the surface the eye sees (cos_x > 0, reflective BSDFs), so one
    # offset origin per end point serves all its shadow rays.
    o_rows = x + end.ng[sl].astype(f32) * (_offset_scale(geom, end.position[sl]).astype(f32) * side)[:, None]
    ovec = cols.pos[None, :, :] - o_rows[:, None, :]
    if cols.directional.any():
        ovec[:, cols.directional] = -cols.normal[cols.directional][None]
    len_o = np.sqrt(np.maximum(np.einsum("ijk,ijk->ij", ovec, ovec), f32(1e-30)))
    inv_o = f32(1) / len_o
    udir = ovec * inv_o[:, :, None]
    if len(gi):
        wo_x = udir[gi].reshape(-1, 3).astype(np.float64)
        nx = np.repeat(end.ns[sl][gi], m, axis=0)
        rows = np.arange(sl.start, sl.stop)[gi]
        spx = end.sp.subset(np.repeat(rows, m))
        wi_x = np.repeat(end.wi[rows], m, axis=0)
        wo_l = to_local(wo_x, nx)
        fx = bsdf.eval(spx, wi_x, wo_l, mode="radiance").reshape(len(gi), m, 3)
        fx = fx / np.maximum(albedo[gi], 1e-6)[:, None, :]
        pdf_gl = bsdf.pdf(spx, wi_x, wo_l).reshape(len(gi), m)
    if cols.mis.any():
        # Multiple importance sampling of the emitter samples against the BSDF-sampled ray
        # each end point also traces (power heuristic, D emitter samples per set).
        pb = np.maximum(cos_x, 0) * f32(1 / np.pi)
        if len(gi):
            pb[gi] = pdf_gl
        mc = cols.mis
        pl = np.broadcast_to(cols.light_pdf[mc][None, :], (n, int(mc.sum()))).astype(f32)
        area_mc = cols.area[mc]
        pl = np.where(area_mc[None, :], pl * d2[:, mc] / np.maximum(cos_y[:, mc], f32(1e-7)), pl)
        pl = pl * f32(vpls.direct_count)
        em[:, mc] *= pl * pl / np.maximum(pl * pl + pb[:, mc] * pb[:, mc], f32(1e-30))
    weight = em * recv
    if len(gi):
        weight[gi] = em[gi]  # glossy rows: the scalar part only, BSDF applied below
    live = weight > 0
    if cols.glossy.any():
        live[:, cols.glossy] = em[:, cols.glossy] > 0
    live &= np.isfinite(weight)
    # Shadow rays for the live pairs only, in one Embree batch.
    ii, jj = np.nonzero(live)
    if len(ii):
        # Everything in Embree's centred float32 frame: no float64 round trip per pair.
        wij = udir[ii, jj]
        ox = o_rows[ii]
        tmax = len_o[ii, jj] * f32(1 - 1e-4) - f32(2 * geom.eps)
        tmax[cols.directional[jj]] = np.inf
        blocked = geom.occluded_local(ox, wij, np.maximum(tmax, f32(0)), _interior_pairs(geom, cols, o_rows)[ii, jj])
        live[ii[blocked], jj[blocked]] = False
    weight = np.where(live, weight, f32(0))  # not `*=`: NaN * False stays NaN
    out = weight @ cols.color.astype(f32) if not len(gi) else np.zeros((n, 3), f32)
    if len(gi):
        lrows = np.nonzero(~gl)[0]
        out[lrows] = weight[lrows] @ cols.color.astype(f32)
        # Glossy receivers: f_x(wi, w)/albedo per pair.
        out[gi] = np.einsum("ij,ijk,jk->ik", weight[gi], fx, cols.color)
    if cols.glossy.any():
        # Glossy VPLs: f_y(ω_in, y->x) per pair replaces the Lambertian colour (which was
        # left as raw flux for them).
        gj = np.nonzero(cols.glossy)[0]
        sub = vpls.surface.subset(np.searchsorted(cols.surf_rows, gj))
        wo_y = -udir[:, gj].reshape(-1, 3).astype(np.float64)
        ny = np.tile(vpls.normal[gj], (n, 1))
        spy = sub.subset(np.tile(np.arange(len(gj)), n))
        wi_y = np.tile(vpls.wi_local[gj], (n, 1))
        fy = bsdf.eval(spy, wi_y, to_local(wo_y, ny), mode="importance")
        # on a mapped surface its light leaves through the true surface: |wo·ng| / |wo·ns|
        gy = np.tile(np.where(cols.bumped[gj][:, None], vpls.ng[gj], vpls.normal[gj]), (n, 1))
        cs, cg = np.abs(np.sum(wo_y * ny, 1)), np.abs(np.sum(wo_y * gy, 1))
        ratio = np.where(cs > 1e-9, cg / np.where(cs > 1e-9, cs, 1.0), 0.0)
        fy = (fy * np.where(np.all(ny == gy, axis=1), 1.0, ratio)[:, None]).reshape(n, len(gj), 3)
        # out already holds weight * flux for these columns; swap flux for flux * f_y.
        wg = weight[:, gj]
        rec = wg[:, :, None] * cols.color[gj][None]
        if len(gi):
            # glossy rows used fx already: rec must carry fx too
            fxg = np.ones((n, len(gj), 3))
            fxg[gi] = fx[:, gj]
            rec = rec * fxg
        out = out - rec.sum(axis=1) + (rec * fy).sum(axis=1)
    return np.nan_to_num(out.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)


def lobe_guesses_numpy(x, ns, side, lobes, vpos, vnormal, directional, pi, pj, pl) -> np.ndarray:
    """The shadow roulette's guess of each listed pair's BSDF share (worker.kernels.vpl_gather
    ._lobe_guess) in numpy float32, operation by operation: 1 where its row has no lobe."""
    f32 = np.float32
    one = f32(1.0)
    lo = lobes[pi]
    d = np.where(directional[pj][:, None], -vnormal[pj], vpos[pj] - x[pi]).astype(f32)
    d0, d1, d2 = d[:, 0], d[:, 1], d[:, 2]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    inv_d = one / np.sqrt(np.maximum(dd, f32(1e-30)))
    n = ns[pi]
    cos_x = (d0 * n[:, 0] + d1 * n[:, 1] + d2 * n[:, 2]) * inv_d * side[pi]
    a2 = lo[:, 4]
    e = (d0 * lo[:, 0] + d1 * lo[:, 1] + d2 * lo[:, 2]) * inv_d
    h2 = np.maximum(one + e, f32(1e-7))
    ch = lo[:, 3] + cos_x
    c2 = np.minimum(ch * ch / (f32(2.0) * h2), one)
    den = c2 * (a2 - one) + one
    with np.errstate(all="ignore"):
        dn = a2 * a2 / (den * den)
        u = one - np.minimum(np.sqrt(f32(0.5) * h2), one)
        u2 = u * u
        fr = lo[:, 7] + (one - lo[:, 7]) * (u2 * u2 * u)
        f = lo[:, 5] * fr * dn + lo[:, 6] * cos_x
        pb = lo[:, 8] * dn + lo[:, 9] * cos_x
        pl2 = pl * pl
        m = np.where(pl > 0, pl2 / (pl2 + pb * pb), one)
        g = f * m
    g = np.where(g < np.inf, np.maximum(g, f32(1e-30)), one)
    return np.where(a2 > 0, g, one).astype(f32)


def shadow_roulette(k, pi, pj, w, pl, o, d, t, row, lum, fraction, seed, base, guess=None, boost=None) -> int:
    """The shadow rays' Russian roulette as a separate pass over the first ``k`` pairs
    (row-major), in place, in plain Python: what worker.kernels.vpl_gather.pair_weights does per
    row while it writes them. ``guess``: each pair's weight is taken times it for the draw and
    divided by it after (:func:`lobe_guesses_numpy`; None: 1); ``boost``: each row's threshold
    times it (None: 1). Returns how many pairs remain."""
    from igi.worker.kernels import vpl_gather as vg

    g = np.ones(k, np.float32) if guess is None else guess
    wg = w[:k] * g  # (float32, as the kernel weighs)
    g = np.where(wg < np.inf, g, np.float32(1.0))
    wg = np.where(wg < np.inf, wg, w[:k])
    out, s = 0, 0
    while s < k:
        e = s
        while e < k and pi[e] == pi[s]:
            e += 1
        i = int(pi[s])
        eligible = row[i] in (vg.ROW_LAMBERT, vg.ROW_LAYER, vg.ROW_GLOSSY)
        total = float(np.sum(wg[s:e].astype(np.float64) * lum[pj[s:e]]))
        threshold = fraction * total * (1.0 if boost is None else float(boost[i])) / (e - s) if eligible else 0.0
        t32 = np.float32(threshold)
        c = wg[s:e] * lum[pj[s:e]].astype(np.float32)  # float32, as the kernel compares
        for a in range(s, e):
            j = int(pj[a])
            w[a] = wg[a]
            if threshold > 0.0 and c[a - s] < t32:
                if vg.pair_uniform(seed, base + i, j) * t32 >= c[a - s]:
                    continue
                w[a] = t32 / np.float32(lum[j])
            w[a] = w[a] / g[a]
            pi[out], pj[out], w[out], pl[out], t[out] = pi[a], j, w[a], pl[a], t[a]
            o[out], d[out] = o[a], d[a]
            out += 1
        s = e
    return out


def shadow_origins_numpy(geom, end, sl):
    """worker.shading._shadow_origins as numpy computed it (before vpl_gather.shadow_origins)."""
    f32 = np.float32
    pos = end.position[sl]
    x = np.ascontiguousarray(pos - geom.center, dtype=f32)
    ns = np.ascontiguousarray(end.ns[sl], dtype=f32)
    ng = np.ascontiguousarray(end.ng[sl], dtype=f32)
    side = np.where(end.wi[sl, 2] >= 0, f32(1), f32(-1))
    off = (_offset_scale(geom, pos).astype(f32) * side).astype(f32)
    return x, ns, ng, side, off


def _interior_pairs(geom, cols, o_rows):
    """(rows, columns): the pairs whose shadow rays may skip the supporting planes' triangles
    (the BVH choice the compiled gather makes, common.hull_culling): the row's origin and the
    column (not directional) on the inner side of every plane; none without planes."""
    planes = geom.interior_bvh()[1]
    if not len(planes):
        return np.zeros((len(o_rows), len(cols.pos)), bool)
    in_col = ~cols.directional & np.all(cols.pos @ planes[:, :3].T + planes[:, 3] <= 0, axis=1)
    in_row = np.all(o_rows @ planes[:, :3].T + planes[:, 3] <= 0, axis=1)
    return in_row[:, None] & in_col[None, :]


def _offset_scale(geom, p):
    """Per-point offset length as numpy computed it (Geometry.offset_scale before
    vpl_gather.shadow_origins): the scene epsilon plus float32 ulps of the local coordinate."""
    a = np.abs(p - geom.center)
    return geom.eps + 4 * np.finfo(np.float32).eps * np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])
