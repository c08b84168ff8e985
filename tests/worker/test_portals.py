"""Light walks from the sky through portals found from the view (worker.portals): the openings
are found where the window is, portal walks deliver the same light as disk walks in expectation
(room lit through a window, sun and sky), more of them enter the room, and the renderer turns
them on only where a sky is seen through an enclosure."""
from __future__ import annotations

import numpy as np

from igi.common import bundled
from igi.common.camera import resolve_camera
from igi.common.lights import VPL_SURFACE
from igi.common.loader import load_scene
from igi.common.params import make_params
from igi.common.scene import CONSTANT
from igi.worker.portals import DISK_SHARE, _meets_box, find_portals, portal_walks
from igi.worker.renderer import Renderer
from igi.worker.vpl import build_vpl_set
from igi.worker.vpl_importance import View, view_portals

ROOM_LO, ROOM_HI = np.array([-2.0, 0.0, -3.0]), np.array([2.0, 2.5, 3.0])  # window-room's walls
WINDOW = (-2.0, (0.8, 2.0), (-1.5, 0.0))  # x plane, y range, z range (scene.xml header)


def _window_room():
    scene = load_scene(bundled.resolve("window-room"))
    r = Renderer(scene)
    cam, fov, w, h = resolve_camera(scene, None, None, None)
    view = View(tuple(np.asarray(cam, np.float64).ravel()), fov, w, h)
    return r, view


