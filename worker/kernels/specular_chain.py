"""One bounce of a mirror/glass chain, fused: the delta BSDF sampled at each chain vertex, the
rays that still carry light compacted, turned to world space and offset off their surface,
ready for Embree (worker.indirect_caustics follows its chains with it: per bounce a dozen numpy
passes over a few thousand rays, whose fixed costs outweighed the work).

The math is the kernels' own (common.kernels.bsdf.sample, common.kernels.shading_frame,
common.kernels.hit_surface.offset_point), in the order the numpy form applied it, so the rays
are bit-identical to it.
"""
from __future__ import annotations

from numba import njit

from igi.common.kernels import bsdf as kb
from igi.common.kernels import shading_frame
from igi.common.kernels.hit_surface import offset_point


# No reference counting (as common.kernels.bsdf): P's 17 arrays would be counted per point.
@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def delta_bounce(P, prow, src, pos, ns, ng, d, thr, seg, u1, u2, max_depth, delta_only, center, eps, ulps,
                 out_src, out_thr, out_seg, out_d, out_o) -> int:
    """The chain vertices ``i = src[j]`` (on surfaces with parameters ``P[.][prow[i]]``, reached
    along ``d[i]`` with throughput ``thr[i]`` after ``seg[i]`` segments) each sample their BSDF
    with ``(u1[j], u2[j])``; the delta samples (any sample, ``delta_only`` False) that carry
    light (positive in some channel, finite in all) and stay within ``max_depth`` segments (< 0: no limit) are written, in order, to the
    outputs: i, throughput × weight, segments + 1, world direction, offset origin. Returns how
    many were written."""
    c = 0
    for j in range(src.shape[0]):
        i = src[j]
        nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
        wix, wiy, wiz = shading_frame.to_local(-d[i, 0], -d[i, 1], -d[i, 2], nx, ny, nz)
        ox, oy, oz, wr, wg, wb, _p, delta = kb.sample(P, prow[i], wix, wiy, wiz, u1[j], u2[j, 0], u2[j, 1], True)
        if delta_only and not delta:
            continue
        if not kb.carries(wr, wg, wb):
            continue
        s = seg[i] + 1
        if max_depth >= 0 and s > max_depth:
            continue
        dx, dy, dz = shading_frame.to_world(ox, oy, oz, nx, ny, nz)
        out_src[c] = i
        out_thr[c, 0] = thr[i, 0] * wr
        out_thr[c, 1] = thr[i, 1] * wg
        out_thr[c, 2] = thr[i, 2] * wb
        out_seg[c] = s
        out_d[c, 0] = dx
        out_d[c, 1] = dy
        out_d[c, 2] = dz
        out_o[c, 0], out_o[c, 1], out_o[c, 2] = offset_point(pos[i, 0], pos[i, 1], pos[i, 2], ng[i, 0], ng[i, 1],
                                                              ng[i, 2], dx, dy, dz, center, eps, ulps)
        c += 1
    return c
