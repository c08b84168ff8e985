"""Embree's ray queries in packets of the CPU's native width, called from compiled code.

embreex traces one ray per Embree call (``rtcOccluded1`` in a loop); Embree's packets
(``rtcOccluded8`` / ``rtcOccluded16``, SoA ``RTCRay8`` / ``RTCRay16``) traverse the same BVH
with SIMD over the rays. The width is the one Embree's kernels run natively on this CPU
(:func:`native_lanes`): 16 with AVX-512, 8 with AVX/AVX2, 4 below — a wider packet than the
CPU's is split inside Embree at a cost: on an AVX2 EPYC, 16-wide packets took 1.6x the time of
8-wide ones on a 640x480 frame's 3.6 M shadow rays of cornell-box-sphere, 1.2x on modern-hall's
8.7 M, with identical answers (the frames' recorded rays replayed at each width, stop
48). The kernels call Embree's C API by symbol
from the library embreex ships (numba ``ExternalFunction``: cacheable, unlike ctypes pointers;
numba keys its cache by the CPU, so a cached kernel never meets another width); :data:`AVAILABLE`
is False where that library is not found, and callers keep embreex's path.

RTCRay<LANES> layout (embree4/rtcore_ray.h): twelve LANES-wide fields, float org_x, org_y,
org_z, tnear, dir_x, dir_y, dir_z, time, tfar, then unsigned mask, id, flags; aligned to the
packet's size (64 bytes suffices for all). A blocked ray's tfar comes back -inf.
"""
from __future__ import annotations

import glob
import os

import numpy as np
from numba import njit, types

from .hit_surface import reconstruct


def embree_library() -> str | None:
    """The path of the Embree 4 library embreex links (bundled beside it), or None."""
    try:
        import embreex
    except ImportError:  # pragma: no cover - embreex is a core dependency
        return None
    here = os.path.dirname(embreex.__file__)
    for pattern in ("../embreex.libs/libembree4*.so*", "../embreex.libs/libembree4*.dylib", ".dylibs/libembree4*"):
        found = sorted(glob.glob(os.path.join(here, pattern)))
        if found:
            return found[0]
    return None


def _load() -> bool:
    path = embree_library()
    if path is None:
        return False
    try:
        import llvmlite.binding as llb

        llb.load_library_permanently(path)  # the compiled kernels resolve rtc* symbols here
    except Exception:  # noqa: BLE001 - any loader failure: embreex's own path serves
        return False
    return True


AVAILABLE = _load()


def native_lanes() -> int:
    """The packet width Embree traverses natively on this CPU: 16 (AVX-512), 8 (AVX), 4."""
    try:
        import llvmlite.binding as llb

        features = llb.get_host_cpu_features()
    except Exception:  # noqa: BLE001 - no feature list: the width every x86-64 Embree build runs
        return 4
    if features.get("avx512f", False):
        return 16
    return 8 if features.get("avx", False) else 4


LANES = native_lanes()
FIELDS = 12  # RTCRay<LANES>'s LANES-wide fields

# void rtcOccluded<LANES>(const int* valid, RTCScene scene, RTCRay<LANES>* ray, RTCOccludedArguments* args)
# (pointers passed as size_t: the same register on every 64-bit ABI Embree supports)
_rtcOccludedN = types.ExternalFunction(f"rtcOccluded{LANES}", types.void(types.uintp, types.uintp, types.uintp,
                                                                          types.uintp))
_TFAR_MAX = np.float32(3.0e38)  # longer segments are clamped (as Geometry.occluded's callers did)


@njit(cache=True, nogil=True, inline="always")
def _packet(floats: int, masks: int = 1):
    """A packet buffer of ``floats`` float32 (its uint32 view too) and ``masks`` LANES-wide
    valid masks side by side, all 64-byte aligned (what Embree's 16-wide calls require, more
    than narrower ones do)."""
    buf = np.empty(floats + LANES, np.float32)
    a = ((64 - buf.ctypes.data % 64) % 64) // 4
    ray = buf[a:a + floats]
    vbuf = np.empty((masks + 1) * LANES, np.int32)
    b = ((64 - vbuf.ctypes.data % 64) % 64) // 4
    return ray, ray.view(np.uint32), vbuf[b:b + masks * LANES]


