"""An Embree scene built through Embree's C API (ctypes, on the library embreex ships) and
queried in packets of the CPU's width by common.kernels.ray_packets: the shadow rays' BVH, and
the closest hits' (robust) one, whose rays go to Embree from the caller's float64 arrays in one
compiled pass (no float32 copies, no per-call dictionaries of result arrays).

It answers ``run(o, d, query="OCCLUDED", dists=t)`` as embreex's scenes do (geomID per ray, -1
where nothing blocks it), so it takes their place under Geometry.shadow_bvh, the benchmark
replay and the Embree timer alike. :func:`packet_scene` returns None where the library or a
C call is missing: the caller keeps embreex's scene.
"""
from __future__ import annotations

import ctypes
import threading
import weakref

import numpy as np

from .kernels import ray_packets

_SIZE = ctypes.c_size_t  # handles and pointers
_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX, _RTC_BUFFER_TYPE_VERTEX = 0, 1
_RTC_FORMAT_UINT3, _RTC_FORMAT_FLOAT3 = 0x5003, 0x9003
_RTC_SCENE_FLAG_ROBUST = 1 << 2

_LIB: list = []  # [ctypes library or None], loaded once
_DEVICE: list = []  # [RTCDevice handle]: one per process, shared by every scene
_LOCK = threading.Lock()


def _api():
    if not _LIB:
        path = ray_packets.embree_library() if ray_packets.AVAILABLE else None
        lib = None
        if path is not None:
            try:
                lib = ctypes.CDLL(path)
                for name, res, args in (
                        ("rtcNewDevice", _SIZE, [ctypes.c_char_p]), ("rtcNewScene", _SIZE, [_SIZE]),
                        ("rtcSetSceneFlags", None, [_SIZE, ctypes.c_int]),
                        ("rtcNewGeometry", _SIZE, [_SIZE, ctypes.c_int]),
                        ("rtcSetSharedGeometryBuffer", None,
                         [_SIZE, ctypes.c_int, ctypes.c_uint, ctypes.c_int, _SIZE, _SIZE, _SIZE, _SIZE]),
                        ("rtcCommitGeometry", None, [_SIZE]), ("rtcAttachGeometry", ctypes.c_uint, [_SIZE, _SIZE]),
                        ("rtcReleaseGeometry", None, [_SIZE]), ("rtcCommitScene", None, [_SIZE]),
                        ("rtcReleaseScene", None, [_SIZE]), ("rtcGetDeviceError", ctypes.c_int, [_SIZE]),
                        ("rtcSetGeometryUserData", None, [_SIZE, _SIZE]),
                        ("rtcSetGeometryIntersectFilterFunction", None, [_SIZE, _SIZE]),
                        ("rtcSetGeometryOccludedFilterFunction", None, [_SIZE, _SIZE])):
                    fn = getattr(lib, name)
                    fn.restype, fn.argtypes = res, args
            except (OSError, AttributeError):
                lib = None
        _LIB.append(lib)
    return _LIB[0]


