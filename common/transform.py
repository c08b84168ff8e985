"""4x4 affine transforms with Mitsuba 3's conventions.

A ``<transform name="to_world">`` element holds a sequence of ``translate``, ``rotate``,
``scale``, ``matrix`` and ``lookat`` children. Mitsuba applies them in document order: each
later element acts *after* the earlier ones, so the result is ``M = T_n @ ... @ T_2 @ T_1``
(column vectors, ``p_world = M @ p_local``).

Points transform with ``M``, directions with its upper 3x3, normals with the inverse transpose
of the upper 3x3 (then renormalized).
"""
from __future__ import annotations

import math

import numpy as np


def identity() -> np.ndarray:
    return np.eye(4)


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, dtype=np.float64).reshape(3)
    return m


def scale(v) -> np.ndarray:
    s = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return np.diag([s[0], s[1], s[2], 1.0])


def rotate(axis, angle_deg: float, normalize: bool = True) -> np.ndarray:
    """Right-handed rotation by ``angle_deg`` degrees about ``axis`` (Rodrigues' formula).

    Mitsuba 3's ``<rotate>`` does *not* normalize the axis (checked with Mitsuba 3.9.1: an axis
    of (1, 1, 1) gives a matrix with a unit diagonal, i.e. not a rotation); ``normalize=False``
    reproduces that, the XML parser uses it.
    """
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    n = np.linalg.norm(a)
    if n == 0 or not np.isfinite(n):
        raise ValueError("rotation axis must be a non-zero finite vector")
    x, y, z = a / n if normalize else a
    t = np.radians(angle_deg)
    s, c = np.sin(t), np.cos(t)
    cm = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [
        [x * x * cm + c, x * y * cm - z * s, x * z * cm + y * s],
        [x * y * cm + z * s, y * y * cm + c, y * z * cm - x * s],
        [x * z * cm - y * s, y * z * cm + x * s, z * z * cm + c],
    ]
    return m


def coordinate_system(n) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to unit ``n`` (Duff et al. 2017, as Mitsuba's ``coordinate_system``)."""
    x, y, z = np.asarray(n, dtype=np.float64).reshape(3)
    sign = math.copysign(1.0, z)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.array([1.0 + sign * x * x * a, sign * b, -sign * x])
    t = np.array([b, sign + y * y * a, -y])
    return s, t


def look_at(origin, target, up=None) -> np.ndarray:
    """Mitsuba 3's ``Transform4f::look_at``: camera space +z looks at ``target``.

    ``dir = normalize(target - origin)``, ``left = normalize(cross(up, dir))``,
    ``new_up = cross(dir, left)``; the matrix columns are ``[left, new_up, dir, origin]``.
    """
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    t = np.asarray(target, dtype=np.float64).reshape(3)
    d = t - o
    dn = np.linalg.norm(d)
    if dn == 0:
        raise ValueError("lookat: origin and target coincide")
    d = d / dn
    # Without an up vector Mitsuba uses the first vector of coordinate_system(dir).
    u = coordinate_system(d)[0] if up is None else np.asarray(up, dtype=np.float64).reshape(3)
    left = np.cross(u, d)
    ln = np.linalg.norm(left)
    if ln == 0:
        raise ValueError("lookat: up vector is parallel to the viewing direction")
    left = left / ln
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0] = left
    m[:3, 1] = new_up
    m[:3, 2] = d
    m[:3, 3] = o
    return m


