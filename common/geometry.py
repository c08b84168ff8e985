"""All scene triangles in one Embree scene, queried in large numpy batches.

The triangles are stored relative to the scene's centre (computed in float64) before the
float32 conversion Embree needs: a scene translated by 1e5 then keeps the precision of one
at the origin. Ray offsets are scale-aware: a fixed fraction of the scene diagonal plus a
few float32 ulps of the (centred) coordinate.
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import numpy as np
from embreex import rtcore as rtc
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from . import hull_culling
from .bump_mapping import bump_tables
from .kernels import hit_surface, triangle_sampling
from .ray_packets import PacketScene, packet_scene
from .luminance import LUMINANCE_WEIGHTS
from .scene import Scene, SceneError

log = logging.getLogger("igi.geometry")

_OFFSET_ULPS = float(4 * np.finfo(np.float32).eps)  # (np.finfo costs µs: asked per tile and kernel call)
# A point counts as on the inner side of a supporting plane up to this fraction of the scene's
# diagonal: ~16 float32 ulps of its coordinates, so a VPL on a wall is not put outside it by
# rounding (the ray still ends ~1e-4 of its length short of the VPL, the wall behind it).
_PLANE_SLACK = 1e-6


@dataclass
class Hits:
    """Closest hits of a batch of rays; arrays are aligned with the rays, ``valid`` marks hits."""

    valid: np.ndarray  # (N,) bool
    t: np.ndarray  # (N,) float64
    prim: np.ndarray  # (N,) int64 global triangle index (-1 = miss)
    position: np.ndarray  # (N, 3) float64 world space
    ng: np.ndarray  # (N, 3) geometric normal (unit, as wound)
    ns: np.ndarray  # (N, 3) shading normal (unit, same hemisphere as ng)
    uv: np.ndarray  # (N, 2) texture coordinates (0 if the mesh has none)
    material: np.ndarray  # (N,) int32
    emitter: np.ndarray  # (N,) int32 (-1 = none)
    mesh: np.ndarray  # (N,) int32

    def rows(self, idx: np.ndarray) -> "Hits":
        """The hits of rays ``idx`` (an index array)."""
        return Hits(*(getattr(self, f).take(idx, axis=0) for f in _HIT_FIELDS))

    @staticmethod
    def concat(parts: "list[Hits]") -> "Hits":
        """The hits of ``parts`` in order."""
        return Hits(*(np.concatenate([getattr(h, f) for h in parts]) for f in _HIT_FIELDS))


_HIT_FIELDS = ("valid", "t", "prim", "position", "ng", "ns", "uv", "material", "emitter", "mesh")


def rows3(*arrays: np.ndarray) -> list[np.ndarray]:
    """The arrays as contiguous float64 (N, 3) rows, broadcast against each other (one vector
    may stand for all rows): the layout the compiled per-row kernels take."""
    out = [np.ascontiguousarray(a, dtype=np.float64).reshape(-1, 3) for a in arrays]
    if len({a.shape for a in out}) > 1:
        out = [np.ascontiguousarray(a) for a in np.broadcast_arrays(*out)]
    return out


def _repair_nonfinite(scene: Scene, m) -> tuple:
    """A mesh's (vertices, faces, normals, uvs) with NaN/Inf data repaired, never rendered.

    Triangles using a vertex with a non-finite position are dropped; non-finite positions no
    triangle uses any more are replaced by a finite vertex of the mesh, so they cannot make the
    scene bounds (centre, offsets, light sampler radius) NaN; non-finite shading normals become
    0 (the face normal is used) and non-finite uvs 0. Each repair that changes what is rendered
    is a warning naming the mesh, in ``scene.warnings`` and the log (loaders that already dropped
    such triangles leave only the silent replacement of unused vertices).
    """
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.faces, np.int64)
    vn = np.asarray(m.normals, np.float64) if m.normals is not None else None
    vt = np.asarray(m.uvs, np.float64) if m.uvs is not None else None
    if np.isfinite(v).all() and (vn is None or np.isfinite(vn).all()) and (vt is None or np.isfinite(vt).all()):
        return v, f, vn, vt
    notes = []
    bad = ~np.all(np.isfinite(v), axis=1)
    if bad.any():
        drop = bad[f].any(axis=1)
        if drop.any():
            notes.append(f"dropped {int(drop.sum())} of {len(f)} triangle(s) with non-finite (NaN/Inf) vertex positions")
            f = f[~drop]
        if len(f):
            v = v.copy()
            v[bad] = v[f[0, 0]]
    fixed = []
    for what, arr in (("shading normals", vn), ("texture coordinates", vt)):
        if arr is not None and not np.isfinite(arr).all():
            badr = ~np.all(np.isfinite(arr), axis=1)
            arr = arr.copy()
            arr[badr] = 0.0
            if len(f) and badr[f].any():
                notes.append(f"set {int(badr.sum())} non-finite {what} to 0")
        fixed.append(arr)
    vn, vt = fixed
    if notes:
        msg = f"{scene.source or 'scene'}: mesh '{m.name}': " + "; ".join(notes)
        log.warning(msg)
        scene.warnings.append(msg)
    return v, f, vn, vt


class Geometry:
    """The scene's triangles, flattened, with per-triangle attributes and an Embree BVH."""

    def __init__(self, scene: Scene):
        verts, faces, mesh_of, nrm, uvs, has_n, has_uv = [], [], [], [], [], [], []
        offset = 0
        for i, m in enumerate(scene.meshes):
            if len(m.faces) == 0:
                continue
            v, f, vn, vt = _repair_nonfinite(scene, m)
            if len(f) == 0:
                continue
            verts.append(v)
            faces.append(f + offset)
            mesh_of.append(np.full(len(f), i, np.int32))
            nrm.append(vn if vn is not None else np.zeros_like(v))
            uvs.append(vt if vt is not None else np.zeros((len(v), 2)))
            has_n.append(np.full(len(f), m.normals is not None))
            has_uv.append(np.full(len(f), m.uvs is not None))
            offset += len(v)
        if not faces:
            raise SceneError(f"{scene.source or 'scene'}: no triangles to render")
        self.vertices = np.concatenate(verts)
        self.faces = np.concatenate(faces)
        self.mesh_of = np.concatenate(mesh_of)
        self.vertex_normals = np.concatenate(nrm)
        self.vertex_uvs = np.concatenate(uvs)
        self.smooth = np.concatenate(has_n)
        self.material_of = np.array([scene.meshes[i].material for i in range(len(scene.meshes))],
                                    np.int32)[self.mesh_of]
        self.emitter_of = np.array([scene.meshes[i].emitter for i in range(len(scene.meshes))],
                                   np.int32)[self.mesh_of]

        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        self.center = 0.5 * (lo + hi)
        self.diagonal = float(np.linalg.norm(hi - lo)) or 1.0
        self.extent = float(np.abs(hi - lo).max()) or 1.0
        # Offset: 1e-5 of the diagonal (geometry precision) + float32 ulps of the local coordinate.
        self.eps = 1e-5 * self.diagonal + 8 * np.finfo(np.float32).eps * 0.5 * float(np.abs(hi - lo).max())

        tri = self.vertices[self.faces]  # (F, 3, 3)
        e1 = tri[:, 1] - tri[:, 0]
        e2 = tri[:, 2] - tri[:, 0]
        cross = np.cross(e1, e2)
        area2 = np.linalg.norm(cross, axis=1)
        self.area = 0.5 * area2
        self.face_normal = cross / np.maximum(area2, 1e-300)[:, None]
        self._tri = tri
        self._e1 = e1
        self._e2 = e2

        # Ray counters (primary = closest-hit queries, shadow = occlusion queries) and, when
        # ``record`` is set, the batches themselves so benchmarks can replay them on raw Embree.
        self.counters = {"intersect_rays": 0, "occluded_rays": 0}
        # Texture coordinates are interpolated only when some texture reads them (render plan).
        self.need_uv = bool(any(m.uvs is not None for m in scene.meshes))
        # Mitsuba's normal and bump maps: the shading normal's perturbation at each hit
        # (common.kernels.bump_mapping; empty tables without them): they read uv
        self.bumps = bump_tables(scene.materials, self.material_of, self.vertices, self.faces, self.vertex_uvs)
        self.need_uv = self.need_uv or len(self.bumps[0]) > 0
        # per material: is its shading normal perturbed (the light paths' corrections apply there)
        self.bumped_materials = self.bumps[2][:, 0] > 0 if len(self.bumps[0]) else np.zeros(len(scene.materials), bool)
        self.record: list | None = None
        # float32 per-triangle data for hit reconstruction (centred positions, normals).
        local = (tri - self.center).astype(np.float32)
        self._v0c = local[:, 0].copy()
        self._e1c = (local[:, 1] - local[:, 0]).copy()
        self._e2c = (local[:, 2] - local[:, 0]).copy()
        self._fn32 = self.face_normal.astype(np.float32)
        self._any_smooth = bool(self.smooth.any())
        self._tri_normals = self.vertex_normals[self.faces].astype(np.float32)
        self._device = rtc.EmbreeDevice()
        self._local = local
        self._shadow = None  # shadow_bvh(): made on first use (the master's picking never needs it)
        self._interior = None  # interior_bvh(): likewise
        self._build_lock = threading.Lock()
        # Closest hits: a robust BVH (no ray slips through an edge), through Embree's C API
        # where at hand (common.ray_packets: the same answers without embreex's per-call
        # copies); embreex's own robust scene is then built only if asked for (benchmark
        # replays), so the triangles are not held in two closest-hit BVHs.
        self._embree_scene = None
        # Mitsuba's masks: every BVH's filter (common.kernels.opacity_mask), None without masks
        self._masks = opacity_masks(scene.materials, self.material_of, self.faces, self.vertex_uvs, self.emitter_of)
        self._packets = packet_scene(local, robust=True, masks=self._masks)
        if self._packets is None:
            if self._masks is not None:
                log.warning("%s: no Embree C API at hand, opacity masks ignored (the surfaces are opaque)",
                            scene.source or "scene")
            self.embreex_bvh()  # Embree builds a BVH on its first query: now

    def embreex_bvh(self):
        """embreex's robust scene of the triangles, built on first use."""
        if self._embree_scene is None:
            with self._build_lock:
                if self._embree_scene is None:
                    scene = rtcs.EmbreeScene(self._device)
                    self._mesh = TriangleMesh(scene, self._local)
                    scene.run(*_ONE_RAY, output=1)
                    self._embree_scene = scene
        return self._embree_scene

    @property
    def _embree(self):
        return self.embreex_bvh()

    @_embree.setter
    def _embree(self, scene) -> None:  # (time_embree's timer, tests' spies)
        self._embree_scene = scene

    def shadow_bvh(self):
        """The BVH of the shadow rays, built on first use (Renderer builds it up front), queried
        in packets of the CPU's width where Embree's C API is at hand (common.ray_packets): the
        same triangles without Embree's robust mode — occlusion queries 20% faster
        (cornell-box-sphere; 9% grey-white-room), and a shadow ray through a shared edge
        decides differently about once in a million (3 of a frame's 3.9M, 7 of 6.6M). Where an
        eye ray slipping through would show the background, a shadow ray adds one clamped VPL."""
        if self._shadow is None:
            with self._build_lock:
                if self._shadow is None:
                    # Embree's C API in packets of the CPU's width (common.ray_packets) where at
                    # hand: the same answers ~1.6x faster than embreex's one ray per call.
                    scene = packet_scene(self._local, robust=False, masks=self._masks)
                    if scene is None:
                        scene = rtcs.EmbreeScene(self._device, robust=False)
                        self._shadow_mesh = TriangleMesh(scene, self._local)
                    scene.run(*_ONE_RAY, query="OCCLUDED", dists=np.zeros(1, np.float32))
                    self._shadow = scene
        return self._shadow

    def interior_bvh(self) -> tuple:
        """``(BVH, planes)``: the shadow BVH without the triangles that lie in a supporting
        plane of the scene (common.hull_culling: a room's walls, floor and ceiling when nothing
        lies beyond them), for shadow rays between two points on the planes' inner side, and
        those planes in the centred frame (float32 (K, 4), n·x + d > 0: outside, a few float32
        ulps of slack folded into d). With no such plane, or no packet queries: the shadow BVH
        itself and no planes."""
        if self._interior is None:
            shadow = self.shadow_bvh()
            shadow = getattr(shadow, "inner", shadow)  # (never the benchmarks' timing wrapper)
            with self._build_lock:
                if self._interior is None:
                    planes, culled = np.zeros((0, 4)), np.zeros(len(self.faces), bool)
                    if isinstance(shadow, PacketScene):
                        planes, culled = hull_culling.supporting_planes(self.vertices, self.faces, self.area,
                                                                        self.diagonal)
                    masks = None if self._masks is None else (self._masks[0][~culled], self._masks[1][~culled],
                                                              self._masks[2], self._masks[3], self._masks[4][~culled])
                    inner = packet_scene(self._local[~culled], robust=False, masks=masks) if culled.any() else None
                    if inner is None:
                        self._interior = (shadow, np.zeros((0, 4), np.float32))
                    else:
                        inner.run(*_ONE_RAY, query="OCCLUDED", dists=np.zeros(1, np.float32))
                        self._interior = (inner, hull_culling.centred_planes(planes, self.center,
                                                                             _PLANE_SLACK * self.diagonal))
        return self._interior

    def packet_handle(self) -> int | None:
        """The shadow BVH's RTCScene handle for compiled code that queries it in packets
        itself (worker.kernels.vpl_gather.gather_packets), or None where its rays must pass
        through :meth:`occluded_local`: embreex's scene, or a benchmark timing or recording them."""
        shadow = self.shadow_bvh()
        if self.record is not None or not isinstance(shadow, PacketScene):
            return None
        return shadow.handle

    def closest_terms(self) -> tuple | None:
        """What compiled callers that follow rays themselves (worker.kernels.specular_chain) take
        to find closest hits as :meth:`intersect` does — ``(RTCScene handle, centre, then
        hit_surface.reconstruct's triangle arrays)`` — or None where the rays must pass through
        :meth:`intersect`: no packet scene, or a benchmark timing or recording them."""
        if self.record is not None or not isinstance(self._packets, PacketScene):
            return None
        return (self._packets.handle, self.center, self._v0c, self._e1c, self._e2c, self._fn32, self.smooth,
                self._tri_normals, self.faces, self.vertex_uvs, bool(self.need_uv), self.material_of,
                self.emitter_of, self.mesh_of, self.bumps)

    # -- queries ---------------------------------------------------------------------------
    def intersect(self, origins: np.ndarray, directions: np.ndarray,
                  tmax: float | np.ndarray | None = None) -> Hits:
        """Closest hit for each ray (directions need not be normalized; t is in their units);
        ``tmax`` (one for all rays, or per ray): only hits with t < tmax count (Embree stops
        short rays early)."""
        n = len(origins)
        if n == 0:
            return self._empty()
        self.counters["intersect_rays"] += n
        dist = None if tmax is None else np.ascontiguousarray(
            np.minimum(np.broadcast_to(np.asarray(tmax, np.float64), (n,)), 3.0e38), dtype=np.float32)
        if self.record is not None:
            # Embree writes each hit's distance into ``dist``: keep the ray's own tmax
            self.record.append(("intersect", (origins - self.center).astype(np.float32),
                                directions.astype(np.float32), None if dist is None else dist.copy(), None))
        if self._packets is not None:
            valid, prim, u, v, t = self._packets.closest(origins, directions, dist, self.center)
            return self._surface(origins, directions, valid, prim, u, v, t)
        o = (origins - self.center).astype(np.float32)
        d = directions.astype(np.float32)
        r = self._embree.run(o, d, output=1) if dist is None else self._embree.run(o, d, dists=dist, output=1)
        prim = r["primID"].astype(np.int64)
        valid = (r["geomID"] != -1) & (prim >= 0)
        prim = np.where(valid, prim, -1)
        return self._surface(origins, directions, valid, prim, r["u"].astype(np.float64),
                             r["v"].astype(np.float64), r["tfar"].astype(np.float64))

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """True where something blocks the segment origin + t*direction, 0 < t < tmax."""
        return self.occluded_local((origins - self.center).astype(np.float32), directions.astype(np.float32),
                                   np.minimum(tmax, 3.0e38))

    def occluded_local(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
                       interior: np.ndarray | None = None) -> np.ndarray:
        """occluded() for origins already in the centred float32 frame (hot path). ``interior``
        (per ray, optional): rays that may skip the triangles of the supporting planes
        (:meth:`interior_bvh`); a benchmark recording the rays traces them all on the full BVH."""
        if len(o) == 0:
            return np.zeros(0, bool)
        self.counters["occluded_rays"] += len(o)
        shadow = self.shadow_bvh()
        o = np.ascontiguousarray(o, dtype=np.float32)
        d = np.ascontiguousarray(d, dtype=np.float32)
        if self.record is None and hasattr(shadow, "occluded"):
            inner, planes = self.interior_bvh()
            if interior is not None and len(planes) and interior.any():
                out = np.empty(len(o), bool)
                sub = (o[interior], d[interior], tmax[interior])
                timed = isinstance(shadow, _TimedEmbree)  # (a benchmark timing Embree: the inner BVH too)
                out[interior] = (shadow._timed("occluded_seconds", inner.occluded, *sub) if timed
                                 else inner.occluded(*sub))
                rest = ~interior
                out[rest] = shadow.occluded(o[rest], d[rest], tmax[rest])
                return out
            return shadow.occluded(o, d, tmax)  # packets: the kernel clamps tmax, answers in bools
        dist = np.ascontiguousarray(np.minimum(tmax, np.float32(3.0e38)), dtype=np.float32)
        if self.record is not None:
            self.record.append(("occluded", o, d, dist, None if interior is None else interior.copy()))
        return shadow.run(o, d, query="OCCLUDED", dists=dist) != -1

    def visible(self, x: np.ndarray, nx: np.ndarray, y: np.ndarray, ny: np.ndarray | None) -> np.ndarray:
        """Mutual visibility of surface points x and y (normals give the offset side)."""
        d = y - x
        ox = self.offset(x, nx, d)
        if ny is not None:
            oy = self.offset(y, ny, -d)
        else:
            oy = y
        seg = oy - ox
        dist = np.linalg.norm(seg, axis=1)
        dirs = seg / np.maximum(dist, 1e-300)[:, None]
        tmax = dist * (1 - 1e-5) - self.eps
        return ~self.occluded(ox, dirs, np.maximum(tmax, 0.0))

    def offset_terms(self) -> tuple[np.ndarray, float, float]:
        """``(center, eps, ulps)`` of :meth:`offset` for compiled callers (hit_surface.offset_point)."""
        return self.center, float(self.eps), _OFFSET_ULPS

    def offset(self, p: np.ndarray, ng: np.ndarray, towards: np.ndarray,
               scale: np.ndarray | None = None) -> np.ndarray:
        """Move p off its surface, along ng, to the side ``towards`` points to."""
        if scale is None:
            p, ng, towards = rows3(p, ng, towards)
            out = np.empty(p.shape)
            hit_surface.offset_points(p, ng, towards, *self.offset_terms(), out)
            return out
        side = np.sign(np.einsum("ij,ij->i", ng, towards))
        side[side == 0] = 1.0
        return p + ng * (side * scale)[:, None]

    def replay(self, batches: list, own: bool = False) -> float:
        """Trace recorded batches on raw Embree (each kind on its own BVH: the full scene's, or
        with ``own`` the shadow rays the gather may send there on :meth:`interior_bvh`'s);
        returns the seconds it took."""
        import time

        embree = getattr(self._embree, "inner", self._embree)  # never the timing wrapper
        shadow = self.shadow_bvh()
        shadow = getattr(shadow, "inner", shadow)
        inner = self.interior_bvh()[0]
        calls = []  # (BVH, query, o, d, dist): split before the clock starts
        for kind, o, d, dist, interior in batches:
            # (copies of tfar: Embree writes each hit's distance over it)
            if kind == "intersect":
                calls.append((embree, None, o, d, None if dist is None else dist.copy()))
            elif own and interior is not None:
                calls.append((inner, "OCCLUDED", o[interior], d[interior], dist[interior]))
                calls.append((shadow, "OCCLUDED", o[~interior], d[~interior], dist[~interior]))
            else:
                calls.append((shadow, "OCCLUDED", o, d, dist.copy()))
        t0 = time.perf_counter()
        for bvh, query, o, d, dist in calls:
            if query is None:
                bvh.run(o, d, output=1) if dist is None else bvh.run(o, d, dists=dist, output=1)
            else:
                bvh.run(o, d, query=query, dists=dist)
        return time.perf_counter() - t0

    def time_embree(self, on: bool = True) -> None:
        """Benchmarks: accumulate the seconds spent inside Embree in ``counters`` (keys
        ``intersect_seconds``, ``occluded_seconds``). Off by default, and then nothing is
        measured: the queries call Embree directly."""
        inner = getattr(self._embree, "inner", self._embree)
        shadow = self.shadow_bvh()
        shadow = getattr(shadow, "inner", shadow)
        if self._packets is not None:
            packets = getattr(self._packets, "inner", self._packets)
            self._packets = _TimedEmbree(packets, self.counters) if on else packets
        self._embree = _TimedEmbree(inner, self.counters) if on else inner
        self._shadow = _TimedEmbree(shadow, self.counters) if on else shadow

    # -- surface interaction -----------------------------------------------------------------
    def _empty(self) -> Hits:
        z3 = np.zeros((0, 3))
        zi = np.zeros(0, np.int32)
        return Hits(np.zeros(0, bool), np.zeros(0), np.zeros(0, np.int64), z3, z3, z3,
                    np.zeros((0, 2)), zi, zi, zi)

    def _surface(self, origins, directions, valid, prim, u, v, t) -> Hits:
        n = len(origins)
        pos, ng, ns = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        uv, tt = np.empty((n, 2)), np.empty(n)
        mat, em, mesh = (np.empty(n, np.int32) for _ in range(3))
        d = np.ascontiguousarray(directions, np.float64).reshape(n, 3)  # (one compiled signature)
        hit_surface.reconstruct(valid, prim, u, v, t, d, self.center, self._v0c, self._e1c, self._e2c,
                                self._fn32, self.smooth, self._tri_normals, self.faces, self.vertex_uvs,
                                bool(self.need_uv), self.material_of, self.emitter_of, self.mesh_of,
                                self.bumps, pos, ng, ns, uv, tt, mat, em, mesh)
        return Hits(valid, tt, prim, pos, ng, ns, uv, mat, em, mesh)

    def bumped(self, material: np.ndarray) -> np.ndarray:
        """Per hit of ``material`` (-1 or past the materials: none): does a normal or bump map
        perturb its shading normal?"""
        m = np.asarray(material, np.int64)
        ok = (m >= 0) & (m < len(self.bumped_materials))
        out = np.zeros(m.shape, bool)
        out[ok] = self.bumped_materials[m[ok]]
        return out

    def sample_triangles(self, tri_idx: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Uniform points on the given triangles from (N, 2) uniforms: (position, ng, uv).
        Emission follows the shading normal, as in Mitsuba (a mirroring to_world flips the
        winding but not the vertex normals). Compiled: common.kernels.triangle_sampling."""
        u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1, 2)
        n = len(u)
        idx = np.ascontiguousarray(np.broadcast_to(np.asarray(tri_idx, np.int64), (n,)))
        pos, nrm, uv = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2))
        triangle_sampling.sample(self._tri, self.faces, self.vertex_uvs, self.face_normal, self.smooth,
                                 self.vertex_normals, idx, u, pos, nrm, uv)
        return pos, nrm, uv


_ONE_RAY = (np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # a query that builds a BVH


def opacity_masks(materials: list, material_of: np.ndarray, faces: np.ndarray, vertex_uvs: np.ndarray,
                  emitter_of: np.ndarray | None = None) -> tuple | None:
    """The opacity masks of the triangles, as common.kernels.opacity_mask.user_data takes them —
    ``(mask row per triangle (-1: opaque), its vertices' uv (F, 6), masks (M, 9), bitmap atlas,
    triangle index)`` — or None where no material has a mask below full opacity. A constant mask is its
    luminance, clamped to [0, 1]; a bitmap is looked up as the materials' textures are. Emitting
    triangles (``emitter_of`` >= 0) stay opaque: the lights are sampled over their whole shape."""
    rows = np.full(len(materials), -1, np.int32)
    masks, parts, base = [], [], 0
    for i, mat in enumerate(materials):
        t = mat.opacity
        if t is None:
            continue
        if t.is_constant:
            a = float(np.clip(np.dot(LUMINANCE_WEIGHTS, t.rgb), 0.0, 1.0))
            if a >= 1.0:
                continue
            masks.append((a, 0, 0, 0, 0, 0, 0, 0, 0))
        else:
            img = np.ascontiguousarray(t.image, np.float32)
            masks.append((-1.0, base, img.shape[0], img.shape[1], *t.uv_scale, *t.uv_offset, t.filter == "nearest"))
            parts.append(img.reshape(-1))
            base += img.size
        rows[i] = len(masks) - 1
    tri_mask = rows[material_of] if masks else rows[:0]
    if masks and emitter_of is not None:
        tri_mask = np.where(emitter_of >= 0, -1, tri_mask).astype(np.int32)
    if not (tri_mask >= 0).any():
        return None
    tri_uv = np.where((tri_mask >= 0)[:, None], vertex_uvs[faces].reshape(-1, 6), 0.0)
    pixels = np.concatenate(parts) if parts else np.zeros(0, np.float32)
    return tri_mask, tri_uv, np.array(masks, np.float64), pixels, np.arange(len(tri_mask), dtype=np.int32)


class _TimedEmbree:
    """Embree scene wrapper that adds each query's wall time to ``counters`` (time_embree)."""

    def __init__(self, inner, counters: dict):
        self.inner = inner
        self.counters = counters

    def run(self, *args, **kwargs):
        key = "occluded_seconds" if kwargs.get("query") == "OCCLUDED" else "intersect_seconds"
        return self._timed(key, self.inner.run, *args, **kwargs)

    def closest(self, *args):
        return self._timed("intersect_seconds", self.inner.closest, *args)

    def __getattr__(self, name: str):
        # ``occluded`` exactly where the wrapped scene has it (Geometry.occluded_local asks)
        if name == "occluded" and hasattr(self.inner, "occluded"):
            return lambda *args: self._timed("occluded_seconds", self.inner.occluded, *args)
        raise AttributeError(name)

    def _timed(self, key: str, fn, *args, **kwargs):
        import time

        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            self.counters[key] = self.counters.get(key, 0.0) + time.perf_counter() - t0
