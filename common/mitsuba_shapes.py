"""Mitsuba shapes (``obj``, ``ply``, ``rectangle``, ``cube``, ``sphere``, ``disk``) ->
:class:`common.scene.Mesh`, with their BSDF and area emitter. A plain function of the loader at
work (:class:`common.mitsuba_xml._Loader`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import shapes as shp
from . import transform as tf
from .limits import fmt_bytes, memory_budget
from .mitsuba_bsdfs import material_index
from .mitsuba_doc import Node, Props
from .obj_mtl import drop_nonfinite, load_obj_mesh, recompute_vertex_normals, remove_degenerate
from .scene import AREA, Emitter, Mesh
from .scene_root import read_bytes


def _cylinder_frame(loader, p: Props, node: Node) -> np.ndarray:
    """Mitsuba's cylinder: the unit cylinder carried onto its axis p0 -> p1 with its radius,
    translate(p0) · to_frame(Frame(d)) · scale(radius, radius, |d|), as Mitsuba 3 builds it."""
    p0 = p.vec3("p0", (0.0, 0.0, 0.0))
    p1 = p.vec3("p1", (0.0, 0.0, 1.0))
    r = p.float("radius", 1.0)
    d = np.asarray(p1, np.float64) - np.asarray(p0, np.float64)
    length = float(np.linalg.norm(d))
    if not (length > 0 and np.isfinite(length)):
        raise loader.error(node, f"cylinder axis p0 {list(p0)} -> p1 {list(p1)} has no length")
    if not (np.isfinite(r) and r != 0):
        raise loader.error(p.named.get("radius", node), f"cylinder radius {r} must be finite and not 0")
    s, t = tf.coordinate_system(d / length)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2] = s, t, d / length
    return tf.translate(p0) @ frame @ tf.scale([r, r, length])


def _mesh_file(loader, kind: str, path: Path, fn: str, option) -> tuple:
    """(vertices, faces, normals, uvs, stored name) of a mesh file in its own space, read once
    per loader (the instances of a shapegroup share their files; a serialized file's meshes
    share its bytes)."""
    cache = loader.mesh_files
    key = (kind, str(path), option)
    if key not in cache:
        if kind == "obj":
            cache[key] = (*load_obj_mesh(path, fn, loader.warnings, flip_tex_coords=option), "")
        elif kind == "ply":
            from .ply import load_ply_mesh

            cache[key] = (*load_ply_mesh(path, fn, loader.warnings), "")
        else:
            from .serialized import load_serialized_mesh

            if ("bytes", str(path)) not in cache:
                cache["bytes", str(path)] = read_bytes(path, fn)
            cache[key] = load_serialized_mesh(path, fn, option, loader.warnings, cache["bytes", str(path)])
    v, f, n, uv, stored = cache[key]
    return v, f.copy(), n, None if uv is None else uv.copy(), stored


def _load_instance(loader, node: Node, p: Props) -> None:
    """Mitsuba's ``instance``: every shape of its shapegroup (a <ref> to it or nested), placed by
    the instance's to_world after its own — as meshes of their own (igi flattens instances)."""
    groups = [loader.deref(c) for c in p.children]
    if len(groups) != 1 or groups[0].tag != "shape" or groups[0].attrib.get("type") != "shapegroup":
        raise loader.error(node, "<shape type='instance'> needs one shapegroup (a <ref> to it, or nested)")
    M = p.transform("to_world")
    p.finish()
    label = "#" + node.attrib.get("id", f"instance@{Path(node.file).name}:{node.line}")
    for c in groups[0].children:
        child = loader.deref(c)
        if child.tag != "shape":
            loader.warn(child, f"{child.describe()} inside a shapegroup", "ignored")
            continue
        load_shape(loader, child, M, label)