@njit(cache=True, nogil=True, inline="always")
def _put_ray(ray, bits, k, ox, oy, oz, dx, dy, dz, tfar) -> None:
    """Lane k of an RTCRay<LANES>: origin, direction (float32), tnear 0, time 0, tfar, mask all
    ones, id and flags 0."""
    ray[k] = ox
    ray[LANES + k] = oy
    ray[2 * LANES + k] = oz
    ray[3 * LANES + k] = 0.0
    ray[4 * LANES + k] = dx
    ray[5 * LANES + k] = dy
    ray[6 * LANES + k] = dz
    ray[7 * LANES + k] = 0.0
    ray[8 * LANES + k] = tfar
    bits[9 * LANES + k] = 0xFFFFFFFF
    bits[10 * LANES + k] = 0
    bits[11 * LANES + k] = 0


@njit(cache=True, nogil=True, inline="always")
def packet_lanes(packets=1):
    """``packets`` occlusion packets side by side (rays, their uint32 view, valid masks; packet
    p's fields from p × FIELDS × LANES on, its mask from p × LANES) whose fixed fields are set — tnear and
    time 0, mask all ones, id and flags 0 — for callers that write the origins, directions and
    tfar of their lanes themselves (Embree's occlusion query changes only tfar)."""
    ray, bits, valid = _packet(packets * LANES * FIELDS, packets)
    for p in range(packets):
        at = p * LANES * FIELDS
        for k in range(LANES):
            ray[at + 3 * LANES + k] = 0.0
            ray[at + 7 * LANES + k] = 0.0
            bits[at + 9 * LANES + k] = 0xFFFFFFFF
            bits[at + 10 * LANES + k] = 0
            bits[at + 11 * LANES + k] = 0
    return ray, bits, valid


@njit(cache=True, nogil=True, inline="always")
def occlude_lanes(scene, ray, valid, count):
    """Embree's occlusion query on the packet's first ``count`` lanes (tfar clamped to 3e38, NaN
    kept); returns the lanes' tfar, negative (-inf) where something blocks the ray."""
    for k in range(LANES):
        if k < count:
            t = ray[8 * LANES + k]
            ray[8 * LANES + k] = _TFAR_MAX if t > _TFAR_MAX else t  # (NaN stays NaN)
            valid[k] = -1
        else:
            valid[k] = 0
    _rtcOccludedN(valid.ctypes.data, scene, ray.ctypes.data, 0)
    return ray[8 * LANES:9 * LANES]


@njit(cache=True, nogil=True)
def occluded(scene, o, d, tfar, out) -> None:
    """out[i] = whether something blocks ray i (origin o[i], direction d[i], 0 < t <
    min(tfar[i], 3e38), float32) in the Embree ``scene`` (an RTCScene handle), LANES rays
    per Embree call."""
    ray, bits, valid = _packet(LANES * FIELDS)  # (_put_ray writes every field of a lane)
    n = o.shape[0]
    for s in range(0, n, LANES):
        m = min(LANES, n - s)
        for k in range(m):
            i = s + k
            _put_ray(ray, bits, k, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2], tfar[i])
        tf = occlude_lanes(scene, ray, valid, m)
        for k in range(m):
            out[s + k] = tf[k] < 0.0



# void rtcIntersect<LANES>(const int* valid, RTCScene scene, RTCRayHit<LANES>* rayhit, RTCIntersectArguments* args)
_rtcIntersectN = types.ExternalFunction(f"rtcIntersect{LANES}", types.void(types.uintp, types.uintp, types.uintp,
                                                                            types.uintp))
