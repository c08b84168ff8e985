"""Mitsuba 3 scene XML (a subset) -> :class:`common.scene.Scene`.

Supported (everything else is skipped or replaced, with a warning in ``Scene.warnings`` that names
the element, its ``file:line`` and the fallback):

- shapes ``obj``, ``ply``, ``rectangle``, ``cube``, ``sphere`` (tessellated), ``disk`` (tessellated)
  with ``to_world``, ``face_normals``, ``flip_normals``, ``flip_tex_coords`` (obj), ``center`` and
  ``radius`` (sphere); a nested or referenced BSDF and area emitter;
- BSDFs ``diffuse``, ``conductor``, ``roughconductor``, ``dielectric``, ``thindielectric``,
  ``plastic``, ``roughplastic``, ``twosided``; ``null`` maps to the black ``NULL`` kind;
  ``roughdielectric`` falls back to ``dielectric``; ``mask``/``bumpmap``/``normalmap``/``blendbsdf``
  fall back to their (first) nested BSDF; textures ``bitmap`` (``filename``, ``filter_type``,
  ``raw``, ``to_uv`` scale/translate); other textures fall back to their mean colour;
- emitters ``area``, ``point``, ``spot``, ``directional``, ``constant`` (``envmap`` falls back to
  a ``constant`` with the map's solid-angle mean radiance);
- sensor ``perspective`` (``fov``/``focal_length``, ``fov_axis``, ``to_world``, ``near_clip``) with
  an ``hdrfilm`` (``width``, ``height``); ``<integrator>``'s ``max_depth``;
- ``<default>`` + ``$name`` substitution (the ``defaults`` argument wins), ``<ref>``, ids,
  ``<alias>``, ``<path>``, ``<include>``; values ``float``, ``integer``, ``boolean``, ``string``,
  ``rgb``, ``spectrum`` (a single value is gray), ``point``, ``vector``, ``transform``;
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
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import shapes as shp
from . import transform as tf
from .obj_mtl import drop_nonfinite, load_obj_mesh, recompute_vertex_normals, remove_degenerate
from .scene import (AREA, CONDUCTOR, CONSTANT, DIELECTRIC, DIFFUSE, DIRECTIONAL, NULL, PLASTIC, POINT,
                    ROUGHCONDUCTOR, ROUGHPLASTIC, SPOT, THINDIELECTRIC, Camera, Emitter, Material, Mesh, Scene,
                    SceneError, Texture)
from .scene_root import SceneRoot, SceneRootError

log = logging.getLogger("igi.scene")

PROPERTY_TAGS = {"float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform"}
OBJECT_TAGS = {"bsdf", "texture", "emitter", "shape", "sensor", "film", "sampler", "rfilter", "integrator",
               "medium", "phase", "volume"}

# Mitsuba 3's named indices of refraction (ior.h).
IOR_TABLE = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277, "carbon dioxide": 1.00045,
    "water": 1.3330, "acetone": 1.36, "ethanol": 1.361, "carbon tetrachloride": 1.461, "glycerol": 1.4729,
    "benzene": 1.501, "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046, "sodium chloride": 1.544,
    "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}

# Conductor presets as RGB (eta, k): the values Mitsuba 3.9.1 (scalar_rgb) derives from its
# spectral IOR tables, read back with mi.traverse().
CONDUCTORS = {
    "a-C": ((2.944046, 2.227136, 1.968162), (0.887465, 0.799299, 0.81529)),
    "Ag": ((0.155276, 0.116728, 0.138388), (4.828354, 3.122222, 2.146901)),
    "Al": ((1.657501, 0.880405, 0.521244), (9.223811, 6.269502, 4.837004)),
    "Au": ((0.143036, 0.375307, 1.442045), (3.982997, 2.385556, 1.603359)),
    "Be": ((4.185012, 3.185029, 2.784061), (3.835466, 3.010122, 2.868994)),
    "Cr": ((4.369668, 2.916505, 1.654905), (5.206547, 4.231306, 3.754699)),
    "Cu": ((0.201005, 0.92375, 1.102215), (3.913262, 2.453045, 2.14209)),
    "Cu2O": ((3.551773, 2.94987, 2.751875), (0.114207, 0.193897, 0.606134)),
    "CuO": ((3.247541, 2.447805, 2.21022), (0.52109, 0.570031, 0.722179)),
    "Hg": ((2.398939, 1.440028, 0.90957), (6.327587, 4.371925, 3.421764)),
    "Ir": ((3.0863, 2.082191, 1.617915), (5.592153, 4.067088, 3.267312)),
    "K": ((0.064043, 0.04641, 0.038185), (2.1042, 1.34894, 0.913126)),
    "Li": ((0.265791, 0.195618, 0.220949), (3.540155, 2.311123, 1.668607)),
    "Mo": ((4.483974, 3.525131, 2.77631), (4.111437, 3.420827, 3.150607)),
    "Na_palik": ((0.060269, 0.056141, 0.061988), (3.179273, 2.11249, 1.579041)),
    "Nb": ((3.420074, 2.790093, 2.395629), (3.441395, 2.737666, 2.579746)),
    "Ni_palik": ((2.367305, 1.663373, 1.467078), (4.498812, 3.050153, 2.345439)),
    "Rh": ((2.585793, 1.860216, 1.554263), (6.78226, 4.702987, 3.976073)),
    "Ta": ((2.062721, 2.392939, 2.627929), (2.40836, 1.741486, 1.947028)),
    "TiN": ((1.64845, 1.150516, 1.379823), (3.368328, 1.943498, 1.102068)),
    "V_palik": ((4.277582, 3.512949, 2.761071), (3.491301, 2.889455, 3.111522)),
    "VN": ((2.865602, 2.119189, 1.940091), (3.032243, 2.056116, 1.616306)),
    "W": ((4.370817, 3.300246, 2.998407), (3.500641, 2.604874, 2.273233)),
}


@dataclass
class Node:
    tag: str
    attrib: dict[str, str]
    line: int
    file: str
    children: list["Node"] = field(default_factory=list)

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"

    def describe(self) -> str:
        a = self.attrib
        bits = [f"{k}='{a[k]}'" for k in ("type", "name", "id") if k in a]
        return f"<{self.tag}{' ' if bits else ''}{' '.join(bits)}>"


# ---------------------------------------------------------------------------------------------
# XML parsing with line numbers (defusedxml)


class _Builder:
    def __init__(self, display: str):
        self.display = display
        self.stack: list[Node] = []
        self.root: Node | None = None
        self.parser = None

    def _line(self) -> int:
        try:
            return int(self.parser.parser.CurrentLineNumber)
        except Exception:  # pragma: no cover - defensive
            return 0

    def start(self, tag, attrib):
        node = Node(tag, dict(attrib), self._line(), self.display)
        if self.stack:
            self.stack[-1].children.append(node)
        else:
            self.root = node
        self.stack.append(node)

    def end(self, tag):
        self.stack.pop()

    def data(self, text):
        pass

    def close(self):
        return self.root


def parse_xml_file(path: Path, display: str) -> Node:
    import xml.etree.ElementTree as ET

    from defusedxml import DefusedXmlException
    from defusedxml.ElementTree import DefusedXMLParser

    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{display}: file not found") from None
    except OSError as e:
        raise SceneError(f"{display}: cannot read ({e.strerror or e})") from None
    builder = _Builder(display)
    parser = DefusedXMLParser(target=builder, forbid_dtd=False, forbid_entities=True, forbid_external=True)
    builder.parser = parser
    try:
        parser.feed(data)
        root = parser.close()
    except ET.ParseError as e:
        line = e.position[0] if getattr(e, "position", None) else builder._line()
        msg = re.sub(r":? line \d+, column \d+$", "", str(e)).strip() or "malformed XML"
        raise SceneError(f"{display}:{line}: {msg}") from None
    except DefusedXmlException as e:
        kind = type(e).__name__
        what = {"EntitiesForbidden": "entity declarations are not allowed (entity expansion / external entity)",
                "ExternalReferenceForbidden": "external references are not allowed",
                "DTDForbidden": "DTDs are not allowed"}.get(kind, kind)
        raise SceneError(f"{display}:{builder._line()}: {what} ({e})") from None
    except (ValueError, LookupError) as e:  # e.g. an unknown encoding in the XML declaration
        raise SceneError(f"{display}:{builder._line()}: {e}") from None
    if root is None:
        raise SceneError(f"{display}:1: empty document")
    return root


# ---------------------------------------------------------------------------------------------
# Object property access


class _Props:
    """The named properties and unnamed nested objects of one object element."""

    def __init__(self, loader: "_Loader", node: Node):
        self.loader = loader
        self.node = node
        self.type = node.attrib.get("type", "")
        self.named: dict[str, Node] = {}
        self.children: list[Node] = []
        self.used: set[str] = set()
        for c in node.children:
            if c.tag in PROPERTY_TAGS or c.tag in OBJECT_TAGS or c.tag == "ref":
                name = c.attrib.get("name")
                if name is None:
                    if c.tag in PROPERTY_TAGS:
                        raise loader.error(c, f"<{c.tag}> needs a 'name' attribute")
                    self.children.append(c)
                    continue
                if name in self.named:
                    raise loader.error(c, f"duplicate property '{name}' in {node.describe()}")
                self.named[name] = c
            else:
                loader.warn(c, f"unsupported element <{c.tag}> inside {node.describe()}", "ignored")

    def has(self, name: str) -> bool:
        return name in self.named

    def get(self, name: str) -> Node | None:
        n = self.named.get(name)
        if n is not None:
            self.used.add(name)
        return n

    def _value(self, n: Node) -> str:
        if "value" not in n.attrib:
            raise self.loader.error(n, f"{n.describe()} needs a 'value' attribute")
        return n.attrib["value"]

    def _expect(self, n: Node, *tags: str) -> None:
        if n.tag not in tags:
            raise self.loader.error(n, f"{n.describe()}: expected <{'> or <'.join(tags)}>")

    def float(self, name: str, default: float | None = None) -> float | None:
        n = self.get(name)
        if n is None:
            return default
        self._expect(n, "float", "integer")
        s = self._value(n)
        try:
            return float(s)
        except ValueError:
            raise self.loader.error(n, f"<{n.tag} name='{name}'> value '{s}' is not a number") from None

    def int(self, name: str, default: int | None = None) -> int | None:
        n = self.get(name)
        if n is None:
            return default
        self._expect(n, "integer")
        s = self._value(n)
        try:
            return int(s)
        except ValueError:
            raise self.loader.error(n, f"<integer name='{name}'> value '{s}' is not an integer") from None

    def bool(self, name: str, default: bool = False) -> bool:
        n = self.get(name)
        if n is None:
            return default
        self._expect(n, "boolean")
        s = self._value(n).strip().lower()
        if s in ("true", "1"):
            return True
        if s in ("false", "0"):
            return False
        raise self.loader.error(n, f"<boolean name='{name}'> value '{s}' is not 'true' or 'false'")

    def string(self, name: str, default: str | None = None) -> str | None:
        n = self.get(name)
        if n is None:
            return default
        self._expect(n, "string")
        return self._value(n)

    def vec3(self, name: str, default=None) -> np.ndarray | None:
        n = self.get(name)
        if n is None:
            return None if default is None else np.asarray(default, dtype=np.float64)
        self._expect(n, "point", "vector", "rgb")
        return self.loader.xyz(n)

    def transform(self, name: str) -> np.ndarray:
        n = self.get(name)
        if n is None:
            return np.eye(4)
        self._expect(n, "transform")
        return self.loader.transform(n)

    def ior(self, name: str, default: float) -> float:
        n = self.get(name)
        if n is None:
            return default
        if n.tag == "string":
            s = self._value(n).strip().lower()
            if s in IOR_TABLE:
                return IOR_TABLE[s]
            raise self.loader.error(n, f"<string name='{name}'>: unknown index of refraction '{s}' "
                                       f"(known: {', '.join(sorted(IOR_TABLE))})")
        self._expect(n, "float", "integer")
        s = self._value(n)
        try:
            v = float(s)
        except ValueError:
            raise self.loader.error(n, f"<{n.tag} name='{name}'> value '{s}' is not a number") from None
        if not (np.isfinite(v) and v > 0):
            # Mitsuba refuses these too; a zero IOR would divide by zero in the BSDF tables.
            raise self.loader.error(n, f"<{n.tag} name='{name}'> index of refraction {s} must be a positive number")
        return v

    def texture(self, name: str, default) -> Texture:
        n = self.get(name)
        if n is None:
            return Texture.constant(default)
        return self.loader.texture(n)

    def rgb(self, name: str, default) -> np.ndarray:
        """A colour; a texture is replaced by its mean (with a warning)."""
        n = self.get(name)
        if n is None:
            return np.broadcast_to(np.asarray(default, dtype=np.float64), (3,)).copy()
        t = self.loader.texture(n)
        if not t.is_constant:
            self.loader.warn(n, f"textured '{name}' in {self.node.describe()} is not supported",
                             "using the texture's mean colour")
            return t.mean().astype(np.float64)
        return np.asarray(t.rgb, dtype=np.float64)

    def finish(self, ignore: tuple[str, ...] = ()) -> None:
        """Warn about parameters nobody read (after checking that their values are well-formed,
        as Mitsuba parses every value)."""
        for name, n in self.named.items():
            if name in self.used:
                continue
            self.validate(n)
            if name not in ignore:
                self.loader.warn(n, f"unsupported parameter '{name}' of {self.node.describe()}", "ignored")

    def validate(self, n: Node) -> None:
        tag, name = n.tag, n.attrib.get("name")
        if tag == "float":
            self.float(name)
        elif tag == "integer":
            self.int(name)
        elif tag == "boolean":
            self.bool(name)
        elif tag in ("rgb", "spectrum"):
            self.loader.color(n)
        elif tag in ("point", "vector"):
            self.loader.xyz(n)
        elif tag == "transform":
            self.loader.transform(n)


# ---------------------------------------------------------------------------------------------


_PARAM_RE = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def _camel_to_snake(s: str) -> str:
    return re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", s).lower()


class _Loader:
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
        self.warnings: list[str] = []
        self.meshes: list[Mesh] = []
        self.materials: list[Material] = []
        self.emitters: list[Emitter] = []
        self.material_of: dict[int, int] = {}
        self.texture_of: dict[int, Texture] = {}
        self.images: dict[tuple[str, bool], np.ndarray] = {}
        self.default_material: int | None = None
        self.camera: Camera | None = None
        self.max_depth = -1

    # -- diagnostics ---------------------------------------------------------------------------
    def error(self, node: Node, msg: str) -> SceneError:
        return SceneError(f"{node.where}: {msg}")

    def warn(self, node: Node | None, what: str, fallback: str) -> None:
        where = f" at {node.where}" if node is not None else ""
        msg = f"{what}{where}, {fallback}"
        log.warning(msg)
        self.warnings.append(msg)

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

    def color(self, node: Node) -> np.ndarray:
        """<rgb>, <spectrum>, <float> -> (3,) float64."""
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
                self.warn(node, f"spectrum file '{node.attrib['filename']}' is not supported", "using 0.5")
                return np.full(3, 0.5)
            s = node.attrib.get("value")
            if s is None:
                raise self.error(node, f"{node.describe()} needs a 'value' attribute")
            if ":" in s:
                vals = []
                for pair in s.replace(",", " ").split():
                    try:
                        _, val = pair.split(":")
                        vals.append(float(val))
                    except ValueError:
                        raise self.error(node, f"{node.describe()} value '{s}' is not a list of "
                                               "wavelength:value pairs") from None
                self.warn(node, "sampled <spectrum> is not supported", "using the mean of its values (gray)")
                return np.full(3, float(np.mean(vals)) if vals else 0.0)
            v = self.numbers(node, s)
            if len(v) != 1:
                raise self.error(node, f"{node.describe()} value '{s}' must be a single number")
            return np.full(3, v[0])
        raise self.error(node, f"{node.describe()}: expected a colour (<rgb>, <spectrum>, <float>) or a texture")

    # -- textures ------------------------------------------------------------------------------
    def texture(self, node: Node) -> Texture:
        node = self.deref(node)
        if node.tag != "texture":
            return Texture.constant(self.color(node))
        key = id(node)
        if key in self.texture_of:
            return self.texture_of[key]
        p = _Props(self, node)
        kind = p.type
        if kind == "bitmap":
            fn = p.string("filename")
            if fn is None:
                raise self.error(node, "<texture type='bitmap'> needs a 'filename'")
            path = self.resolve(fn, node)
            raw = p.bool("raw", False)
            ft = p.string("filter_type", "bilinear")
            if ft not in ("bilinear", "nearest"):
                self.warn(node, f"filter_type '{ft}'", "using bilinear")
                ft = "bilinear"
            wrap = p.string("wrap_mode", "repeat")
            if wrap != "repeat":
                self.warn(node, f"wrap_mode '{wrap}' is not supported", "using repeat")
            m = p.transform("to_uv")
            uv_scale, uv_offset = (1.0, 1.0), (0.0, 0.0)
            if not tf.is_identity(m):
                if abs(m[0, 1]) > 1e-12 or abs(m[1, 0]) > 1e-12:
                    self.warn(p.named["to_uv"], "rotated/sheared to_uv is not supported", "using its diagonal")
                sx, sy, tx, ty = m[0, 0], m[1, 1], m[0, 3], m[1, 3]
                # Meshes store v_scene = 1 - v_mitsuba; Mitsuba looks up row (sy v + ty) H.
                uv_scale, uv_offset = (float(sx), float(sy)), (float(tx), float(1.0 - sy - ty))
            ikey = (str(path.resolve()), raw)
            if ikey not in self.images:
                from .image_io import read_image

                try:
                    self.images[ikey] = read_image(path, raw=raw)
                except SceneError as e:
                    raise SceneError(f"{e} (referenced at {node.where})") from None
            t = Texture(image=self.images[ikey], filter=ft, uv_scale=uv_scale, uv_offset=uv_offset, name=fn)
            p.finish(ignore=("format",))
        elif kind == "checkerboard":
            c0 = p.rgb("color0", 0.4)
            c1 = p.rgb("color1", 0.2)
            p.transform("to_uv")
            self.warn(node, "texture 'checkerboard' is not supported", "using the mean of its two colours")
            t = Texture.constant(0.5 * (c0 + c1))
        else:
            vals = [self.color(c) for c in node.children if c.tag in ("rgb", "spectrum", "float")]
            mean = np.mean(vals, axis=0) if vals else np.full(3, 0.5)
            self.warn(node, f"texture '{kind}' is not supported", f"using constant {_fmt(mean)}")
            t = Texture.constant(mean)
        self.texture_of[key] = t
        return t

    # -- BSDFs ---------------------------------------------------------------------------------
    def material_index(self, node: Node | None) -> int:
        if node is None:
            if self.default_material is None:
                self.materials.append(Material(name="default", kind=DIFFUSE))
                self.default_material = len(self.materials) - 1
            return self.default_material
        node = self.deref(node)
        key = id(node)
        if key not in self.material_of:
            mat = self.bsdf(node)
            self.materials.append(mat)
            self.material_of[key] = len(self.materials) - 1
        return self.material_of[key]

    def _nested_bsdfs(self, p: _Props) -> list[Node]:
        out = []
        for c in p.children + list(p.named.values()):
            t = self.deref(c)
            if t.tag == "bsdf":
                out.append(t)
        return out

    def bsdf(self, node: Node, name: str | None = None) -> Material:
        if node.tag != "bsdf":
            raise self.error(node, f"{node.describe()} is not a <bsdf>")
        p = _Props(self, node)
        kind = p.type
        name = name or node.attrib.get("id", f"{kind}@{node.line}")
        if kind == "twosided":
            inner = self._nested_bsdfs(p)
            for k in list(p.named):
                p.get(k)
            if not inner:
                raise self.error(node, "<bsdf type='twosided'> needs a nested BSDF")
            if len(inner) > 1:
                self.warn(node, "twosided with two different BSDFs is not supported", "using the front BSDF on both sides")
            mat = self.bsdf(inner[0], name)
            mat.twosided = True
            p.finish()
            return mat
        if kind == "diffuse":
            mat = Material(name=name, kind=DIFFUSE, diffuse=p.texture("reflectance", 0.5))
        elif kind in ("conductor", "roughconductor"):
            mat = Material(name=name, kind=CONDUCTOR if kind == "conductor" else ROUGHCONDUCTOR,
                           specular=p.texture("specular_reflectance", 1.0))
            material = p.string("material", "none")
            if p.has("eta") or p.has("k"):
                mat.eta = p.rgb("eta", 0.0)
                mat.k = p.rgb("k", 1.0)
                if material != "none":
                    self.warn(p.named["material"], "conductor with both 'material' and 'eta'/'k'", "using eta/k")
            elif material == "none":
                mat.eta, mat.k = np.zeros(3), np.zeros(3)  # perfect mirror (scene.py convention)
            elif material in CONDUCTORS:
                eta, k = CONDUCTORS[material]
                mat.eta, mat.k = np.array(eta), np.array(k)
            else:
                raise self.error(p.named["material"], f"unknown conductor material '{material}' "
                                                      f"(known: none, {', '.join(sorted(CONDUCTORS))})")
            if kind == "roughconductor":
                self._roughness(p, mat, node)
        elif kind in ("dielectric", "thindielectric", "roughdielectric"):
            if kind == "roughdielectric":
                self.warn(node, "bsdf 'roughdielectric' is not supported", "using a smooth dielectric")
                p.get("alpha"), p.get("alpha_u"), p.get("alpha_v"), p.get("distribution")
            mat = Material(name=name, kind=THINDIELECTRIC if kind == "thindielectric" else DIELECTRIC,
                           int_ior=p.ior("int_ior", 1.5046), ext_ior=p.ior("ext_ior", 1.000277),
                           specular=p.texture("specular_reflectance", 1.0),
                           specular_transmittance=p.texture("specular_transmittance", 1.0))
            if p.has("eta"):
                eta = p.float("eta")
                mat.int_ior, mat.ext_ior = float(eta), 1.0
        elif kind in ("plastic", "roughplastic"):
            mat = Material(name=name, kind=PLASTIC if kind == "plastic" else ROUGHPLASTIC,
                           diffuse=p.texture("diffuse_reflectance", 0.5),
                           specular=p.texture("specular_reflectance", 1.0),
                           int_ior=p.ior("int_ior", 1.49), ext_ior=p.ior("ext_ior", 1.000277),
                           nonlinear=p.bool("nonlinear", False))
            if kind == "roughplastic":
                self._roughness(p, mat, node)
        elif kind == "null":
            self.warn(node, "bsdf 'null' (pass-through) is not supported", "using a black (NULL) material")
            mat = Material(name=name, kind=NULL, diffuse=Texture.constant(0.0))
        elif kind in ("mask", "bumpmap", "normalmap", "blendbsdf"):
            inner = self._nested_bsdfs(p)
            if inner:
                self.warn(node, f"bsdf '{kind}' is not supported", "using its (first) nested BSDF")
                return self.bsdf(inner[0], name)
            self.warn(node, f"bsdf '{kind}' is not supported", "using diffuse 0.5")
            return Material(name=name, kind=DIFFUSE)
        else:
            self.warn(node, f"unsupported bsdf '{kind}'", "using diffuse 0.5")
            return Material(name=name, kind=DIFFUSE)
        p.finish(ignore=("sample_visible", "specular_sampling_weight"))
        return mat

    def _roughness(self, p: _Props, mat: Material, node: Node) -> None:
        dist = p.string("distribution", "beckmann")
        if dist not in ("beckmann", "ggx"):
            raise self.error(p.named["distribution"], f"unknown microfacet distribution '{dist}' (beckmann or ggx)")
        mat.distribution = dist
        if p.has("alpha_u") or p.has("alpha_v"):
            au, av = p.float("alpha_u", 0.1), p.float("alpha_v", 0.1)
            if au != av:
                self.warn(node, "anisotropic roughness (alpha_u != alpha_v) is not supported",
                          f"using alpha = {math.sqrt(au * av):.4g}")
            mat.alpha = float(math.sqrt(au * av))
        else:
            n = p.named.get("alpha")
            if n is not None and self.deref(n).tag == "texture":
                t = self.texture(p.get("alpha"))
                self.warn(n, "textured alpha is not supported", "using its mean")
                mat.alpha = float(t.mean()[0])
            else:
                mat.alpha = float(p.float("alpha", 0.1))

    # -- shapes --------------------------------------------------------------------------------
    def shape(self, node: Node) -> None:
        p = _Props(self, node)
        kind = p.type
        if kind not in ("obj", "ply", "rectangle", "cube", "sphere", "disk"):
            self.warn(node, f"unsupported shape '{kind}'", "skipped")
            return
        M = p.transform("to_world")
        name = node.attrib.get("id", "")
        face_normals = False
        flip = p.bool("flip_normals", False)
        if kind in ("obj", "ply", "rectangle", "cube"):  # meshes in Mitsuba 3.9.1
            face_normals = p.bool("face_normals", False)
        if kind in ("obj", "ply"):
            fn = p.string("filename")
            if fn is None:
                raise self.error(node, f"<shape type='{kind}'> needs a 'filename'")
            path = self.resolve(fn, node)
            if kind == "obj":
                v, f, n, uv = load_obj_mesh(path, fn, self.warnings, flip_tex_coords=p.bool("flip_tex_coords", True))
            else:
                from .ply import load_ply_mesh

                v, f, n, uv = load_ply_mesh(path, fn, self.warnings)
            name = name or Path(fn).stem
        else:
            if kind == "rectangle":
                v, f, n, uv = shp.rectangle()
            elif kind == "cube":
                v, f, n, uv = shp.cube()
            elif kind == "disk":
                v, f, n, uv = shp.disk()
            else:
                c = p.vec3("center", (0.0, 0.0, 0.0))
                r = p.float("radius", 1.0)
                v, f, n, uv = shp.sphere()
                M = M @ tf.translate(c) @ tf.scale(r)
            name = name or f"{kind}@{node.line}"
        if abs(np.linalg.det(M[:3, :3])) < 1e-300:
            raise self.error(p.named.get("to_world", node), f"to_world of {node.describe()} is singular")
        V = tf.transform_points(M, v)
        if face_normals:
            N = None
        elif n is not None:
            N = tf.transform_normals(M, n)
        else:
            N = recompute_vertex_normals(V, f)
        f = drop_nonfinite(name, V, f, N, uv, self.warnings)
        f, _ = remove_degenerate(name, V, f, self.warnings)
        if flip:
            f, N = shp.flip_normals(f, N)
        # BSDF and emitter (nested or referenced)
        bsdf_node = None
        emitter_node = None
        others = list(p.children)
        if p.has("bsdf"):
            others.append(p.get("bsdf"))
        for c in others:
            t = self.deref(c)
            if t.tag == "bsdf":
                if bsdf_node is not None:
                    self.warn(c, f"{node.describe()} has more than one BSDF", "using the first")
                    continue
                bsdf_node = t
            elif t.tag == "emitter":
                if emitter_node is not None:
                    self.warn(c, f"{node.describe()} has more than one emitter", "using the first")
                    continue
                emitter_node = t
            else:
                self.warn(c, f"{t.describe()} inside {node.describe()} is not supported", "ignored")
        for k in ("interior", "exterior"):
            if p.has(k):
                self.warn(p.get(k), f"medium '{k}' is not supported", "ignored")
        p.finish()
        if len(f) == 0:
            self.warn(node, f"{node.describe()} has no triangles", "skipped")
            return
        mat = self.material_index(bsdf_node)
        mesh = Mesh(name=name, vertices=V, faces=np.ascontiguousarray(f, dtype=np.int32), material=mat,
                    normals=N, uvs=uv)
        self.meshes.append(mesh)
        if emitter_node is not None:
            ep = _Props(self, emitter_node)
            if ep.type != "area":
                self.warn(emitter_node, f"emitter '{ep.type}' attached to a shape is not supported", "ignored")
            else:
                e = Emitter(kind=AREA, radiance=ep.rgb("radiance", 1.0), mesh=len(self.meshes) - 1,
                            name=emitter_node.attrib.get("id", name))
                ep.finish()
                self.emitters.append(e)
                mesh.emitter = len(self.emitters) - 1

    # -- emitters ------------------------------------------------------------------------------
    def emitter(self, node: Node) -> None:
        p = _Props(self, node)
        kind = p.type
        name = node.attrib.get("id", kind)
        if kind == "area":
            self.warn(node, "an area emitter must be nested in a shape", "skipped")
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
                raise self.error(node, "directional emitter needs a non-zero direction")
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
                    img = read_image(self.resolve(fn, node)).astype(np.float64)
                    h = img.shape[0]
                    w = np.sin((np.arange(h) + 0.5) / h * np.pi)  # lat-long solid-angle weights
                    rad = (img.mean(axis=1) * w[:, None]).sum(axis=0) / w.sum()
                except SceneRootError:
                    raise
                except SceneError as err:
                    self.warn(node, f"envmap file unusable ({err})", "using radiance 1")
            rad = rad * scale
            self.warn(node, "emitter 'envmap' is not supported", f"using a constant emitter with its mean {_fmt(rad)}")
            e = Emitter(kind=CONSTANT, radiance=rad, name=name)
        else:
            self.warn(node, f"unsupported emitter '{kind}'", "skipped")
            return
        p.finish()
        self.emitters.append(e)

    # -- sensor / integrator -------------------------------------------------------------------
    def sensor(self, node: Node) -> None:
        p = _Props(self, node)
        kind = p.type
        if self.camera is not None:
            self.warn(node, "more than one <sensor>", "using the first")
            return
        if kind not in ("perspective", "thinlens"):
            self.warn(node, f"unsupported sensor '{kind}'", "using a perspective camera with its to_world")
        elif kind == "thinlens":
            self.warn(node, "sensor 'thinlens' (depth of field) is not supported", "using a pinhole perspective camera")
            p.get("aperture_radius"), p.get("focus_distance")
        M = p.transform("to_world")
        width, height = 768, 576
        film = None
        for c in p.children + [n for k, n in p.named.items() if n.tag == "film"]:
            t = self.deref(c)
            if t.tag == "film":
                film = t
            elif t.tag not in ("sampler", "rfilter"):
                self.warn(t, f"{t.describe()} inside a sensor is not supported", "ignored")
        if film is not None:
            fp = _Props(self, film)
            if fp.type not in ("hdrfilm", "specfilm"):
                self.warn(film, f"film '{fp.type}'", "reading only width/height")
            width = fp.int("width", 768)
            height = fp.int("height", 576)
            if width <= 0 or height <= 0:
                raise self.error(film, f"film size {width}x{height} must be positive")
        fov_axis = p.string("fov_axis", "x")
        if fov_axis not in ("x", "y", "diagonal", "smaller", "larger"):
            raise self.error(p.named["fov_axis"], f"unknown fov_axis '{fov_axis}'")
        if p.has("fov") and p.has("focal_length"):
            raise self.error(node, "give either 'fov' or 'focal_length', not both")
        if p.has("fov"):
            fov = p.float("fov")
            if not 0 < fov < 180:
                raise self.error(p.named["fov"], f"fov {fov} must be in (0, 180) degrees")
        else:
            s = p.string("focal_length", "50mm")
            m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*(mm)?\s*", s or "")
            try:
                flen = float(m.group(1)) if m else float("nan")
            except ValueError:
                flen = float("nan")
            if not flen > 0:
                raise self.error(p.named.get("focal_length", node), f"focal_length '{s}' is not a length like '50mm'")
            fov = math.degrees(2 * math.atan(math.hypot(36.0, 24.0) / (2 * flen)))
            fov_axis = "diagonal"
        self.camera = Camera(to_world=M, fov=float(fov), fov_axis=fov_axis, width=int(width), height=int(height),
                             near_clip=float(p.float("near_clip", 0.01)))
        p.finish(ignore=("far_clip", "shutter_open", "shutter_close", "principal_point_offset_x",
                         "principal_point_offset_y", "sample_border", "srf"))

    def integrator(self, node: Node) -> None:
        p = _Props(self, node)
        if p.type not in ("path", "volpath", "direct", "ptracer", "volpathmis"):
            self.warn(node, f"integrator '{p.type}' is not supported", "using path-tracing semantics (max_depth only)")
        self.max_depth = int(p.int("max_depth", -1))
        for c in p.children:
            t = self.deref(c)
            if t.tag == "integrator":
                sub = _Props(self, t)
                if sub.has("max_depth"):
                    self.max_depth = int(sub.int("max_depth", -1))

    # -- driver --------------------------------------------------------------------------------
    def run(self) -> Scene:
        root = self.load_root()
        for c in root.children:
            tag = c.tag
            if tag == "shape":
                self.shape(c)
            elif tag == "emitter":
                if c.attrib.get("type") == "area" and "id" in c.attrib:
                    continue  # a named area emitter is instantiated where a shape references it
                self.emitter(c)
            elif tag == "sensor":
                self.sensor(c)
            elif tag == "integrator":
                self.integrator(c)
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
        if self.camera is None:
            self.camera = self.default_camera()
            self.warn(root, "no <sensor>", "using Mitsuba's default camera (45 deg, looking along +z at the scene)")
        return Scene(meshes=self.meshes, materials=self.materials, emitters=self.emitters, camera=self.camera,
                     source=self.display, warnings=self.warnings, max_depth=self.max_depth)

    def default_camera(self) -> Camera:
        """Mitsuba's fallback sensor: perspective, fov 45 (x), 768x576, placed on -z in front of the
        scene's bounding box looking along +z."""
        if self.meshes:
            lo = np.min([m.vertices.min(axis=0) for m in self.meshes], axis=0)
            hi = np.max([m.vertices.max(axis=0) for m in self.meshes], axis=0)
        else:
            lo, hi = -np.ones(3), np.ones(3)
        centre, ext = 0.5 * (lo + hi), hi - lo
        dist = float(ext.max()) / (2.0 * math.tan(math.radians(22.5)))
        M = tf.translate([centre[0], centre[1], lo[2] - dist])
        return Camera(to_world=M, fov=45.0, fov_axis="x", width=768, height=576, near_clip=max(dist / 100, 1e-4))


def _fmt(v) -> str:
    v = np.asarray(v, dtype=np.float64)
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


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