def matrix(values) -> np.ndarray:
    """16 values (row-major 4x4) or 9 values (row-major 3x3, no translation)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 16:
        return v.reshape(4, 4).copy()
    if v.size == 9:
        m = np.eye(4)
        m[:3, :3] = v.reshape(3, 3)
        return m
    raise ValueError(f"a matrix needs 16 (or 9) values, got {v.size}")


def compose(transforms) -> np.ndarray:
    """Compose in Mitsuba's document order: the first element is applied first."""
    m = np.eye(4)
    for t in transforms:
        m = np.asarray(t, dtype=np.float64) @ m
    return m


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply the affine part of ``m`` to (N, 3) points (the projective row is ignored, as Mitsuba's
    ``transform_affine``)."""
    p = np.asarray(p, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def transform_vectors(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.asarray(v, dtype=np.float64) @ m[:3, :3].T


def normal_matrix(m: np.ndarray) -> np.ndarray:
    """The inverse transpose of the upper 3x3 (normals transform with it)."""
    return np.linalg.inv(m[:3, :3]).T


def transform_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Transform (N, 3) normals with the inverse transpose and renormalize; zero normals stay zero."""
    out = np.asarray(n, dtype=np.float64) @ normal_matrix(m).T
    length = np.linalg.norm(out, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(length > 0, out / np.where(length > 0, length, 1.0), 0.0)
    return out


def is_identity(m: np.ndarray) -> bool:
    return bool(np.array_equal(m, np.eye(4)))


# ---------------------------------------------------------------------------------------------
# <transform> element parsing


class TransformError(ValueError):
    """A malformed transform child; ``node`` is the offending element (for its line number)."""

    def __init__(self, node, message: str):
        super().__init__(message)
        self.node = node


def parse_floats(text: str) -> list[float]:
    """Numbers separated by commas and/or whitespace, as Mitsuba writes vectors and matrices."""
    parts = text.replace(",", " ").split()
    return [float(p) for p in parts]


def _vec3(node, text: str, what: str) -> np.ndarray:
    try:
        v = parse_floats(text)
    except ValueError:
        raise TransformError(node, f"<{node.tag}> {what} '{text}' is not a list of numbers") from None
    if len(v) == 1:
        v = v * 3
    if len(v) != 3:
        raise TransformError(node, f"<{node.tag}> {what} '{text}' needs 3 numbers, got {len(v)}")
    return np.array(v, dtype=np.float64)


def _xyz(node, default: float) -> np.ndarray:
    """x/y/z attributes, or a 'value' attribute holding 1 or 3 numbers."""
    a = node.attrib
    if "value" in a:
        return _vec3(node, a["value"], "value")
    out = []
    for k in ("x", "y", "z"):
        s = a.get(k)
        if s is None:
            out.append(default)
            continue
        try:
            out.append(float(s))
        except ValueError:
            raise TransformError(node, f"<{node.tag}> {k}='{s}' is not a number") from None
    return np.array(out, dtype=np.float64)


def element_matrix(node, warn=None) -> np.ndarray:
    """The 4x4 matrix of one transform child (``node`` has ``.tag`` and ``.attrib``);
    ``warn(node, what, fallback)`` is called for Mitsuba quirks worth knowing."""
    tag, a = node.tag, node.attrib
    if tag == "translate":
        return translate(_xyz(node, 0.0))
    if tag == "scale":
        if "value" in a:
            return scale(_vec3(node, a["value"], "value"))
        return scale(_xyz(node, 1.0))
    if tag == "rotate":
        if "angle" not in a:
            raise TransformError(node, "<rotate> needs an 'angle' attribute (degrees)")
        try:
            angle = float(a["angle"])
        except ValueError:
            raise TransformError(node, f"<rotate> angle '{a['angle']}' is not a number") from None
        axis = _xyz(node, 0.0)
        if not np.any(axis) or not np.all(np.isfinite(axis)):
            raise TransformError(node, "<rotate> needs a non-zero axis (x/y/z or value)")
        if warn is not None and abs(np.linalg.norm(axis) - 1.0) > 1e-6:
            warn(node, f"<rotate> axis {tuple(float(a) for a in axis)} is not unit length",
                 "used unnormalized as Mitsuba 3 does (the matrix is not a pure rotation)")
        return rotate(axis, angle, normalize=False)
    if tag == "matrix":
        if "value" not in a:
            raise TransformError(node, "<matrix> needs a 'value' attribute")
        try:
            vals = parse_floats(a["value"])
        except ValueError:
            raise TransformError(node, f"<matrix> value '{a['value']}' is not a list of numbers") from None
        if len(vals) not in (9, 16):
            raise TransformError(node, f"<matrix> needs 16 values (row-major), got {len(vals)}")
        return matrix(vals)
    if tag == "lookat":
        for k in ("origin", "target"):
            if k not in a:
                raise TransformError(node, f"<lookat> needs an '{k}' attribute")
        o = _vec3(node, a["origin"], "origin")
        t = _vec3(node, a["target"], "target")
        u = _vec3(node, a["up"], "up") if "up" in a else None
        try:
            return look_at(o, t, u)
        except ValueError as e:
            raise TransformError(node, f"<lookat> {e}") from None
    raise TransformError(node, f"unexpected <{tag}> inside <transform>")


def parse_transform(children, warn=None) -> np.ndarray:
    """Compose the children of a ``<transform>`` element in Mitsuba's order (``M = T_n @ ... @ T_1``).

    Raises :class:`TransformError` naming the offending child.
    """
    return compose(element_matrix(c, warn) for c in children)
