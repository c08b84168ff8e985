"""Small scenes built in code, for tests that need exact analytic answers."""
from __future__ import annotations

import numpy as np

from igi.common.camera import look_at
from igi.common.scene import AREA, DIFFUSE, Camera, Emitter, Material, Mesh, Scene, Texture


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


def plastic_tile_in_furnace(albedo: float, radiance: float, diffuse: float = 0.0, width=24, height=24,
                            mirror_side: bool = False) -> Scene:
    """:func:`furnace_box` with a smooth plastic tile (``diffuse`` reflectance, specular 1, η
    1.5046) hanging in it: a 0.8 square centred at (1, 1, 0.8), its normal (0, sin 40°, cos 40°)
    tilted from the camera's axis, so the camera sees it at a range of angles and its coat
    mirrors the emitting, reflecting walls (radiance Le / (1 - albedo) with unlimited paths, up
    to the tile's small shadow on them). Material 1 is the tile's, mesh 6 the tile.
    ``mirror_side``: the wall x = 0 (mesh 2) a dark mirror instead (a conductor, material 2) and
    the camera's field of view 140°: it sees the tile also in the mirror (chains meet plastic)."""
    from igi.common.scene import CONDUCTOR, PLASTIC

    scene = furnace_box(albedo, radiance, width, height)
    scene.materials.append(Material("tile", PLASTIC, diffuse=Texture.constant(diffuse)))
    if mirror_side:
        scene.materials.append(Material("mirror", CONDUCTOR, specular=Texture.constant(0.8)))
        scene.meshes[2].material, scene.meshes[2].emitter = 2, -1
        del scene.emitters[2]
        for m in scene.meshes[3:6]:
            m.emitter -= 1
        scene.camera.fov = 140.0
    a = np.radians(40.0)
    u = np.array([0.8, 0.0, 0.0])
    v = 0.8 * np.array([0.0, np.cos(a), -np.sin(a)])
    tv, tf = quad(np.array([1.0, 1.0, 0.8]) - (u + v) / 2, u, v)
    if np.dot(np.cross(tv[1] - tv[0], tv[2] - tv[0]), [0.0, np.sin(a), np.cos(a)]) < 0:
        tf = tf[:, ::-1].copy()
    scene.meshes.append(Mesh("tile", tv, tf, 1))
    return scene


def plastic_box(width=32, height=32) -> Scene:
    """A closed box of smooth plastic walls (diffuse 0.5) under a small ceiling lamp: every coat's
    mirror ray meets another smooth plastic."""
    from igi.common.scene import PLASTIC

    mats = [Material("wall", PLASTIC, diffuse=Texture.constant(0.5)),
            Material("lamp", DIFFUSE, diffuse=Texture.constant(0.0))]
    meshes = [Mesh(f"wall{i}", v, f, 0) for i, (v, f) in enumerate(box_faces())]
    lv, lf = quad([0.7, 1.99, 0.7], [0.6, 0, 0], [0, 0, 0.6])
    if np.cross(lv[1] - lv[0], lv[2] - lv[0])[1] > 0:  # face down into the box
        lf = lf[:, ::-1].copy()
    meshes.append(Mesh("lamp", lv, lf, 1, emitter=0))
    cam = Camera(look_at([1.0, 1.0, 1.9], [1.0, 1.0, 0.0], [0, 1, 0]), fov=60, width=width, height=height)
    return Scene(meshes, mats, [Emitter(AREA, radiance=np.full(3, 20.0), mesh=6)], cam, source="plastic box")


