"""Shadow-ray culling by the scene's supporting planes.

A plane with every vertex of the scene on one side of it (a face plane of the scene's convex
hull: the floor, ceiling and walls of a closed box of a room) cannot be crossed by a segment
whose two ends lie on that side. A shadow ray between two points of the scene — an offset end
point and a VPL, both on the scene's surfaces — is such a segment, so the triangles lying in
such a plane never block it: the gather traces its rays against a BVH without them (the walls
are large triangles whose boxes every ray of a room enters). A ray that may leave the region
(a directional VPL's, a point light's outside the geometry, an origin pushed out through a
wall seen from outside) keeps the full BVH. The answers are the full BVH's: only triangles
that cannot be hit are left out.
"""
from __future__ import annotations

import numpy as np

MAX_PLANES = 16  # planes tested per ray origin: the ones holding the most triangle area
_COPLANAR = 1e-9  # a triangle lies in a plane within this fraction of the scene's diagonal


def supporting_planes(vertices: np.ndarray, faces: np.ndarray, area: np.ndarray, diagonal: float,
                      max_planes: int = MAX_PLANES) -> tuple[np.ndarray, np.ndarray]:
    """``(planes, culled)``: up to ``max_planes`` face planes of the convex hull of
    ``vertices`` (float64 (K, 4): unit normal n pointing out of the hull and d, so n·x + d <= 0
    for every vertex) that hold triangles of ``faces``, the planes holding the most triangle
    ``area`` first, and (F,) bool: the triangles lying in one of them (every vertex within
    1e-9 of the ``diagonal`` of the plane). A scene with no volume (all vertices in one plane,
    or fewer than four) has no such plane: ``((0, 4), all False)``."""
    f = len(faces)
    none = (np.zeros((0, 4)), np.zeros(f, bool))
    pts = np.unique(np.asarray(vertices, np.float64), axis=0)
    if len(pts) < 4 or not np.all(np.isfinite(pts)):
        return none
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):  # flat or degenerate: no volume, nothing to cull
        return none
    eq = hull.equations
    tol = _COPLANAR * diagonal
    # qhull splits a face into triangles: one plane per face, up to rounding
    key = np.round(np.column_stack([eq[:, :3] * 1e9, eq[:, 3] / max(tol, 1e-300)])).astype(np.int64)
    _u, first = np.unique(key, axis=0, return_index=True)
    planes = eq[np.sort(first)]
    tri = np.asarray(vertices, np.float64)[faces]  # (F, 3, 3)
    culled = np.zeros(f, bool)
    weight = np.zeros(len(planes))
    members = []
    for p, (n0, n1, n2, d) in enumerate(planes):
        dist = tri[:, :, 0] * n0 + tri[:, :, 1] * n1 + tri[:, :, 2] * n2 + d
        on = np.all(np.abs(dist) <= tol, axis=1) & ~culled
        members.append(on)
        weight[p] = float(area[on].sum())
        culled |= on
    keep = [p for p in np.argsort(-weight, kind="stable")[:max_planes] if weight[p] > 0]
    culled = np.zeros(f, bool)
    for p in keep:
        culled |= members[p]
    return planes[keep].reshape(-1, 4), culled


def centred_planes(planes: np.ndarray, center: np.ndarray, slack: float) -> np.ndarray:
    """The planes in Embree's centred frame (x - center), float32 as the kernels test them,
    ``slack`` subtracted from d: a point within it outside a plane counts as inside (the
    rounding of float32 coordinates)."""
    out = np.array(planes, np.float64, copy=True).reshape(-1, 4)
    out[:, 3] += out[:, :3] @ np.asarray(center, np.float64) - slack
    return out.astype(np.float32)
