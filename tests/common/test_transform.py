"""Mitsuba 3 transform conventions (reference values checked against Mitsuba 3.9.1)."""
from types import SimpleNamespace

import numpy as np
import pytest

from igi.common import transform as tf


def el(tag, **attrib):
    return SimpleNamespace(tag=tag, attrib={k: str(v) for k, v in attrib.items()}, line=1)


def test_lookat_matches_mitsuba_convention_for_hand_computed_case():
    # origin (0,0,5) looking at the origin with up +y: dir = (0,0,-1),
    # left = normalize(cross(up, dir)) = (-1,0,0), new_up = cross(dir, left) = (0,1,0).
    m = tf.look_at([0, 0, 5], [0, 0, 0], [0, 1, 0])
    expected = np.array([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], dtype=float)
    np.testing.assert_allclose(m, expected, atol=1e-12)


def test_lookat_general_case_columns_are_left_up_dir_origin():
    o, t, up = np.array([1.0, 2, 3]), np.array([4.0, -5, 6]), np.array([0.0, 0, 1])
    m = tf.look_at(o, t, up)
    d = (t - o) / np.linalg.norm(t - o)
    left = np.cross(up, d)
    left /= np.linalg.norm(left)
    np.testing.assert_allclose(m[:3, 0], left)
    np.testing.assert_allclose(m[:3, 1], np.cross(d, left))
    np.testing.assert_allclose(m[:3, 2], d)
    np.testing.assert_allclose(m[:3, 3], o)
    # Mitsuba 3.9.1's ScalarTransform4f.look_at for the same arguments
    mitsuba = np.array([[0.919145, -0.144375, 0.366508], [0.393919, 0.336874, -0.855186], [0.0, 0.930415, 0.366508]])
    np.testing.assert_allclose(m[:3, :3], mitsuba, atol=1e-5)


def test_lookat_without_up_uses_mitsubas_coordinate_system():
    # Mitsuba 3.9.1 gives these columns for <lookat origin="0,0,0" target="0,0,1"/> and target (0,1,0)
    m = tf.parse_transform([el("lookat", origin="0,0,0", target="0 0 1")])
    np.testing.assert_allclose(m[:3, :3], [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-12)
    m = tf.parse_transform([el("lookat", origin="0,0,0", target="0 1 0")])
    np.testing.assert_allclose(m[:3, :3], [[0, 1, 0], [0, 0, 1], [1, 0, 0]], atol=1e-12)


def test_later_elements_apply_after_earlier_ones():
    tr_then_rot = tf.parse_transform([el("translate", x=1), el("rotate", z=1, angle=90)])
    rot_then_tr = tf.parse_transform([el("rotate", z=1, angle=90), el("translate", x=1)])
    p = np.array([[0.0, 0.0, 0.0]])
    # translate first: (1,0,0), then rotate 90 deg about z: (0,1,0)
    np.testing.assert_allclose(tf.transform_points(tr_then_rot, p), [[0, 1, 0]], atol=1e-12)
    # rotate first (origin stays), then translate: (1,0,0)
    np.testing.assert_allclose(tf.transform_points(rot_then_tr, p), [[1, 0, 0]], atol=1e-12)
    assert not np.allclose(tr_then_rot, rot_then_tr)
    np.testing.assert_allclose(tr_then_rot, tf.rotate([0, 0, 1], 90) @ tf.translate([1, 0, 0]))


def test_rotation_is_right_handed_in_degrees():
    np.testing.assert_allclose(tf.transform_vectors(tf.rotate([0, 0, 1], 90), [[1, 0, 0]]), [[0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(tf.transform_vectors(tf.rotate([1, 0, 0], 90), [[0, 1, 0]]), [[0, 0, 1]], atol=1e-12)


def test_rotate_axis_is_not_normalized_like_mitsuba():
    # Mitsuba 3.9.1: <rotate x="1" y="1" z="1" angle="33"/> has a unit diagonal (not a rotation)
    warned = []
    m = tf.parse_transform([el("rotate", value="1 1 1", angle=33)], warn=lambda *a: warned.append(a))
    np.testing.assert_allclose(m[:3, :3], [[1, -0.3833, 0.706], [0.706, 1, -0.3833], [-0.3833, 0.706, 1]], atol=1e-4)
    assert warned and "not unit length" in warned[0][1]
    # the plain helper normalizes by default
    r = tf.rotate([1, 1, 1], 33)
    np.testing.assert_allclose(r[:3, :3] @ r[:3, :3].T, np.eye(3), atol=1e-12)


def test_translate_scale_and_matrix_forms():
    np.testing.assert_allclose(tf.parse_transform([el("translate", value="1, 2, 3")])[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(tf.parse_transform([el("translate", y=2)])[:3, 3], [0, 2, 0])
    np.testing.assert_allclose(np.diag(tf.parse_transform([el("scale", value=2)])), [2, 2, 2, 1])
    np.testing.assert_allclose(np.diag(tf.parse_transform([el("scale", x=2, z=4)])), [2, 1, 4, 1])
    m = tf.parse_transform([el("matrix", value="1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1")])
    np.testing.assert_allclose(m[:3, 3], [5, 6, 7])  # row-major: translation in the last column


def test_normals_use_inverse_transpose():
    m = tf.scale([1, 4, 1])
    n = tf.transform_normals(m, np.array([[1.0, 1.0, 0.0]]))
    # the surface x + y = c scaled by 4 in y becomes x + y/4 = c: normal (1, 1/4, 0)
    np.testing.assert_allclose(n, [np.array([1.0, 0.25, 0.0]) / np.linalg.norm([1, 0.25, 0])])


@pytest.mark.parametrize("node, text", [
    (el("matrix", value="1 2 3"), "16 values"),
    (el("translate", x="abc"), "not a number"),
    (el("rotate", z=1), "angle"),
    (el("lookat", origin="0 0 0", target="0 0 0"), "coincide"),
    (el("skew", value=1), "unexpected"),
])
def test_malformed_transform_children_raise_transform_error(node, text):
    with pytest.raises(tf.TransformError, match=text) as e:
        tf.parse_transform([node])
    assert e.value.node is node
