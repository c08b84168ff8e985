"""Mitsuba emitters (``point``, ``spot``, ``directional``, ``constant``, ``envmap``)
-> :class:`common.scene.Emitter`; area emitters come with their shape (:mod:`common.mitsuba_shapes`).
A plain function of the loader at work (:class:`common.mitsuba_xml._Loader`)."""
from __future__ import annotations

import numpy as np

from .mitsuba_doc import Node, Props
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
        e = Emitter(kind=POINT, intensity=p.emitted("intensity", 1.0), position=pos, name=name)
    elif kind == "spot":
        M = p.transform("to_world")
        cutoff = p.float("cutoff_angle", 20.0)
        beam = p.float("beam_width", cutoff * 0.75)
        d = M[:3, :3] @ np.array([0.0, 0.0, 1.0])
        e = Emitter(kind=SPOT, intensity=p.emitted("intensity", 1.0), position=M[:3, 3].copy(),
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
        e = Emitter(kind=DIRECTIONAL, irradiance=p.emitted("irradiance", 1.0), direction=d / nd, name=name)
    elif kind == "constant":
        e = Emitter(kind=CONSTANT, radiance=p.emitted("radiance", 1.0), name=name)
    elif kind == "envmap":
        fn = p.string("filename")
        scale = p.float("scale", 1.0)
        M = p.transform("to_world")
        if fn is None:
            raise loader.error(node, "<emitter type='envmap'> needs a filename")
        from .environment_map import EnvironmentMap
        from .image_io import read_image
        from .limits import LimitError, check_environment_map

        R = M[:3, :3]
        if not abs(np.linalg.det(R)) > 1e-12:
            raise loader.error(node, "envmap to_world is singular")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4):  # a scaled or sheared frame: its rotation
            q, tri = np.linalg.qr(R)
            R = q * np.sign(np.diag(tri))[None, :]
        R = np.array(R, np.float64)
        try:
            img = read_image(loader.resolve(fn, node)).astype(np.float32) * np.float32(scale)
            check_environment_map(img.shape[1], img.shape[0], f"envmap '{fn}'")
            env_map = EnvironmentMap(img, R)
        except SceneRootError:
            raise
        except LimitError as err:
            raise loader.error(node, str(err)) from None
        except SceneError as err:
            raise loader.error(node, f"envmap '{fn}': {err}") from None
        e = Emitter(kind=CONSTANT, radiance=env_map.mean, image=img, to_world=R, name=name)
        e.__dict__["_environment_map"] = (img, R, env_map)  # (common.environment_map.emitter_map's cache)
    else:
        loader.warn(node, f"unsupported emitter '{kind}'", "skipped")
        return
    p.finish()
    loader.emitters.append(e)