def load_shape(loader, node: Node, outer: np.ndarray | None = None, instance: str = "") -> None:
    """A ``<shape>`` as meshes of the scene. ``outer``: the to_world of the instance that places
    this shape of a shapegroup (named ``instance``)."""
    p = Props(loader, node)
    kind = p.type
    if kind in ("shapegroup", "instance"):
        if outer is not None:
            raise loader.error(node, f"a {kind} inside a shapegroup (nested instancing) is not supported, "
                                     "as in Mitsuba 3")
        if kind == "instance":
            _load_instance(loader, node, p)
        elif "id" not in node.attrib:
            loader.warn(node, "a shapegroup without an id is never instanced", "ignored")
        return  # (a shapegroup's shapes are loaded where an instance places them)
    if kind not in ("obj", "ply", "serialized", "rectangle", "cube", "sphere", "disk", "cylinder"):
        loader.warn(node, f"unsupported shape '{kind}'", "skipped")
        return
    M = p.transform("to_world")
    if outer is not None:
        M = outer @ M
    name = node.attrib.get("id", "")
    face_normals = False
    flip = p.bool("flip_normals", False)
    if kind in ("obj", "ply", "serialized", "rectangle", "cube"):  # meshes in Mitsuba 3.9.1
        face_normals = p.bool("face_normals", False)
    if kind in ("obj", "ply", "serialized"):
        fn = p.string("filename")
        if fn is None:
            raise loader.error(node, f"<shape type='{kind}'> needs a 'filename'")
        path = loader.resolve(fn, node)
        option = {"obj": lambda: p.bool("flip_tex_coords", True), "serialized": lambda: p.int("shape_index", 0),
                  "ply": lambda: 0}[kind]()
        v, f, n, uv, stored = _mesh_file(loader, kind, path, fn, option)
        if kind == "serialized":  # Mitsuba's name: the one stored with the mesh, or file@index
            name = name or stored or f"{Path(fn).name}@{option}"
        name = name or Path(fn).stem
    else:
        if kind == "rectangle":
            v, f, n, uv = shp.rectangle()
        elif kind == "cube":
            v, f, n, uv = shp.cube()
        elif kind == "disk":
            v, f, n, uv = shp.disk()
        elif kind == "cylinder":
            v, f, n, uv = shp.cylinder()
            M = M @ _cylinder_frame(loader, p, node)
        else:
            c = p.vec3("center", (0.0, 0.0, 0.0))
            r = p.float("radius", 1.0)
            v, f, n, uv = shp.sphere()
            M = M @ tf.translate(c) @ tf.scale(r)
        name = name or f"{kind}@{node.line}"
    if abs(np.linalg.det(M[:3, :3])) < 1e-300:
        raise loader.error(p.named.get("to_world", node), f"to_world of {node.describe()} is singular")
    V = tf.transform_points(M, v)
    if face_normals:
        N = None
    elif n is not None:
        N = tf.transform_normals(M, n)
    else:
        N = recompute_vertex_normals(V, f)
    f = drop_nonfinite(name, V, f, N, uv, loader.warnings)
    f, _ = remove_degenerate(name, V, f, loader.warnings)
    if flip:
        f, N = shp.flip_normals(f, N)
    # BSDF and emitter (nested or referenced)
    bsdf_node = None
    emitter_node = None
    others = list(p.children)
    if p.has("bsdf"):
        others.append(p.get("bsdf"))
    for c in others:
        t = loader.deref(c)
        if t.tag == "bsdf":
            if bsdf_node is not None:
                loader.warn(c, f"{node.describe()} has more than one BSDF", "using the first")
                continue
            bsdf_node = t
        elif t.tag == "emitter":
            if emitter_node is not None:
                loader.warn(c, f"{node.describe()} has more than one emitter", "using the first")
                continue
            emitter_node = t
        else:
            loader.warn(c, f"{t.describe()} inside {node.describe()} is not supported", "ignored")
    for k in ("interior", "exterior"):
        if p.has(k):
            loader.warn(p.get(k), f"medium '{k}' is not supported", "ignored")
    p.finish()
    if outer is not None and emitter_node is not None:
        raise loader.error(emitter_node, "an emitting shape inside a shapegroup is not supported "
                                         "(Mitsuba 3 does not instance emitters)")
    if len(f) == 0:
        loader.warn(node, f"{node.describe()} has no triangles", "skipped")
        return
    name += instance
    mat = material_index(loader, bsdf_node, emitting=emitter_node is not None)
    mesh = Mesh(name=name, vertices=V, faces=np.ascontiguousarray(f, dtype=np.int32), material=mat,
                normals=N, uvs=uv)
    loader.meshes.append(mesh)
    loader.mesh_bytes += sum(a.nbytes for a in (V, mesh.faces, N, uv) if a is not None)
    if loader.mesh_bytes > memory_budget():  # (instances multiply a scene's meshes: refuse before they fill memory)
        raise loader.error(node, f"the scene's meshes take {fmt_bytes(loader.mesh_bytes)} so far, more than the "
                                 f"memory budget of {fmt_bytes(memory_budget())} (--memory-budget)")
    if emitter_node is not None:
        ep = Props(loader, emitter_node)
        if ep.type != "area":
            loader.warn(emitter_node, f"emitter '{ep.type}' attached to a shape is not supported", "ignored")
        else:
            e = Emitter(kind=AREA, radiance=ep.emitted("radiance", 1.0), mesh=len(loader.meshes) - 1,
                        name=emitter_node.attrib.get("id", name))
            ep.finish()
            loader.emitters.append(e)
            mesh.emitter = len(loader.emitters) - 1
            if loader.materials[mat].opacity is not None:
                # (light sampling emits from the whole shape: a mask on it would show α·L seen)
                loader.warn(node, "an opacity mask on an emitting shape is not supported", "the shape is opaque")
