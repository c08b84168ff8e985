"""The Mitsuba scene document: parsed XML elements with ``file:line`` (:class:`Node`,
:func:`parse_xml_file`, through ``defusedxml``) and typed access to one object's properties
(:class:`Props`), shared by the scene loader (:mod:`common.mitsuba_xml`) and its per-plugin parsers
(:mod:`common.mitsuba_bsdfs`, :mod:`common.mitsuba_shapes`, :mod:`common.mitsuba_emitters`,
:mod:`common.mitsuba_sensors`)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .scene import SceneError, Texture
from .scene_root import read_bytes

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

    data = read_bytes(path, display)
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


class Props:
    """The named properties and unnamed nested objects of one object element.

    ``loader`` is the :class:`common.mitsuba_xml._Loader` at work: it reports errors and warnings
    and parses values (``error``, ``warn``, ``xyz``, ``color``, ``transform``, ``texture``)."""

    def __init__(self, loader, node: Node):
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

    def emitted(self, name: str, default) -> np.ndarray:
        """An emitter's colour (radiance, intensity, irradiance): a ``<spectrum>`` there is light of
        that spectrum, as Mitsuba 3's RGB variants read it (:mod:`common.cie`: a uniform one is the
        equal-energy illuminant, pink beside sRGB's white); ``<rgb>`` and ``<float>`` as given."""
        n = self.named.get(name)
        spectrum = None if n is None else self.loader.deref(n)
        if spectrum is not None and spectrum.tag == "spectrum":
            self.used.add(name)
            return self.loader.color(spectrum, emitted=True)
        return self.rgb(name, default)

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
            self.loader.color(n, emitted=self.node.tag == "emitter")  # (an emitter's light has no gamut bound)
        elif tag in ("point", "vector"):
            self.loader.xyz(n)
        elif tag == "transform":
            self.loader.transform(n)


def fmt_rgb(v) -> str:
    v = np.asarray(v, dtype=np.float64)
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"