_HIT = 12 * LANES  # RTCHit<LANES> after RTCRay<LANES>: Ng_x, Ng_y, Ng_z, u, v, primID, geomID, instID[levels]
_HIT_ROOM = 16 * LANES  # the hit's 7 fields and room for up to 9 instance levels
_INVALID = 0xFFFFFFFF  # RTC_INVALID_GEOMETRY_ID


@njit(cache=True, nogil=True)
def closest_hits(scene, origins, directions, tfar, center, out_prim, out_u, out_v, out_t) -> None:
    """Closest hit of ray i in the Embree ``scene``, LANES rays per Embree call: the float64 ray
    (origins[i] - center, directions[i]) rounded to float32 as Embree takes it, 0 < t <
    tfar[i] (float32). out_prim[i] the triangle (-1 on a miss), out_u/out_v its barycentrics,
    out_t the distance (tfar[i] on a miss), as float64."""
    ray, bits, valid = _packet(_HIT + _HIT_ROOM)
    n = origins.shape[0]
    for s in range(0, n, LANES):
        m = min(LANES, n - s)
        for k in range(LANES):
            if k < m:
                i = s + k
                _put_ray(ray, bits, k, np.float32(origins[i, 0] - center[0]), np.float32(origins[i, 1] - center[1]),
                         np.float32(origins[i, 2] - center[2]), np.float32(directions[i, 0]),
                         np.float32(directions[i, 1]), np.float32(directions[i, 2]), tfar[i])
                bits[_HIT + 5 * LANES + k] = _INVALID  # primID
                bits[_HIT + 6 * LANES + k] = _INVALID  # geomID
                bits[_HIT + 7 * LANES + k] = _INVALID  # instID[0]
                valid[k] = -1
            else:
                valid[k] = 0
        _rtcIntersectN(valid.ctypes.data, scene, ray.ctypes.data, 0)
        for k in range(m):
            i = s + k
            hit = bits[_HIT + 6 * LANES + k] != _INVALID and bits[_HIT + 5 * LANES + k] < 0x80000000
            out_prim[i] = np.int64(bits[_HIT + 5 * LANES + k]) if hit else -1
            out_u[i] = ray[_HIT + 3 * LANES + k] if hit else 0.0
            out_v[i] = ray[_HIT + 4 * LANES + k] if hit else 0.0
            out_t[i] = ray[8 * LANES + k]


_UNBOUNDED = np.float32(1e37)  # the tfar of an unbounded ray (as common.ray_packets.PacketScene.closest)


@njit(cache=True, nogil=True, inline="always")
def hit_buffers(n):
    """Room for the closest hits of up to n rays (:func:`closest_surfaces`)."""
    return (np.empty(n, np.int64), np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.bool_), np.empty((n, 3)),
            np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2)), np.empty(n), np.empty(n, np.int32),
            np.empty(n, np.int32), np.empty(n, np.int32), np.full(n, _UNBOUNDED, np.float32))


@njit(cache=True, nogil=True, inline="always")
def closest_surfaces(closest, o, d, c, hits) -> None:
    """The closest hits of rays o[:c], d[:c] (unbounded) into ``hits`` (:func:`hit_buffers`:
    prim, u, v, t, then valid, position, ng, ns, uv, t, material, emitter, mesh as
    common.geometry.Geometry.intersect reconstructs them), through ``closest``
    (Geometry.closest_terms)."""
    prim, hu, hv, ht, valid, hpos, hng, hns, huv, htt, hmat, hem, hmesh, tfar = hits
    closest_hits(closest[0], o[:c], d[:c], tfar[:c], closest[1], prim[:c], hu[:c], hv[:c], ht[:c])
    for i in range(c):
        valid[i] = prim[i] >= 0
    reconstruct(valid[:c], prim[:c], hu[:c], hv[:c], ht[:c], d[:c], closest[1], closest[2], closest[3], closest[4],
                closest[5], closest[6], closest[7], closest[8], closest[9], closest[10], closest[11], closest[12],
                closest[13], closest[14], hpos, hng, hns, huv, htt, hmat, hem, hmesh)
