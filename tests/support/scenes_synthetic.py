"""Small scenes built in code, for tests that need exact analytic answers."""
from __future__ import annotations

import numpy as np

from common.camera import look_at
from common.scene import AREA, DIFFUSE, Camera, Emitter, Material, Mesh, Scene, Texture


def quad(corner, e1, e2, flip=False):
    c = np.asarray(corner, float)
    e1 = np.asarray(e1, float)
    e2 = np.asarray(e2, float)
    v = np.array([c, c + e1, c + e1 + e2, c + e2])
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    if flip:
        f = f[:, ::-1].copy()
    return v, f


def box_faces(size=2.0, inward=True):
    """Six quads of an axis-aligned cube [0, size]^3; normals point inward when ``inward``."""
    s = size
    faces = [
        quad([0, 0, 0], [s, 0, 0], [0, 0, s]),
        quad([0, s, 0], [s, 0, 0], [0, 0, s]),
        quad([0, 0, 0], [0, 0, s], [0, s, 0]),
        quad([s, 0, 0], [0, 0, s], [0, s, 0]),
        quad([0, 0, 0], [0, s, 0], [s, 0, 0]),
        quad([0, 0, s], [0, s, 0], [s, 0, 0]),
    ]
    out = []
    centre = np.full(3, s / 2)
    for v, f in faces:
        n = np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]])
        points_in = np.dot(n, centre - v[0]) > 0
        if points_in != inward:
            f = f[:, ::-1].copy()
        out.append((v, f))
    return out


def furnace_box(albedo: float, radiance: float, width=32, height=32) -> Scene:
    """A closed diffuse box whose every wall emits ``radiance`` and reflects ``albedo``.

    Every point sees L = Le · Σ_{i<D} albedo^i with D the maximum path length (segments).
    """
    mats = [Material("wall", DIFFUSE, diffuse=Texture.constant(albedo))]
    meshes, emitters = [], []
    for i, (v, f) in enumerate(box_faces()):
        emitters.append(Emitter(AREA, radiance=np.full(3, radiance), mesh=i))
        meshes.append(Mesh(f"wall{i}", v, f, 0, emitter=i))
    cam = Camera(look_at([1.0, 1.0, 1.9], [1.0, 1.0, 0.0], [0, 1, 0]), fov=60, width=width, height=height)
    return Scene(meshes, mats, emitters, cam, source="furnace")
