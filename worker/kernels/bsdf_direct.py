"""BSDF-direct light (worker.shading.bsdf_direct), compiled: per traced continuation ray that
meets an area emitter's front or leaves the scene under a lit sky, the emission it sees,
MIS-weighted against the set's emitter samples (power heuristic), per unit of its end point's
albedo — added straight into the irradiance of its row. One pass over the rays where the numpy
form took the lit rays' rows, their hits, and a dozen passes over them per tile. Its arithmetic
is the numpy form's, in its order (tests/worker/test_bsdf_direct_kernel.py: bit for bit).
"""
from __future__ import annotations

import math

from numba import njit

from igi.common.kernels import environment_map as env_map


@njit(cache=True, nogil=True, error_model="numpy")
def add_emission(rows, base, weight, pdf_b, delta, d, valid, t, ns, emitter, radiance, area_pdf, env, sky_map, sky,
                 env_pl, direct_count, albedo, irr) -> int:
    """irr[base + rows[q]] += weight_q × L_e × w_MIS / max(albedo, 1e-6) (0 where not finite)
    for each ray q that reaches an emitter (``valid`` and ``emitter`` >= 0: L_e its row of
    ``radiance`` (emitters + 1, 3; the last row 0) on the front side, else 0; the emitter
    samples' solid-angle pdf area_pdf[emitter] · t² / max(|cos|, 1e-7)) or, with ``sky``,
    misses (L_e = ``env``, or the environment map ``sky_map``'s radiance along the ray where it
    is one — common.kernels.environment_map —, pdf ``env_pl[q]``); w_MIS = 1 for a delta sample, else
    pdf_b² / max(pdf_b² + (direct_count · pdf)², 1e-300). Returns the rays that carried light."""
    last = radiance.shape[0] - 1
    mapped = sky_map[0].shape[0] > 0
    lit = 0
    for q in range(rows.shape[0]):
        if valid[q]:
            em = emitter[q]
            if em < 0:
                continue
            cos_front = -(d[q, 0] * ns[q, 0] + d[q, 1] * ns[q, 1] + d[q, 2] * ns[q, 2])
            r = em if em < last else last
            front = cos_front > 0
            l0 = radiance[r, 0] if front else 0.0
            l1 = radiance[r, 1] if front else 0.0
            l2 = radiance[r, 2] if front else 0.0
            pl = area_pdf[em if em < area_pdf.shape[0] else area_pdf.shape[0] - 1] * (t[q] * t[q]) / max(
                abs(cos_front), 1e-7)
        elif sky:
            if mapped:
                l0, l1, l2 = env_map.radiance(sky_map, d[q, 0], d[q, 1], d[q, 2])
            else:
                l0, l1, l2 = env[0], env[1], env[2]
            pl = env_pl[q]
        else:
            continue
        pl = pl * direct_count
        p2 = pdf_b[q] * pdf_b[q]
        w = 1.0 if delta[q] else p2 / max(p2 + pl * pl, 1e-300)
        i = base + rows[q]
        for c, le in ((0, l0), (1, l1), (2, l2)):
            v = weight[q, c] * le * w / max(albedo[i, c], 1e-6)
            irr[i, c] += v if math.isfinite(v) else 0.0
        lit += 1
    return lit
