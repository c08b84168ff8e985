"""Mitsuba emitters (``point``, ``spot``, ``directional``, ``constant``; ``envmap`` as a constant)
-> :class:`common.scene.Emitter`; area emitters come with their shape (:mod:`common.mitsuba_shapes`).
A plain function of the loader at work (:class:`common.mitsuba_xml._Loader`)."""
from __future__ import annotations

import numpy as np

from .mitsuba_doc import Node, Props, fmt_rgb
from .scene import CONSTANT, DIRECTIONAL, POINT, SPOT, Emitter, SceneError
from .scene_root import SceneRootError


def load_emitter(loader, node: Node) -> None:
    p = Props(loader, node)
    kind = p.type
    name = node.attrib.get("id", kind)
    if kind == "area":
        loader.warn(node, "an area emitter must be nested in a shape", "skipped")
        return
    if kind == "point":
        if p.has("position"):
            pos = p.vec3("position")
        else:
            pos = p.transform("to_world")[:3, 3].copy()
        e = Emitter(kind=POINT, intensity=p.rgb("intensity", 1.0), position=pos, name=name)
    elif kind == "spot":
        M = p.transform("to_world")
        cutoff = p.float("cutoff_angle", 20.0)
        beam = p.float("beam_width", cutoff * 0.75)
        d = M[:3, :3] @ np.array([0.0, 0.0, 1.0])
        e = Emitter(kind=SPOT, intensity=p.rgb("intensity", 1.0), position=M[:3, 3].copy(),
                    direction=d / np.linalg.norm(d), cutoff_angle=float(cutoff), beam_width=float(beam),
                    name=name)
    elif kind == "directional":
        if p.has("direction"):
            d = p.vec3("direction")
        else:
            d = p.transform("to_world")[:3, :3] @ np.array([0.0, 0.0, 1.0])
        nd = np.linalg.norm(d)
        if not nd > 0:
            raise loader.error(node, "directional emitter needs a non-zero direction")
        e = Emitter(kind=DIRECTIONAL, irradiance=p.rgb("irradiance", 1.0), direction=d / nd, name=name)
    elif kind == "constant":
        e = Emitter(kind=CONSTANT, radiance=p.rgb("radiance", 1.0), name=name)
    elif kind == "envmap":
        fn = p.string("filename")
        scale = p.float("scale", 1.0)
        p.transform("to_world")
        rad = np.ones(3)
        if fn is not None:
            from .image_io import read_image

            try:
                img = read_image(loader.resolve(fn, node)).astype(np.float64)
                h = img.shape[0]
                w = np.sin((np.arange(h) + 0.5) / h * np.pi)  # lat-long solid-angle weights
                rad = (img.mean(axis=1) * w[:, None]).sum(axis=0) / w.sum()
            except SceneRootError:
                raise
            except SceneError as err:
                loader.warn(node, f"envmap file unusable ({err})", "using radiance 1")
        rad = rad * scale
        loader.warn(node, "emitter 'envmap' is not supported", f"using a constant emitter with its mean {fmt_rgb(rad)}")
        e = Emitter(kind=CONSTANT, radiance=rad, name=name)
    else:
        loader.warn(node, f"unsupported emitter '{kind}'", "skipped")
        return
    p.finish()
    loader.emitters.append(e)