def two_rooms(width=32, height=24) -> Scene:
    """Two diffuse rooms side by side ([0,2] and [2,4] along x, 2 high and deep) joined by a
    narrow door in the wall x = 2; the only light is a ceiling quad in the left room and the
    camera looks at the door from the right room: nearly all light it sees is indirect and
    came through the gap (the veach-ajar situation)."""
    mats = [Material("wall", DIFFUSE, diffuse=Texture.constant(0.7)),
            Material("black", DIFFUSE, diffuse=Texture.constant(0.0))]
    meshes = []
    for i, (v, f) in enumerate(box_faces(2.0)):
        if i != 3:  # face 3 (x = 2) is the shared wall, built below with its door
            meshes.append(Mesh(f"left{i}", v, f, 0))
        if i != 2:  # face 2 (x = 0) moved by 2 is the same shared wall
            meshes.append(Mesh(f"right{i}", v + np.array([2.0, 0, 0]), f, 0))
    # The shared wall x = 2 with a door 0.3 wide, 1.6 high at z in [0.85, 1.15]: four quads,
    # two-sided by being duplicated with both windings.
    pieces = [quad([2, 0, 0], [0, 0, 0.85], [0, 2, 0]), quad([2, 0, 1.15], [0, 0, 0.85], [0, 2, 0]),
              quad([2, 1.6, 0.85], [0, 0, 0.3], [0, 0.4, 0])]
    for j, (v, f) in enumerate(pieces):
        meshes.append(Mesh(f"door wall {j}a", v, f, 0))
        meshes.append(Mesh(f"door wall {j}b", v, f[:, ::-1].copy(), 0))
    lv, lf = quad([0.7, 1.99, 0.7], [0.6, 0, 0], [0, 0, 0.6])
    n = np.cross(lv[1] - lv[0], lv[2] - lv[0])
    if n[1] > 0:  # face down into the room
        lf = lf[:, ::-1].copy()
    meshes.append(Mesh("light", lv, lf, 1, emitter=0))
    emitters = [Emitter(AREA, radiance=np.full(3, 20.0), mesh=len(meshes) - 1)]
    cam = Camera(look_at([3.8, 1.0, 1.0], [2.0, 0.8, 1.0], [0, 1, 0]), fov=80, width=width, height=height)
    return Scene(meshes, mats, emitters, cam, source="two rooms")


def glossy_floor_lamp(width=48, height=36, alpha=0.05) -> Scene:
    """A smooth rough-conductor floor (white, perfect-mirror Fresnel) under a small, bright
    ceiling lamp, nothing else: every pixel sees the floor, and all it shows is the lamp's
    glossy reflection (no indirect light: nothing else reflects)."""
    from igi.common.scene import ROUGHCONDUCTOR

    mats = [Material("floor", ROUGHCONDUCTOR, alpha=alpha),
            Material("lamp", DIFFUSE, diffuse=Texture.constant(0.0))]
    fv, ff = quad([-3, 0, -3], [0, 0, 6], [6, 0, 0])  # normal +y
    lv, lf = quad([-0.15, 1.0, -0.15], [0.3, 0, 0], [0, 0, 0.3])  # normal -y: faces the floor
    if np.cross(lv[1] - lv[0], lv[2] - lv[0])[1] > 0:
        lf = lf[:, ::-1].copy()
    meshes = [Mesh("floor", fv, ff, 0), Mesh("lamp", lv, lf, 1, emitter=0)]
    emitters = [Emitter(AREA, radiance=np.full(3, 40.0), mesh=1)]
    cam = Camera(look_at([0.0, 0.8, 2.5], [0.0, 0.0, 0.6], [0, 1, 0]), fov=50, width=width, height=height)
    return Scene(meshes, mats, emitters, cam, source="glossy floor lamp")


def panel_and_lamp(width=32, height=24) -> Scene:
    """A diffuse room 2 × 2 × 2 lit by a large, dim ceiling panel (most of the power) and a
    small, bright lamp a hand's width from the wall the camera looks at: that wall's light
    comes mostly from the lamp, which a choice of emitter by power rarely samples."""
    mats = [Material("wall", DIFFUSE, diffuse=Texture.constant(0.6)),
            Material("black", DIFFUSE, diffuse=Texture.constant(0.0))]
    meshes = [Mesh(f"wall{i}", v, f, 0) for i, (v, f) in enumerate(box_faces(2.0))]

    def facing(v, f, normal):
        n = np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]])
        return f if np.dot(n, normal) > 0 else f[:, ::-1].copy()

    pv, pf = quad([0.2, 1.99, 0.2], [1.6, 0, 0], [0, 0, 1.6])  # the panel, facing down
    lv, lf = quad([0.95, 0.95, 0.15], [0.1, 0, 0], [0, 0.1, 0])  # the lamp, facing the wall z = 0
    meshes.append(Mesh("panel", pv, facing(pv, pf, [0, -1, 0]), 1, emitter=0))
    meshes.append(Mesh("lamp", lv, facing(lv, lf, [0, 0, -1]), 1, emitter=1))
    emitters = [Emitter(AREA, radiance=np.full(3, 1.0), mesh=len(meshes) - 2),
                Emitter(AREA, radiance=np.full(3, 60.0), mesh=len(meshes) - 1)]
    cam = Camera(look_at([1.0, 1.0, 1.95], [1.0, 1.0, 0.0], [0, 1, 0]), fov=70, width=width, height=height)
    return Scene(meshes, mats, emitters, cam, source="panel and lamp")
