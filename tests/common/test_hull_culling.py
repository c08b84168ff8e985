"""common.hull_culling and the shadow BVH without the supporting planes' triangles
(Geometry.interior_bvh): which triangles are left out, that the gather's rays get the full
BVH's answers, and that rays that may leave the planes' inner side keep the full BVH."""
from __future__ import annotations

import numpy as np
import pytest

from igi.bench.stress_scenes import eye_end_points, load_shared
from igi.common.hull_culling import centred_planes, supporting_planes
from igi.common.lights import VPL_DIRECTIONAL
from igi.common.ray_packets import packet_scene
from igi.common.scene import CONSTANT, POINT, Emitter
from igi.worker.renderer import Renderer
from igi.worker.shading import gather_vpls, vpl_columns
from igi.worker.vpl import build_vpl_set, subset_vpls

_CUBE_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def _cube(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return v, _CUBE_FACES.copy()


def _mesh(*parts):
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    v, f = np.concatenate(verts), np.concatenate(faces)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return v, f, area, float(np.linalg.norm(v.max(0) - v.min(0)))


def test_a_rooms_walls_are_culled_and_the_furniture_is_not():
    room = _cube([0, 0, 0], [4, 3, 5])
    box = _cube([1, 0, 1], [2, 1, 2])  # standing on the floor: its bottom lies in the floor's plane
    v, f, area, diag = _mesh(room, box)
    planes, culled = supporting_planes(v, f, area, diag)
    assert len(planes) == 6
    assert culled[:12].all()  # the room's six faces
    assert culled[12:].sum() == 2  # the box's bottom, in the floor's plane; its other faces stay
    assert np.all(v @ planes[:, :3].T + planes[:, 3] <= 1e-12)  # every vertex on the inner side
    np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0)


def test_an_open_box_culls_its_walls_and_has_no_plane_where_it_is_open():
    v, f = _cube([0, 0, 0], [1, 1, 1])
    keep = ~np.all(v[f][:, :, 2] == 1.0, axis=1)  # no front face (z = 1): the Cornell box's opening
    v2, f2, area, diag = _mesh((v, f[keep]), _cube([0.3, 0.3, 0.3], [0.6, 0.6, 0.6]))
    planes, culled = supporting_planes(v2, f2, area, diag)
    assert len(planes) == 5 and culled[:10].all() and not culled[10:].any()
    assert not np.any(np.isclose(planes[:, 2], 1.0))  # the opening's plane holds no triangle


def test_geometry_beyond_a_wall_keeps_that_wall():
    room = _cube([0, 0, 0], [4, 3, 5])
    ground = (np.array([[-10, -0.5, -10], [10, -0.5, -10], [10, -0.5, 10], [-10, -0.5, 10]], float),
              np.array([[0, 2, 1], [0, 3, 2]]))  # below the floor and wider than the room
    v, f, area, diag = _mesh(room, ground)
    planes, culled = supporting_planes(v, f, area, diag)
    floor = np.all(v[f][:, :, 1] == 0.0, axis=1)
    walls = np.all(np.isclose(v[f][:, :, 0], 0.0), axis=1) | np.all(np.isclose(v[f][:, :, 0], 4.0), axis=1)
    assert not culled[floor].any()  # the ground lies beyond the floor's plane
    assert not culled[walls].any()  # and beyond the walls'
    assert culled[12:].all()  # the ground itself is a face of the hull


def test_planes_holding_little_of_the_area_are_not_worth_a_second_bvh():
    v, f, area, diag = _mesh(_cube([0, 0, 0], [1, 1, 1]), _cube([0.4, 0.4, 0.4], [0.5, 0.5, 0.5]))
    share = area[:12].sum() / area.sum()  # the room's faces: 0.99 of the area
    planes, culled = supporting_planes(v, f, area, diag, min_share=share - 1e-3)
    assert len(planes) == 6 and culled[:12].all() and not culled[12:].any()
    planes, culled = supporting_planes(v, f, area, diag, min_share=share + 1e-3)
    assert planes.shape == (0, 4) and not culled.any()