def _interior(position: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Hits on the inside of the room's walls: the ray travels outwards through the wall it hits."""
    centre, half = (ROOM_LO + ROOM_HI) / 2, (ROOM_HI - ROOM_LO) / 2
    rel = (position - centre) / half
    axis = np.argmax(np.abs(rel), axis=1)
    rows = np.arange(len(position))
    outward = np.sign(rel[rows, axis])
    return (direction[rows, axis] * outward > 0) & np.all(np.abs(rel) <= 1 + 1e-6, axis=1)


def test_portal_boxes_enclose_the_window_and_not_the_room():
    r, view = _window_room()
    p = view_portals(r.scene, r.geom, r.lights, view, -1, 8)
    assert p is not None and len(p) >= 1
    x, (y0, y1), (z0, z1) = WINDOW
    centre = np.array([x, (y0 + y1) / 2, (z0 + z1) / 2])
    assert any(np.all((lo <= centre) & (centre <= hi)) for lo, hi in zip(p.lo, p.hi))
    for lo, hi in zip(p.lo, p.hi):  # each box hugs the opening: about the window's size, on its wall
        assert lo[0] <= x <= hi[0] and hi[0] - lo[0] < 0.5
        assert hi[1] - lo[1] < (y1 - y0) + 0.5 and hi[2] - lo[2] < (z1 - z0) + 0.5
    np.testing.assert_allclose(p.choice.sum(), 1.0)
    assert p.emitter == next(i for i, e in enumerate(r.scene.emitters) if e.kind == CONSTANT)


def test_no_portals_without_an_enclosure():
    r, _ = _window_room()
    g = np.random.default_rng(0)
    d = g.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    far = r.lights.center + 10 * r.lights.radius  # escaped rays that start far outside everything
    assert find_portals(r.geom, r.lights, 0, np.tile(far, (50, 1)), d) is None
    assert find_portals(r.geom, r.lights, 0, np.zeros((0, 3)), np.zeros((0, 3))) is None


def test_portal_walks_equal_disk_walks_in_expectation():
    """The light that walks from the sky (and sun) bring to each inside wall, floor and ceiling
    is the same with portal walks as with walks from the disk around the scene, within noise;
    portal walks bring many more rays inside."""
    r, view = _window_room()
    portals = view_portals(r.scene, r.geom, r.lights, view, -1, 8)
    g = np.random.default_rng(7)
    sums = {False: [], True: []}
    inside_share = {False: [], True: []}
    for _ in range(12):
        u = g.random((30000, 5))
        for use in (False, True):
            rays = r.lights.emit_rays(u)
            if use:
                portal_walks(rays, u, r.lights, portals)
            hits = r.geom.intersect(rays.origin, rays.direction)
            v = np.nonzero(hits.valid)[0]
            inside = v[_interior(hits.position[v], rays.direction[v])]
            # per wall: which face of the room (6) each inside hit lies on
            rel = (hits.position[inside] - (ROOM_LO + ROOM_HI) / 2) / ((ROOM_HI - ROOM_LO) / 2)
            ax = np.argmax(np.abs(rel), axis=1)
            face = ax * 2 + (rel[np.arange(len(ax)), ax] > 0)
            per_face = np.bincount(face, weights=rays.flux[inside, 1], minlength=6) / len(u)
            sums[use].append(per_face)
            inside_share[use].append(len(inside) / len(u))
    disk, port = np.array(sums[False]), np.array(sums[True])
    se = np.sqrt(disk.var(axis=0, ddof=1) / len(disk) + port.var(axis=0, ddof=1) / len(port))
    lit = disk.mean(axis=0) > 0
    assert lit.sum() >= 3  # the sun patch and the sky's light reach several surfaces
    assert np.all(np.abs(disk.mean(axis=0) - port.mean(axis=0))[lit] < 4 * se[lit] + 1e-12)
    total_se = np.sqrt(disk.sum(1).var(ddof=1) / len(disk) + port.sum(1).var(ddof=1) / len(port))
    assert abs(disk.sum(1).mean() - port.sum(1).mean()) < 4 * total_se
    assert np.mean(inside_share[True]) > 3 * np.mean(inside_share[False])


def test_portal_walks_leave_other_emitters_alone():
    r, view = _window_room()
    portals = view_portals(r.scene, r.geom, r.lights, view, -1, 8)
    u = np.random.default_rng(3).random((4000, 5))
    plain = r.lights.emit_rays(u)
    rays = r.lights.emit_rays(u)
    portal_walks(rays, u, r.lights, portals)
    other = rays.emitter != portals.emitter
    assert other.any() and (~other).any()
    np.testing.assert_array_equal(rays.origin[other], plain.origin[other])
    np.testing.assert_array_equal(rays.flux[other], plain.flux[other])
    # the sky's rays: at least the portal share pass through a box, all with a positive flux
    sky = ~other
    assert np.all(np.isfinite(rays.flux[sky])) and np.all(rays.flux[sky] > 0)
    through = np.zeros(int(sky.sum()), bool)
    for lo, hi in zip(portals.lo, portals.hi):
        through |= _meets_box(rays.origin[sky], rays.direction[sky], lo, hi)
    assert through.mean() > (1 - DISK_SHARE) - 0.05


def test_vpl_sets_with_portals_have_more_vpls_inside():
    r, view = _window_room()
    portals = view_portals(r.scene, r.geom, r.lights, view, -1, 8)
    counts = {False: 0, True: 0}
    for seed in range(6):
        for use in (False, True):
            s = build_vpl_set(r.scene, r.geom, r.lights, seed, 0, 0, 256, 1, portals=portals if use else None)
            counts[use] += int(np.count_nonzero(s.kind == VPL_SURFACE))
    assert counts[True] > 1.15 * counts[False]  # (the sun's walks, most of the power, are unchanged)


def test_renderer_uses_portals_only_where_the_sky_is_seen_through_an_opening():
    r, view = _window_room()
    on = make_params(vpl_importance=1)
    assert r.portals(on, view) is not None
    assert "vpl_portals" in r.portal_notes
    assert r.portals(make_params(vpl_importance=1, vpl_portals=False), view) is None
    box = Renderer(load_scene(bundled.resolve("cornell-box")))  # an area light: no sky, no portals
    cam, fov, w, h = resolve_camera(box.scene, None, None, None)
    assert box.portals(on, View(tuple(np.asarray(cam, np.float64).ravel()), fov, w, h)) is None