class PacketScene:
    """Triangles (float32 (F, 3, 3), one vertex triple each) in an Embree BVH of their own,
    queried in packets. The vertex and index buffers are shared with Embree: held here."""

    def __init__(self, lib, handle: int, buffers: tuple) -> None:
        self._handle = handle
        self._buffers = buffers
        self._finalizer = weakref.finalize(self, lib.rtcReleaseScene, handle)

    @property
    def handle(self) -> int:
        """The RTCScene, for compiled callers (common.kernels.ray_packets); valid while this lives."""
        return self._handle

    def run(self, o: np.ndarray, d: np.ndarray, query: str = "OCCLUDED", dists=None) -> np.ndarray:
        """embreex's occlusion ``run``: geomID per ray (0 blocked, -1 not); no ``dists``: rays
        of unbounded length. Closest hits: :meth:`closest`."""
        if query != "OCCLUDED":
            raise ValueError(f"PacketScene answers occlusion queries only, not {query!r}")
        n = len(o)
        tfar = np.full(n, 1e37, np.float32) if dists is None else np.ascontiguousarray(dists, np.float32).reshape(n)
        blocked = np.empty(n, bool)
        ray_packets.occluded(self._handle, np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32),
                             tfar, blocked)
        return np.where(blocked, 0, -1).astype(np.int32)


    def occluded(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray) -> np.ndarray:
        """(n,) bool: whether something blocks each float32 ray, 0 < t < min(tfar, 3e38)."""
        blocked = np.empty(len(o), bool)
        c = np.ascontiguousarray
        ray_packets.occluded(self._handle, c(o, np.float32), c(d, np.float32), c(tfar, np.float32).reshape(len(o)),
                             blocked)
        return blocked

    def closest(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray | None,
                center: np.ndarray) -> tuple[np.ndarray, ...]:
        """Closest hits of the float64 rays (origins - ``center``, directions), rounded to
        float32 as Embree takes them, up to ``tfar`` (float32 per ray; None: unbounded):
        ``(valid, prim int64 (-1 on a miss), u, v, t)`` as float64 (a miss: u = v = 0, t = tfar)."""
        n = len(origins)
        tfar = np.full(n, 1e37, np.float32) if tfar is None else np.ascontiguousarray(tfar, np.float32).reshape(n)
        prim = np.empty(n, np.int64)
        u, v, t = np.empty(n), np.empty(n), np.empty(n)
        c = np.ascontiguousarray
        ray_packets.closest_hits(self._handle, c(origins, np.float64).reshape(n, 3),
                                 c(directions, np.float64).reshape(n, 3), tfar, c(center, np.float64), prim, u, v, t)
        return prim >= 0, prim, u, v, t


def packet_scene(triangles: np.ndarray, robust: bool = False, masks: tuple | None = None) -> PacketScene | None:
    """An Embree scene of ``triangles`` (float32 (F, 3, 3)) for packet queries, or None where
    Embree's C API is not at hand (the caller keeps embreex's scene). ``masks``: the arguments of
    common.kernels.opacity_mask.user_data for these triangles (their opacity masks), or None."""
    lib = _api()
    if lib is None:
        return None
    with _LOCK:
        if not _DEVICE:
            _DEVICE.append(lib.rtcNewDevice(None))
        device = _DEVICE[0]
    if not device:
        return None
    f = len(triangles)
    vertices = np.zeros((3 * f + 1, 3), np.float32)  # Embree reads 16 bytes past the last vertex
    vertices[:-1] = np.asarray(triangles, np.float32).reshape(-1, 3)
    index = np.arange(3 * f, dtype=np.uint32).reshape(f, 3)
    scene = lib.rtcNewScene(device)
    if not scene:
        return None
    lib.rtcSetSceneFlags(scene, _RTC_SCENE_FLAG_ROBUST if robust else 0)
    geom = lib.rtcNewGeometry(device, _RTC_GEOMETRY_TYPE_TRIANGLE)
    lib.rtcSetSharedGeometryBuffer(geom, _RTC_BUFFER_TYPE_VERTEX, 0, _RTC_FORMAT_FLOAT3, vertices.ctypes.data, 0, 12,
                                   3 * f)
    lib.rtcSetSharedGeometryBuffer(geom, _RTC_BUFFER_TYPE_INDEX, 0, _RTC_FORMAT_UINT3, index.ctypes.data, 0, 12, f)
    held: tuple = ()
    if masks is not None:
        from .kernels import opacity_mask

        held = opacity_mask.user_data(*masks)
        lib.rtcSetGeometryUserData(geom, held[0].ctypes.data)
        lib.rtcSetGeometryIntersectFilterFunction(geom, opacity_mask.mask_filter.address)
        lib.rtcSetGeometryOccludedFilterFunction(geom, opacity_mask.mask_filter.address)
    lib.rtcCommitGeometry(geom)
    lib.rtcAttachGeometry(scene, geom)
    lib.rtcReleaseGeometry(geom)
    lib.rtcCommitScene(scene)
    if lib.rtcGetDeviceError(device) != 0:
        lib.rtcReleaseScene(scene)
        return None
    return PacketScene(lib, scene, (vertices, index, held))
