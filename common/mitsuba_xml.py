"""Mitsuba 3 scene XML (a subset) -> :class:`common.scene.Scene`.

Supported (everything else is skipped or replaced, with a warning in ``Scene.warnings`` that names
the element, its ``file:line`` and the fallback):

- shapes ``obj``, ``ply``, ``serialized`` (``shape_index``), ``rectangle``, ``cube``, ``sphere``,
  ``disk`` and ``cylinder`` (``p0``, ``p1``, ``radius``; the three tessellated) with ``to_world``,
  ``face_normals``, ``flip_normals``, ``flip_tex_coords`` (obj), ``center`` and ``radius``
  (sphere); a nested or referenced BSDF and area emitter (a shape that emits and names no BSDF is
  black, as in Mitsuba); ``shapegroup`` and ``instance`` (flattened);
- BSDFs ``diffuse``, ``conductor``, ``roughconductor``, ``dielectric``, ``thindielectric``,
  ``roughdielectric``, ``plastic``, ``roughplastic``, ``twosided``; ``principled`` and
  ``principledthin`` approximated by the nearest of those (:mod:`common.mitsuba_principled`);
  ``null`` maps to the black ``NULL`` kind; ``mask`` is its nested BSDF with an ``opacity``
  (constant or bitmap, :mod:`common.kernels.opacity_mask`); ``normalmap`` and ``bumpmap`` (its
  one texture, ``scale``) perturb their nested BSDF's shading normal
  (:mod:`common.kernels.bump_mapping`); ``blendbsdf`` falls back to the nested BSDF its ``weight``
  favours; textures ``bitmap``
  (``filename``, ``filter_type``, ``raw``, ``to_uv`` scale/translate) and ``checkerboard``; other
  textures fall back to their mean colour;
- emitters ``area``, ``point``, ``spot``, ``directional``, ``constant``, ``envmap`` (``filename``:
  OpenEXR or Radiance .hdr, ``scale``, ``to_world``; at most one environment emitter when one is
  a map);
- sensors ``perspective`` (``fov``/``focal_length``, ``fov_axis``, ``to_world``, ``near_clip``) and
  ``thinlens`` (also ``aperture_radius``, ``focus_distance``) with an ``hdrfilm`` (``width``,
  ``height``, its ``rfilter``: :mod:`common.reconstruction_filter`); ``<integrator>``'s ``max_depth``;
- ``<default>`` + ``$name`` substitution (the ``defaults`` argument wins), ``<ref>``, ids,
  ``<alias>``, ``<path>``, ``<include>``; values ``float``, ``integer``, ``boolean``, ``string``,
  ``rgb``, ``spectrum`` (a single value, ``wavelength:value`` pairs or an ``.spd`` file, converted to
  linear sRGB as Mitsuba 3's RGB variants do, :mod:`common.cie`: reflectances under D65, emitters'
  radiance, intensity and irradiance as light), ``point``, ``vector``, ``transform``;
- scenes in Mitsuba 0.x syntax (``version`` < 2) get camelCase parameter names upgraded.

Geometry follows Mitsuba 3 exactly where it is observable (checked against Mitsuba 3.9.1):
see :mod:`common.obj_mtl` for OBJ vertex de-duplication, smooth-normal recomputation and uv
flipping, :mod:`common.shapes` for the analytic shapes and the uv convention (meshes store
``(u, 1 - v_mitsuba)`` because :meth:`common.scene.Texture.eval` maps bitmap row 0 to ``v = 1``).
Normals of a transformed mesh follow the inverse transpose; smooth normals that Mitsuba
computes are computed after ``to_world`` (in world space), as Mitsuba does. ``flip_normals``
reverses the winding and negates the shading normals.

Errors are :class:`~common.scene.SceneError` with ``file:line: problem``; the XML parser is
``defusedxml`` (entity declarations and external references are refused). Every file the scene
names must lie inside the scene root (default: the scene file's folder; :mod:`common.scene_root`).

The loader (:class:`_Loader`) walks the document: ``<default>``/``$name``, ``<include>``, ids and
references, ``<path>`` and file resolution, values and transforms; one module per kind of plugin
parses its elements: :mod:`common.mitsuba_bsdfs` (BSDFs, textures), :mod:`common.mitsuba_shapes`,
:mod:`common.mitsuba_emitters`, :mod:`common.mitsuba_sensors` (sensor, film, integrator), on top of
:mod:`common.mitsuba_doc` (XML elements with ``file:line``, property access).
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from . import transform as tf
from .mitsuba_bsdfs import CONDUCTORS, load_texture
from .cie import EQUAL_ENERGY_SRGB, spectrum_to_linear_srgb
from .mitsuba_doc import IOR_TABLE, OBJECT_TAGS, Node, fmt_rgb, parse_xml_file
from .mitsuba_emitters import load_emitter
from .mitsuba_sensors import default_camera, load_integrator, load_sensor
from .mitsuba_shapes import load_shape
from .scene import AREA, CONSTANT, Camera, Emitter, Material, Mesh, Scene, SceneError, Texture
from .scene_root import SceneRoot
from .scene_warnings import SceneWarnings

log = logging.getLogger("igi.scene")

_PARAM_RE = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def _camel_to_snake(s: str) -> str:
    return re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", s).lower()


class _Loader:
    """One scene file being loaded: the document walk and what the plugin parsers share (the
    scene's meshes, materials, emitters and camera so far, caches, warnings)."""

    def __init__(self, path: Path, defaults: dict[str, str] | None, root: SceneRoot):
        self.path = path
        self.display = str(path)
        self.base = path.parent
        self.root = root
        self.user_defaults = {k: str(v) for k, v in (defaults or {}).items()}
        self.params: dict[str, str] = {}
        self.ids: dict[str, Node] = {}
        self.aliases: dict[str, str] = {}
        self.search: list[Path] = [self.base]
        self.warnings = SceneWarnings(log)
        self.meshes: list[Mesh] = []
        self.materials: list[Material] = []
        self.emitters: list[Emitter] = []
        self.material_of: dict[int, int] = {}
        self.texture_of: dict[int, Texture] = {}
        self.images: dict[tuple[str, bool], np.ndarray] = {}
        self.default_materials: dict[str, int] = {}  # mitsuba_bsdfs.material_index's defaults
        self.mesh_files: dict[tuple, object] = {}  # mitsuba_shapes._mesh_file: mesh files (and bytes) read
        self.mesh_bytes = 0  # the meshes' arrays so far, held to the memory budget
        self.camera: Camera | None = None
        self.max_depth = -1

    # -- diagnostics ---------------------------------------------------------------------------
    def error(self, node: Node, msg: str) -> SceneError:
        return SceneError(f"{node.where}: {msg}")

    def warn(self, node: Node | None, what: str, fallback: str) -> None:
        where = f" at {node.where}" if node is not None else ""
        self.warnings.add(f"{what}{where}, {fallback}")

    # -- document preprocessing ----------------------------------------------------------------
    def load_root(self) -> Node:
        root = parse_xml_file(self.path, self.display)
        if root.tag != "scene":
            raise self.error(root, f"the root element must be <scene>, not <{root.tag}>")
        version = root.attrib.get("version", "3.0.0")
        try:
            major = int(version.split(".")[0])
        except ValueError:
            raise self.error(root, f"<scene> version '{version}' is not a version number") from None
        self._expand_includes(root, depth=0)
        if major < 2:
            self._upgrade(root)
        # <default> values, then the caller's overrides.
        for c in root.children:
            if c.tag == "default":
                if "name" not in c.attrib or "value" not in c.attrib:
                    raise self.error(c, "<default> needs 'name' and 'value' attributes")
                self.params.setdefault(c.attrib["name"], c.attrib["value"])
        self.params.update(self.user_defaults)
        self._substitute(root)
        self._collect_ids(root)
        return root

    def _expand_includes(self, node: Node, depth: int) -> None:
        out: list[Node] = []
        for c in node.children:
            if c.tag == "include":
                if depth > 16:
                    raise self.error(c, "<include> nested too deeply")
                fn = c.attrib.get("filename")
                if not fn:
                    raise self.error(c, "<include> needs a 'filename' attribute")
                p = self.resolve(fn, c)
                sub = parse_xml_file(p, fn)
                if sub.tag != "scene":
                    raise self.error(sub, f"an included file must have a <scene> root, not <{sub.tag}>")
                self._expand_includes(sub, depth + 1)
                out.extend(sub.children)
            else:
                self._expand_includes(c, depth)
                out.append(c)
        node.children = out

    def _upgrade(self, node: Node) -> None:
        for c in node.children:
            if "name" in c.attrib:
                c.attrib["name"] = _camel_to_snake(c.attrib["name"])
            if c.tag == "lookAt":
                c.tag = "lookat"
            self._upgrade(c)

    def _substitute(self, node: Node) -> None:
        for c in node.children:
            if c.tag != "default":
                for k, v in c.attrib.items():
                    if "$" in v:
                        def rep(m, c=c):
                            name = m.group(1)
                            if name not in self.params:
                                raise self.error(c, f"undefined parameter '${name}' (no <default name='{name}'>)")
                            return self.params[name]

                        c.attrib[k] = _PARAM_RE.sub(rep, v)
            self._substitute(c)

    def _collect_ids(self, node: Node) -> None:
        for c in node.children:
            if c.tag == "alias":
                if "id" not in c.attrib or "as" not in c.attrib:
                    raise self.error(c, "<alias> needs 'id' and 'as' attributes")
                self.aliases[c.attrib["as"]] = c.attrib["id"]
            elif c.tag in OBJECT_TAGS and "id" in c.attrib:
                i = c.attrib["id"]
                if i in self.ids:
                    raise self.error(c, f"duplicate id '{i}' (first defined at {self.ids[i].where})")
                self.ids[i] = c
            self._collect_ids(c)

    def deref(self, node: Node) -> Node:
        if node.tag != "ref":
            return node
        i = node.attrib.get("id")
        if i is None:
            raise self.error(node, "<ref> needs an 'id' attribute")
        seen = set()
        while i in self.aliases and i not in self.ids and i not in seen:
            seen.add(i)
            i = self.aliases[i]
        target = self.ids.get(i)
        if target is None:
            raise self.error(node, f"<ref id='{node.attrib['id']}'>: no object with this id")
        return target

    def resolve(self, filename: str, node: Node) -> Path:
        """The file ``filename`` (absolute, or relative to a search folder: the scene's, then each
        ``<path>``), resolved; :class:`SceneRootError` when it leads outside the scene root, which
        is checked before whether it exists (a refused path tells nothing about the file)."""
        p = Path(filename.replace("\\", "/"))
        outside = None
        for q in ([p] if p.is_absolute() else [d / p for d in self.search]):
            if not self.root.contains(q):
                outside = outside or q
                continue
            if q.is_file():
                return self.root.check(q, node.where, filename)
        if outside is not None:
            raise self.root.error(outside, node.where, filename)
        raise SceneError(f"{filename}: file not found (referenced at {node.where})")

    # -- values --------------------------------------------------------------------------------
    def numbers(self, node: Node, text: str, what: str = "value") -> list[float]:
        try:
            return tf.parse_floats(text)
        except ValueError:
            raise self.error(node, f"{node.describe()} {what} '{text}' is not a list of numbers") from None

    def xyz(self, node: Node) -> np.ndarray:
        a = node.attrib
        if "value" in a:
            v = self.numbers(node, a["value"])
            if len(v) == 1:
                v = v * 3
            if len(v) != 3:
                raise self.error(node, f"{node.describe()} value '{a['value']}' needs 3 numbers")
            return np.array(v, dtype=np.float64)
        out = []
        for k in ("x", "y", "z"):
            s = a.get(k, "0")
            try:
                out.append(float(s))
            except ValueError:
                raise self.error(node, f"{node.describe()} {k}='{s}' is not a number") from None
        return np.array(out, dtype=np.float64)

    def transform(self, node: Node) -> np.ndarray:
        try:
            m = tf.parse_transform(node.children, warn=self.warn)
        except tf.TransformError as e:
            raise self.error(e.node, str(e)) from None
        if not np.all(np.isfinite(m)):
            raise self.error(node, f"{node.describe()} is not finite")
        return m

    def color(self, node: Node, emitted: bool = False) -> np.ndarray:
        """<rgb>, <spectrum>, <float> -> (3,) float64. ``emitted``: an emitter's radiance, intensity
        or irradiance, whose spectra are light (:mod:`common.cie`) where a reflectance's are under D65."""
        if node.tag in ("float", "integer"):
            v = self.numbers(node, node.attrib.get("value", ""))
            if len(v) != 1:
                raise self.error(node, f"{node.describe()} value '{node.attrib.get('value')}' is not a number")
            return np.full(3, v[0])
        if node.tag == "rgb":
            if "value" not in node.attrib:
                raise self.error(node, f"{node.describe()} needs a 'value' attribute")
            v = self.numbers(node, node.attrib["value"])
            if len(v) == 1:
                return np.full(3, v[0])
            if len(v) != 3:
                raise self.error(node, f"{node.describe()} value '{node.attrib['value']}' needs 1 or 3 numbers")
            return np.array(v, dtype=np.float64)
        if node.tag == "spectrum":
            if "filename" in node.attrib:
                return self._sampled(node, *self._spectrum_file(node), emitted)
            s = node.attrib.get("value")
            if s is None:
                raise self.error(node, f"{node.describe()} needs a 'value' attribute")
            if ":" in s:
                wl, vals = [], []
                for pair in s.replace(",", " ").split():
                    try:
                        w, val = pair.split(":")
                        wl.append(float(w))
                        vals.append(float(val))
                    except ValueError:
                        raise self.error(node, f"{node.describe()} value '{s}' is not a list of "
                                               "wavelength:value pairs") from None
                return self._sampled(node, wl, vals, emitted)
            v = self.numbers(node, s)
            if len(v) != 1:
                raise self.error(node, f"{node.describe()} value '{s}' must be a single number")
            return v[0] * (EQUAL_ENERGY_SRGB if emitted else np.ones(3))
        raise self.error(node, f"{node.describe()}: expected a colour (<rgb>, <spectrum>, <float>) or a texture")

    def _spectrum_file(self, node: Node) -> tuple[list[float], list[float]]:
        """A ``.spd`` file's "wavelength value" lines (``#`` comments)."""
        path = self.resolve(node.attrib["filename"], node)
        wl, vals = [], []
        try:  # (a Latin-1 degree sign in a comment must not fail the scene)
            lines = path.read_bytes().decode("utf-8", errors="replace").splitlines()
        except OSError as e:
            raise self.error(node, f"spectrum file '{node.attrib['filename']}': {e.strerror}") from None
        for i, line in enumerate(lines, 1):
            line = line.split("#")[0].strip()
            if not line:
                continue
            try:
                w, val = map(float, line.split())
            except ValueError:
                raise self.error(node, f"spectrum file '{node.attrib['filename']}' line {i}: "
                                       f"'{line}' is not 'wavelength value'") from None
            wl.append(w)
            vals.append(val)
        return wl, vals

    def _sampled(self, node: Node, wl: list[float], vals: list[float], emitted: bool) -> np.ndarray:
        if len(wl) < 2 or any(b <= a for a, b in zip(wl, wl[1:])):
            raise self.error(node, f"{node.describe()} needs two or more wavelengths in increasing order")
        if not np.all(np.isfinite(vals)) or not np.all(np.isfinite(wl)):
            raise self.error(node, f"{node.describe()} is not finite")
        rgb, clamped = spectrum_to_linear_srgb(wl, vals, emitted)
        if clamped:
            self.warn(node, "spectrum outside the sRGB gamut", f"clamped to {fmt_rgb(rgb)} (as Mitsuba 3 does)")
        return rgb

    def texture(self, node: Node) -> Texture:
        """A colour element or a ``<texture>`` (or a ``<ref>`` to one) -> :class:`Texture`."""
        return load_texture(self, node)

    # -- driver --------------------------------------------------------------------------------
    def run(self) -> Scene:
        root = self.load_root()
        for c in root.children:
            tag = c.tag
            if tag == "shape":
                load_shape(self, c)
            elif tag == "emitter":
                if c.attrib.get("type") == "area" and "id" in c.attrib:
                    continue  # a named area emitter is instantiated where a shape references it
                load_emitter(self, c)
            elif tag == "sensor":
                load_sensor(self, c)
            elif tag == "integrator":
                load_integrator(self, c)
            elif tag in ("bsdf", "texture"):
                if "id" not in c.attrib:
                    self.warn(c, f"top-level {c.describe()} without an id is never used", "ignored")
            elif tag in ("default", "alias"):
                pass
            elif tag == "path":
                v = c.attrib.get("value")
                if not v:
                    raise self.error(c, "<path> needs a 'value' attribute")
                q = Path(v)
                self.search.append(q if q.is_absolute() else self.base / q)
            elif tag in ("medium", "phase", "volume"):
                self.warn(c, f"unsupported {c.describe()} (participating media)", "ignored")
            elif tag in ("sampler", "film", "rfilter"):
                self.warn(c, f"top-level {c.describe()}", "ignored")
            else:
                self.warn(c, f"unsupported element <{tag}>", "ignored")
        if not self.meshes and not any(e.kind != AREA for e in self.emitters):
            self.warn(root, "the scene has no shapes", "nothing to render")
        skies = [e for e in self.emitters if e.kind == CONSTANT]
        if len(skies) > 1 and any(e.image is not None for e in skies):
            raise self.error(root, "only one environment emitter (constant or envmap) per scene, as in Mitsuba 3; "
                             f"found {len(skies)}: " + ", ".join(e.name for e in skies))
        if self.camera is None:
            self.camera = default_camera(self)
            self.warn(root, "no <sensor>", "using Mitsuba's default camera (45 deg, looking along +z at the scene)")
        self.warnings.summarize()
        return Scene(meshes=self.meshes, materials=self.materials, emitters=self.emitters, camera=self.camera,
                     source=self.display, warnings=list(self.warnings), max_depth=self.max_depth)


def load_mitsuba(path: str | Path, defaults: dict[str, str] | None = None,
                 root: str | Path | None = None) -> Scene:
    """Load a Mitsuba 3 scene XML file (see the module docstring for the supported subset).

    Every file the scene names (``<include>``, meshes, bitmaps, envmaps) must lie inside ``root``
    (default: the scene file's folder) after symlinks and ``..``; :class:`SceneRootError` names
    the one that does not (:mod:`common.scene_root`)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    try:
        return _Loader(path, defaults, SceneRoot.for_scene(path, root)).run()
    except SceneError:
        raise
    except RecursionError:
        raise SceneError(f"{path}: elements nested too deeply") from None
    except (ValueError, LookupError, TypeError, OverflowError, ZeroDivisionError) as e:
        # Should not happen: every malformed input is meant to raise SceneError above.
        raise SceneError(f"{path}: cannot load scene ({type(e).__name__}: {e})") from e


__all__ = ["load_mitsuba", "IOR_TABLE", "CONDUCTORS"]
