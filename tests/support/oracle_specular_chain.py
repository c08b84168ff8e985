"""The numpy form of one mirror/glass chain bounce (worker.indirect_caustics before
worker.kernels.specular_chain replaced it): the oracle of tests/worker/test_specular_chain_kernel.py."""
from __future__ import annotations

import numpy as np

from igi.common import bsdf
from igi.common.lights import to_local, to_world


def delta_bounce_numpy(materials, geom, src, pos, ns, ng, d, thr, seg, mat, uv, max_depth, rng, delta_only=True):
    n = len(src)
    sp = bsdf.gather(materials, mat[src], uv[src])
    wo, w, _p, delta = bsdf.sample(sp, to_local(-d[src], ns[src]), rng.random(n), rng.random((n, 2)),
                                   mode="radiance")
    ok = bsdf.carrying(w)
    if delta_only:
        ok &= delta
    live = np.nonzero(ok)[0]
    i = src[live]
    out_thr, out_seg = thr[i] * w[live], seg[i] + 1
    out_d = to_world(wo[live], ns[i])
    if max_depth >= 0:
        keep = np.nonzero(out_seg <= max_depth)[0]
        i, out_thr, out_seg, out_d = i[keep], out_thr[keep], out_seg[keep], out_d[keep]
    return i, out_thr, out_seg, out_d, geom.offset(pos[i], ng[i], out_d)