def test_a_flat_scene_has_no_supporting_plane_to_cull():
    quad = (np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    v, f, area, diag = _mesh(quad)
    planes, culled = supporting_planes(v, f, area, diag)
    assert planes.shape == (0, 4) and not culled.any()


def test_the_planes_holding_the_most_area_are_kept():
    v, f, area, diag = _mesh(_cube([0, 0, 0], [1, 2, 4]))
    planes, culled = supporting_planes(v, f, area, diag, max_planes=2)
    assert len(planes) == 2 and culled.sum() == 4
    assert np.allclose(np.abs(planes[:, 0]), 1.0)  # the two 2 × 4 faces (normal ±x)


def test_centred_planes_move_with_the_centre_and_give_slack():
    planes = np.array([[0.0, 1.0, 0.0, -3.0]])  # y <= 3
    c = centred_planes(planes, np.array([1.0, 2.0, 3.0]), 0.01)
    assert c.dtype == np.float32
    assert c[0, :3] @ np.array([0, 1.0, 0]) + c[0, 3] <= 0  # y = 3 in the world: y = 1 centred, inside
    assert c[0, :3] @ np.array([0, 1.005, 0]) + c[0, 3] <= 0  # within the slack
    assert c[0, :3] @ np.array([0, 1.02, 0]) + c[0, 3] > 0


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-sphere", "veach-ajar"])
def test_the_gathers_rays_get_the_full_bvhs_answers_on_the_inner_bvh(name):
    """Every shadow ray the gather sends to the inner BVH gets the answer the full BVH gives,
    but for rays that graze a wall at their very end (float rounding decides those either
    way): at most 1 in 10^5."""
    from igi.worker import shading

    r = Renderer(load_shared(name))
    geom = r.geom
    inner, planes = geom.interior_bvh()
    assert len(planes) >= 4  # walls, floor, ceiling: not vacuous
    end = eye_end_points(r, 64, 48)
    vpls = build_vpl_set(r.scene, geom, r.lights, 0, 1, 4, 32, 4)
    cols = vpl_columns(vpls, geom, 1e-3 * geom.diagonal ** 2)
    pi, _pj, _w, _row, _pl, o, d, t, use = shading._pair_rays(geom, end, slice(0, len(end)), vpls, cols, -1)
    assert use.mean() > 0.5  # most rows' rays go to the inner BVH
    full = geom.shadow_bvh().occluded(o[use], d[use], t[use])
    got = inner.occluded(o[use], d[use], t[use])
    assert full.any() and not full.all()
    assert np.sum(full != got) <= max(1, use.sum() // 100_000)


def test_a_light_beyond_the_ceiling_stays_blocked():
    """A point light above the closed Cornell box lies outside the ceiling's plane: its
    columns keep the full BVH for every pair, so the ceiling blocks it as before — the gather
    with the light equals the gather without it."""
    scene = load_shared("cornell-box")
    lo, hi = scene.bounds()
    scene.emitters.append(Emitter(POINT, intensity=np.full(3, 50.0), position=np.array(
        [0.5 * (lo[0] + hi[0]), hi[1] + 0.5, 0.5 * (lo[2] + hi[2])]), name="above the ceiling"))
    r = Renderer(scene)
    geom = r.geom
    assert len(geom.interior_bvh()[1]) == 6
    end = eye_end_points(r, 32, 24)
    vpls = build_vpl_set(r.scene, geom, r.lights, 0, 2, 16, 0, 4)
    c2 = 1e-3 * geom.diagonal ** 2
    cols = vpl_columns(vpls, geom, c2)
    assert cols.col_out[-1] > 0 and not np.any(vpls.kind == VPL_DIRECTIONAL)  # the point light's columns
    _a, lit = gather_vpls(geom, end, vpls, c2, -1)
    point = vpls.position[:, 1] > hi[1]
    assert point.any() and (~point).any()
    _a2, area_alone = gather_vpls(geom, end, subset_vpls(vpls, np.flatnonzero(~point)), c2, -1)
    assert np.any(area_alone > 0)
    np.testing.assert_allclose(lit, area_alone, rtol=1e-6, atol=1e-9)


def test_a_room_lit_through_a_window_culls_its_walls_for_the_vpls_inside():
    """The bundled window room (sun and sky through a window): the sky's and the sun's columns
    keep the full BVH, the VPLs inside take the inner one, in the same rows — the packet gather
    still equals the pair-list path bit for bit (each BVH's pairs summed apart in column order),
    and equals the gather with no culling up to the order of the sums."""
    from igi.common import bundled
    from igi.common.loader import load_scene
    from igi.worker.shading import _pair_rays

    r = Renderer(load_scene(bundled.resolve("window-room")))
    geom = r.geom
    if geom.packet_handle() is None:
        pytest.skip("Embree's C API is not at hand")
    assert len(geom.interior_bvh()[1]) >= 4
    end = eye_end_points(r, 48, 36)
    vpls = build_vpl_set(r.scene, geom, r.lights, 0, 1, 8, 24, 4)
    assert np.any(vpls.kind == VPL_DIRECTIONAL) and np.any(vpls.kind != VPL_DIRECTIONAL)
    c2 = 1e-3 * geom.diagonal ** 2
    cols = vpl_columns(vpls, geom, c2)
    inner = _pair_rays(geom, end, slice(0, len(end)), vpls, cols, -1)[8]
    assert 0 < inner.mean() < 1  # both BVHs in use (most pairs here are the sky's and the sun's)
    _a1, fused = gather_vpls(geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=5)
    r2 = Renderer(load_scene(bundled.resolve("window-room")))
    r2.geom.packet_handle = lambda: None  # the pair-list path
    _a2, listed = gather_vpls(r2.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=5)
    assert fused.sum() > 0
    np.testing.assert_array_equal(fused, listed)
    r3 = Renderer(load_scene(bundled.resolve("window-room")))
    r3.geom._interior = (r3.geom.shadow_bvh(), np.zeros((0, 4), np.float32))  # no culling
    _a3, unculled = gather_vpls(r3.geom, end, vpls, c2, -1, shadow_roulette=1.0, seed=5)
    np.testing.assert_allclose(fused, unculled, rtol=1e-9, atol=1e-12)
