"""Mitsuba ``<sensor>`` (with its film) -> :class:`common.scene.Camera`, Mitsuba's default camera,
and ``<integrator>``'s ``max_depth``. Plain functions of the loader at work
(:class:`common.mitsuba_xml._Loader`)."""
from __future__ import annotations

import math
import re

import numpy as np

from . import transform as tf
from .mitsuba_doc import Node, Props
from . import reconstruction_filter as rf
from .limits import MAX_COORD
from .scene import Camera, SceneError


def load_sensor(loader, node: Node) -> None:
    p = Props(loader, node)
    kind = p.type
    if loader.camera is not None:
        loader.warn(node, "more than one <sensor>", "using the first")
        return
    if kind not in ("perspective", "thinlens"):
        loader.warn(node, f"unsupported sensor '{kind}'", "using a perspective camera with its to_world")
    aperture, focus = 0.0, 10000.0
    if kind == "thinlens":  # (Mitsuba: aperture_radius required, focus_distance by default far_clip, 10^4)
        if not p.has("aperture_radius"):
            raise loader.error(node, "sensor 'thinlens' needs an 'aperture_radius'")
        aperture = float(p.float("aperture_radius"))
        focus = float(p.float("focus_distance", p.float("far_clip", 10000.0)))
        if not (0 <= aperture <= MAX_COORD):
            raise loader.error(p.named["aperture_radius"], f"aperture_radius {aperture} must be in [0, {MAX_COORD:g}]")
        if not (1e-6 <= focus <= MAX_COORD):
            raise loader.error(p.named.get("focus_distance", node),
                               f"focus_distance {focus} must be in [1e-06, {MAX_COORD:g}]")
    M = p.transform("to_world")
    width, height = 768, 576
    film = None
    for c in p.children + [n for k, n in p.named.items() if n.tag == "film"]:
        t = loader.deref(c)
        if t.tag == "film":
            film = t
        elif t.tag not in ("sampler", "rfilter"):
            loader.warn(t, f"{t.describe()} inside a sensor is not supported", "ignored")
    if film is not None:
        fp = Props(loader, film)
        if fp.type not in ("hdrfilm", "specfilm"):
            loader.warn(film, f"film '{fp.type}'", "reading only width/height")
        width = fp.int("width", 768)
        height = fp.int("height", 576)
        if width <= 0 or height <= 0:
            raise loader.error(film, f"film size {width}x{height} must be positive")
        rfilter = load_rfilter(loader, [loader.deref(c) for c in fp.children + list(fp.named.values())
                                        if loader.deref(c).tag == "rfilter"])
    else:
        rfilter = rf.DEFAULT
    fov_axis = p.string("fov_axis", "x")
    if fov_axis not in ("x", "y", "diagonal", "smaller", "larger"):
        raise loader.error(p.named["fov_axis"], f"unknown fov_axis '{fov_axis}'")
    if p.has("fov") and p.has("focal_length"):
        raise loader.error(node, "give either 'fov' or 'focal_length', not both")
    if p.has("fov"):
        fov = p.float("fov")
        if not 0 < fov < 180:
            raise loader.error(p.named["fov"], f"fov {fov} must be in (0, 180) degrees")
    else:
        s = p.string("focal_length", "50mm")
        m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*(mm)?\s*", s or "")
        try:
            flen = float(m.group(1)) if m else float("nan")
        except ValueError:
            flen = float("nan")
        if not flen > 0:
            raise loader.error(p.named.get("focal_length", node), f"focal_length '{s}' is not a length like '50mm'")
        fov = math.degrees(2 * math.atan(math.hypot(36.0, 24.0) / (2 * flen)))
        fov_axis = "diagonal"
    loader.camera = Camera(to_world=M, fov=float(fov), fov_axis=fov_axis, width=int(width), height=int(height),
                         near_clip=float(p.float("near_clip", 0.01)), rfilter=rfilter[0], rfilter_params=rfilter[1],
                         aperture_radius=aperture, focus_distance=focus)
    p.finish(ignore=("far_clip", "shutter_open", "shutter_close", "principal_point_offset_x",
                     "principal_point_offset_y", "sample_border", "srf"))


def load_rfilter(loader, nodes: list[Node]) -> tuple[str, tuple[float, float]]:
    """A film's reconstruction filter (common.reconstruction_filter) from its ``<rfilter>``
    elements: Mitsuba's default (gaussian, stddev 0.5) without one."""
    if not nodes:
        return rf.DEFAULT
    if len(nodes) > 1:
        loader.warn(nodes[1], "more than one <rfilter> in a film", "using the first")
    node = nodes[0]
    p = Props(loader, node)
    kind = p.type
    if kind not in rf.KINDS:
        loader.warn(node, f"unknown reconstruction filter '{kind}'", "using Mitsuba's default gaussian")
        return rf.DEFAULT
    if kind == "box":  # (Mitsuba 3's box takes no radius: always 0.5)
        params = (0.5, 0.0)
    else:  # the parameters and defaults rf.KINDS declares
        names, defaults = rf.KINDS[kind]
        defaults = defaults if isinstance(defaults, tuple) else (defaults,)
        values = [p.int(n, d) if n == "lobes" else p.float(n, d)
                  for n, d in zip([n for n in names.split(", ") if n], defaults)]
        params = tuple(float(v) for v in values + [0.0, 0.0][len(values):])
    p.finish()
    try:
        rf.validate(kind, params)
    except SceneError as e:
        raise loader.error(node, str(e)) from None
    if rf.has_negative_lobes(kind, params):
        loader.warn(node, f"reconstruction filter '{kind}' has negative lobes, which igi does not draw",
                    "sampling its positive part (slightly softer than Mitsuba's)")
    return kind, params


def load_integrator(loader, node: Node) -> None:
    p = Props(loader, node)
    if p.type not in ("path", "volpath", "direct", "ptracer", "volpathmis"):
        loader.warn(node, f"integrator '{p.type}' is not supported", "using path-tracing semantics (max_depth only)")
    loader.max_depth = int(p.int("max_depth", -1))
    for c in p.children:
        t = loader.deref(c)
        if t.tag == "integrator":
            sub = Props(loader, t)
            if sub.has("max_depth"):
                loader.max_depth = int(sub.int("max_depth", -1))


def default_camera(loader) -> Camera:
    """Mitsuba's fallback sensor: perspective, fov 45 (x), 768x576, placed on -z in front of the
    scene's bounding box looking along +z."""
    if loader.meshes:
        lo = np.min([m.vertices.min(axis=0) for m in loader.meshes], axis=0)
        hi = np.max([m.vertices.max(axis=0) for m in loader.meshes], axis=0)
    else:
        lo, hi = -np.ones(3), np.ones(3)
    centre, ext = 0.5 * (lo + hi), hi - lo
    dist = float(ext.max()) / (2.0 * math.tan(math.radians(22.5)))
    M = tf.translate([centre[0], centre[1], lo[2] - dist])
    return Camera(to_world=M, fov=45.0, fov_axis="x", width=768, height=576, near_clip=max(dist / 100, 1e-4),
                  rfilter=rf.DEFAULT[0], rfilter_params=rf.DEFAULT[1])
