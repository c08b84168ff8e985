"""Opacity masks (Mitsuba's ``mask`` BSDF) as Embree filter functions: a hit on a masked
triangle is kept with probability its opacity at the hit's uv, or passed through.

Embree calls the filter (a numba ``cfunc``: a C function pointer) for every candidate hit on a
geometry that has one, in closest-hit and occlusion queries alike, so every ray igi traces —
eye rays, chains, light walks, photons, the gather's shadow rays — sees the same stochastic
surface with no change to the kernels that trace them. The choice is a hash of the ray (its
float32 origin and direction) and the triangle: deterministic for one ray, so Embree may call
the filter twice for one hit (it does, at some build qualities) and get one answer; independent
between rays, so a shadow ray and the eye ray that made its end point see the mask unbiasedly.

The filter's data (``geometryUserPtr``) is an int64 array of addresses and sizes,
:func:`user_data`: per triangle of the Embree scene its mask row (-1: opaque) and its three
vertices' uv; per mask its constant opacity or bitmap (an RGB atlas whose luminance is the opacity, looked up as
common.kernels.texture looks colours up).
"""
from __future__ import annotations

import numpy as np
from numba import carray, cfunc, njit, types
from numba.extending import intrinsic

from igi.common.luminance import LUMINANCE_WEIGHTS

from .splitmix import mix64, unit
from .texture import texel

# struct RTCFilterFunctionNArguments { int* valid; void* geometryUserPtr;
#   const RTCRayQueryContext* context; RTCRayN* ray; RTCHitN* hit; unsigned int N; }  (embree4/rtcore_geometry.h)
_ARGS = 6  # 8-byte slots (the last holds N in its low 32 bits)
# RTCRayN: org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar, mask, id, flags (N-wide fields);
# RTCHitN: Ng_x, Ng_y, Ng_z, u, v, primID, geomID, instID (N-wide)
_U, _V, _PRIM = 3, 4, 5
_USER = 8  # user data: addresses of tri_mask, tri_uv, masks, pixels, tri_id; then F, M, P
_MASK = 9  # a mask's row: constant opacity (-1: a bitmap), bitmap base, height, width, uv scale, offset, nearest
_WR, _WG, _WB = LUMINANCE_WEIGHTS


@intrinsic
def _ptr(typingctx, addr):
    """An integer address as a void pointer (for numba.carray)."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))
    return types.voidptr(addr), codegen


@njit(cache=True, nogil=True, inline="always")
def opacity(masks, pixels, row, u, v) -> float:
    """Mask ``row``'s opacity at uv (u, v): its constant (masks[row, 0] >= 0), or the luminance
    of its bitmap (masks[row, 1:9]: base, height, width, uv scale and offset, nearest — looked up
    as common.kernels.texture looks colours up)."""
    c = masks[row, 0]
    if c >= 0.0:
        return c
    r, g, b = texel(pixels, np.int64(masks[row, 1]), np.int64(masks[row, 2]), np.int64(masks[row, 3]), u, v,
                    masks[row, 4], masks[row, 5], masks[row, 6], masks[row, 7], masks[row, 8] != 0.0)
    return _WR * r + _WG * g + _WB * b


@njit(cache=True, nogil=True, inline="always")
def passes(ox, oy, oz, dx, dy, dz, prim, alpha) -> bool:
    """Whether the ray of float32 bits (ox … dz, as uint32) passes through triangle ``prim`` of
    opacity ``alpha``: a uniform hashed from ray and triangle, at or above alpha."""
    h = mix64(np.uint64(prim) + np.uint64(0x9E3779B97F4A7C15))
    h = mix64(h ^ ((np.uint64(ox) << np.uint64(32)) | np.uint64(oy)))
    h = mix64(h ^ ((np.uint64(oz) << np.uint64(32)) | np.uint64(dx)))
    h = mix64(h ^ ((np.uint64(dy) << np.uint64(32)) | np.uint64(dz)))
    return unit(h) >= alpha


@njit(cache=True, nogil=True, inline="always")  # (compiled into the filter function alone)
def filter_hits(valid, ray, hit, hitf, n, tri_mask, tri_uv, masks, pixels, tri_id) -> None:
    """Embree's filter on an N-wide packet: lanes whose hit is on a masked triangle and whose
    ray passes (:func:`passes`, at the opacity at the hit's interpolated uv; the triangle
    hashed by its scene-wide index ``tri_id``, so every BVH decides alike) are made invalid."""
    for k in range(n):
        if valid[k] == 0:
            continue
        prim = hit[_PRIM * n + k]
        if prim >= tri_mask.shape[0]:
            continue
        row = tri_mask[prim]
        if row < 0:
            continue
        b1 = np.float64(hitf[_U * n + k])
        b2 = np.float64(hitf[_V * n + k])
        b0 = 1.0 - b1 - b2
        u = b0 * tri_uv[prim, 0] + b1 * tri_uv[prim, 2] + b2 * tri_uv[prim, 4]
        v = b0 * tri_uv[prim, 1] + b1 * tri_uv[prim, 3] + b2 * tri_uv[prim, 5]
        alpha = opacity(masks, pixels, row, u, v)
        if passes(ray[k], ray[n + k], ray[2 * n + k], ray[4 * n + k], ray[5 * n + k], ray[6 * n + k], tri_id[prim],
                  alpha):
            valid[k] = 0


@cfunc(types.void(types.voidptr), cache=True, nogil=True)
def mask_filter(args_ptr):
    """The C filter function (RTCFilterFunctionN) Embree calls: the packet's arrays and the
    geometry's user data (:func:`user_data`) handed to :func:`filter_hits`."""
    args = carray(args_ptr, _ARGS, np.int64)
    n = args[5] & 0xFFFFFFFF
    user = carray(_ptr(args[1]), _USER, np.int64)
    filter_hits(carray(_ptr(args[0]), n, np.int32), carray(_ptr(args[3]), 12 * n, np.uint32),
                carray(_ptr(args[4]), 8 * n, np.uint32), carray(_ptr(args[4]), 8 * n, np.float32), n,
                carray(_ptr(user[0]), user[5], np.int32), carray(_ptr(user[1]), (user[5], 6), np.float64),
                carray(_ptr(user[2]), (user[6], _MASK), np.float64), carray(_ptr(user[3]), user[7], np.float32),
                carray(_ptr(user[4]), user[5], np.int32))


def user_data(tri_mask: np.ndarray, tri_uv: np.ndarray, masks: np.ndarray, pixels: np.ndarray,
              tri_id: np.ndarray) -> tuple:
    """``(user int64 array, the arrays it points to)`` for :func:`mask_filter`: hold both while
    Embree may call the filter. ``tri_mask`` int32 (F,) mask row per triangle of the Embree
    scene (-1: opaque), ``tri_uv`` (F, 6) its vertices' uv, ``masks`` (M, 9) (:func:`opacity`),
    ``pixels`` the bitmaps' RGB atlas (float32), ``tri_id`` (F,) each triangle's index in the
    whole scene (a BVH of a subset numbers its triangles anew)."""
    held = (np.ascontiguousarray(tri_mask, np.int32), np.ascontiguousarray(tri_uv, np.float64).reshape(-1, 6),
            np.ascontiguousarray(masks, np.float64).reshape(-1, _MASK),
            np.ascontiguousarray(pixels, np.float32).reshape(-1) if len(pixels) else np.zeros(1, np.float32),
            np.ascontiguousarray(tri_id, np.int32))
    user = np.array([a.ctypes.data for a in held] + [len(held[0]), len(held[2]), len(held[3])], np.int64)
    return user, held
