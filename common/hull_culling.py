"""Shadow-ray culling by the scene's supporting planes.

A plane with every vertex of the scene on one side of it (a face plane of the scene's convex
hull: the floor, ceiling and walls of a closed box of a room) cannot be crossed by a segment
whose two ends lie on that side. A shadow ray between two points of the scene — an offset end
point and a VPL, both on the scene's surfaces — is such a segment, so the triangles lying in
such a plane never block it: the gather traces its rays against a BVH without them (the walls
are large triangles whose boxes every ray of a room enters). A ray that may leave the region
(a directional VPL's, a point light's outside the geometry, an origin pushed out through a
wall seen from outside) keeps the full BVH. The answers are the full BVH's but where a ray
ends or starts within a few float32 ulps of a wall (the slack of the inner-side test, ~1e-6
of the scene's diagonal): a self-intersection the full BVH reports and the inner one does not.
"""
from __future__ import annotations

import numpy as np

MAX_PLANES = 16  # planes tested per ray origin: of those with the largest hull faces
# Below this share of the scene's triangle area in the planes, a second BVH is not worth its
# memory (a room whose walls have geometry behind them: modern-hall 6%, grey-white-room 3%).
MIN_AREA_SHARE = 0.1
_COPLANAR = 1e-9  # a triangle lies in a plane within this fraction of the scene's diagonal


def supporting_planes(vertices: np.ndarray, faces: np.ndarray, area: np.ndarray, diagonal: float,
                      max_planes: int = MAX_PLANES, min_share: float = MIN_AREA_SHARE
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``(planes, culled)``: face planes of the convex hull of ``vertices`` (float64 (K, 4):
    unit normal n pointing out of the hull and d, so n·x + d <= 0 for every vertex) that hold
    triangles of ``faces`` — of the ``max_planes`` planes with the largest hull faces, those
    holding the most triangle ``area`` first — and (F,) bool: the triangles lying in one of them
    (every vertex within 1e-9 of the ``diagonal`` of the plane). A scene with no volume (all
    vertices in one plane, or fewer than four), or whose planes hold less than ``min_share`` of
    its triangle area, has none: ``((0, 4), all False)``."""
    f = len(faces)
    none = (np.zeros((0, 4)), np.zeros(f, bool))
    v = np.asarray(vertices, np.float64)
    if len(v) < 4 or f == 0 or not np.all(np.isfinite(v)):
        return none
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(v)
    except (QhullError, ValueError):  # flat or degenerate: no volume, nothing to cull
        return none
    eq = hull.equations
    tol = _COPLANAR * diagonal
    total = float(np.sum(area))
    # qhull splits a face into triangles: one plane per face, up to rounding. The faces' own
    # areas rank the planes (a bound of what a plane's triangles can cover), so the triangles
    # are matched against max_planes planes only: a finely tessellated convex shape has
    # thousands of hull faces
    key = np.round(np.column_stack([eq[:, :3] * 1e9, eq[:, 3] / max(tol, 1e-300)])).astype(np.int64)
    _u, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    s = v[hull.simplices]
    facet = 0.5 * np.linalg.norm(np.cross(s[:, 1] - s[:, 0], s[:, 2] - s[:, 0]), axis=1)
    top = np.argsort(-np.bincount(inv.ravel(), weights=facet, minlength=len(first)), kind="stable")[:max_planes]
    planes = eq[first[top]]
    plane_of = _plane_of(v[faces], planes, tol)
    weight = np.bincount(plane_of[plane_of >= 0], weights=np.asarray(area)[plane_of >= 0], minlength=len(planes))
    keep = [p for p in np.argsort(-weight, kind="stable") if weight[p] > 0]
    culled = np.isin(plane_of, keep) & (plane_of >= 0)
    if not float(np.sum(np.asarray(area)[culled])) >= min_share * total:
        return none
    return planes[keep].reshape(-1, 4), culled


def _plane_of(tri: np.ndarray, planes: np.ndarray, tol: float, chunk: int = 8192) -> np.ndarray:
    """(F,) the first of ``planes`` each triangle (F, 3, 3) lies in (every vertex within
    ``tol``), -1 for none: candidates by the triangle's own normal (parallel to the plane's
    within ~1e-3 rad), then its vertices' distances; chunks of triangles bound the (chunk ×
    planes) cosines."""
    out = np.full(len(tri), -1, np.int64)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(length > 0, length, 1.0)[:, None]
    for s in range(0, len(tri), chunk):
        cos = np.abs(normal[s:s + chunk] @ planes[:, :3].T)
        rows, cols = np.nonzero(cos > 1 - 1e-6)
        if not len(rows):
            continue
        t = tri[s + rows]  # (k, 3, 3)
        dist = np.einsum("kvc,kc->kv", t, planes[cols, :3]) + planes[cols, 3][:, None]
        on = np.all(np.abs(dist) <= tol, axis=1)
        for r, c in zip(rows[on][::-1], cols[on][::-1]):  # (reversed: the first plane wins)
            out[s + r] = c
    return out


def centred_planes(planes: np.ndarray, center: np.ndarray, slack: float) -> np.ndarray:
    """The planes in Embree's centred frame (x - center), float32 as the kernels test them,
    ``slack`` subtracted from d: a point within it outside a plane counts as inside (the
    rounding of float32 coordinates)."""
    out = np.array(planes, np.float64, copy=True).reshape(-1, 4)
    out[:, 3] += out[:, :3] @ np.asarray(center, np.float64) - slack
    return out.astype(np.float32)
