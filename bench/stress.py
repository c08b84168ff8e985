"""``igi bench stress``: numerical stress scenes and scene-file fuzzing (issue 8), as JSON.

Two parts, both also run (smaller) by the tests:

- **Stress scenes** (``bench/stress_scenes.py``, needs a source checkout and the shared
  scenes): every case is rendered small through the distributed path; the JSON records whether
  the image is finite, its mean, and for transformed scenes the relMSE against the
  untransformed render together with the bound the tests enforce.
- **Scene fuzzing**: copies of shared scenes (Mitsuba XML, the per-material OBJs, a whole-scene
  OBJ + MTL, a Mitsuba 0.x file) are mutated — byte flips, truncation, tag/line deletion,
  number garbage, huge numbers, entity-expansion and external-entity attempts, deep and wide
  nesting, hostile snippets (``/dev/zero`` as a mesh, NaN transforms, self-includes, …) — and
  loaded with :func:`common.loader.load_scene` in a child process with a time limit and an
  address-space limit. Every load must give a Scene or a :class:`~common.scene.SceneError`
  whose message is one line naming a file. Anything else is a crash; a load past
  ``--timeout`` is a hang (the child is killed and replaced). Loaded scenes are checked for
  consistency (face indices, finite vertices of used triangles, finite and positive material
  and emitter parameters, camera); inconsistent ones are counted as "accepted with problems"
  and rendered at 12×12, as are every ``--render-every``-th other one and every scene with a
  hostile snippet: the render must not raise and its pixels must be finite.

- **Wire fuzzing**: random and mutated protocol messages (byte flips, truncation, garbage and
  missing/extra fields, wrong kinds and versions, msgpack depth and container-size bombs,
  multi-frame) to the bare decoder, to a live master's ROUTER (several peers) and from a fake
  master to a live worker; then an oversize message (MAX_MESSAGE_SIZE + 1 through ZeroMQ, and a
  raw ZMTP frame header announcing 1 TiB) to each. Counts: messages tried, dropped (and their
  log lines), refused, whether each side still renders afterwards (crashes = 0).

- **Hostile cases** (issue 20, ``bench/stress_hostile.py``): rogue workers (silent with huge
  credit, wrong-sized results) against a render and against ``igi serve``'s stream, 5,000 moves
  then a late worker, absurd sizes and cameras through the viewer, a DNS-rebinding-shaped Host,
  scene files reaching outside ``--scene-root``. Each case: pass/fail and a figure.

    igi bench stress [--mutations 2000] [--wire-messages 1000] [--seed 0] [--timeout 20]
                     [--skip-stress] [--skip-fuzz] [--cases NAMES] [-o PREFIX]

``--cases`` picks parts by name (``stress``, ``fuzz``, ``wire``, ``hostile`` or single hostile
cases such as ``scene-root,host-rebinding``); without it everything runs.

Writes ``PREFIX.json`` (default ``artifacts/bench-stress.json``) with counts: cases, finite,
files tried, outcomes, errors by type, crashes, hangs, max load time, max child RSS, messages
tried, dropped, refused; ``hostile``: {cases: [{name, passed, figure, unit, seconds, detail}],
passed, failed}.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .paths import REPO_ROOT, SHARED_SCENES


DEFAULT_OUT = "artifacts/bench-stress"
MEMORY_LIMIT_MB = 3072  # address-space limit of the loading child: a blow-up is a MemoryError, not an OOM
MAX_MUTANT_BYTES = 8 << 20  # mutated files are cut to this size (large files are not the point here)


# ------------------------------------------------------------------------------------ corpus

@dataclass
class Target:
    path: Path  # the file that gets mutated
    kind: str  # "xml", "obj" or "mtl"
    weight: float


@dataclass
class Entry:
    name: str
    scene: Path  # the file load_scene is called on
    targets: list[Target]
    weight: float


def _copy_tree(src: Path, dst: Path, skip=("preview.png",)) -> None:
    """Copy a read-only shared scene into a writable tree (files get the default mode)."""
    for root, dirs, files in os.walk(src):
        rel = Path(root).relative_to(src)
        (dst / rel).mkdir(parents=True, exist_ok=True)
        for f in files:
            if f not in skip:
                shutil.copyfile(Path(root) / f, dst / rel / f)


def make_corpus(dest: Path, shared: Path = SHARED_SCENES) -> list[Entry]:
    """Writable copies of the seed scenes in ``dest`` and what to mutate in each."""
    dest = Path(dest)
    entries: list[Entry] = []

    def copy(name: str) -> Path:
        d = dest / name
        if not (shared / name).is_dir():
            raise FileNotFoundError(f"seed scene {shared / name} not found (the shared scenes)")
        if not d.exists():
            _copy_tree(shared / name, d)
        return d

    d = copy("cornell-box")
    meshes = sorted((d / "meshes").glob("*.obj"))
    entries.append(Entry("cornell-box.xml", d / "scene.xml",
                         [Target(d / "scene.xml", "xml", 3.0)] + [Target(m, "obj", 2.0 / len(meshes)) for m in meshes],
                         4.0))
    entries.append(Entry("cornell-box.obj", d / "CornellBox-Original.obj",
                         [Target(d / "CornellBox-Original.obj", "obj", 1.0),
                          Target(d / "CornellBox-Original.mtl", "mtl", 1.0)], 2.5))
    d = copy("cornell-box-sphere")
    entries.append(Entry("cornell-box-sphere.xml", d / "scene.xml",
                         [Target(d / "scene.xml", "xml", 1.0),
                          Target(d / "meshes" / "rightSphere.obj", "obj", 1.0)]
                         if (d / "meshes" / "rightSphere.obj").exists() else [Target(d / "scene.xml", "xml", 1.0)],
                         1.5))
    d = copy("veach-bidir")
    small = [m for m in sorted((d / "models").glob("*.obj")) if m.stat().st_size < 12_000][:6]
    entries.append(Entry("veach-bidir.xml", d / "scene.xml",
                         [Target(d / "scene.xml", "xml", 2.0)] + [Target(m, "obj", 1.0 / max(1, len(small))) for m in small],
                         1.5))
    if (shared / "modern-hall").exists():
        d = dest / "modern-hall"
        if not d.exists():  # only the XML (Mitsuba 0.x syntax) is mutated: copy it, link the rest
            d.mkdir(parents=True)
            shutil.copyfile(shared / "modern-hall" / "scene.xml", d / "scene.xml")
            for sub in ("models", "textures"):
                if (shared / "modern-hall" / sub).exists():
                    os.symlink(shared / "modern-hall" / sub, d / sub)
        entries.append(Entry("modern-hall.xml", d / "scene.xml", [Target(d / "scene.xml", "xml", 1.0)], 0.5))
    return [e for e in entries if e.scene.exists()]


# ---------------------------------------------------------------------------------- mutators

_NUM = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_TAG = re.compile(rb"<[^<>]{0,400}>")
GARBAGE_NUMBERS = [b"nan", b"NaN", b"-nan", b"inf", b"-inf", b"Infinity", b"1e999", b"-1e999", b"1e-400",
                   b"1.2.3", b"0x1F", b"--5", b"", b"abc", b"+", b"-", b".", b"e5", b"1e", b"9" * 400,
                   b"\x00", b"1,5", b"1_000", b"\xff\xfe", b"  ", b"1/2", b"$x", b"${a}", b"%s%s%n"]
HUGE_NUMBERS = [b"1e308", b"-1e308", b"1.7976931348623157e308", b"3.5e38", b"-3.5e38", b"1e39",
                b"99999999999999999999999999", b"4294967296", b"2147483648", b"-2147483649",
                b"9223372036854775808", b"1e-320", b"4.9e-324", b"65536", b"1000000000", b"0", b"-0",
                b"-1", b"1e-45"]
ODD_PATHS = [b"/dev/zero", b"/dev/null", b"/dev/urandom", b".", b"..", b"/", b"/etc/passwd", b"/proc/self/environ",
             b"../../../../../../../../etc/shadow", b"", b"nonexistent.obj", b"meshes", b"scene.xml",
             b"a" * 5000, b"\x00.obj", b"C:\\\\windows\\\\win.ini", b"file:///etc/passwd", b"http://127.0.0.1:1/x.obj"]

ENTITY_ATTACKS = [
    # billion laughs
    b'<!DOCTYPE scene [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
    b'<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;"><!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">'
    b'<!ENTITY e "&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;"><!ENTITY f "&e;&e;&e;&e;&e;&e;&e;&e;&e;&e;">'
    b'<!ENTITY g "&f;&f;&f;&f;&f;&f;&f;&f;&f;&f;"><!ENTITY h "&g;&g;&g;&g;&g;&g;&g;&g;&g;&g;">]>',
    # external entities
    b'<!DOCTYPE scene [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>',
    b'<!DOCTYPE scene [<!ENTITY xxe SYSTEM "http://127.0.0.1:1/evil">]>',
    b'<!DOCTYPE scene SYSTEM "http://127.0.0.1:1/evil.dtd">',
    # parameter entities
    b'<!DOCTYPE scene [<!ENTITY % p SYSTEM "file:///etc/passwd"> %p;]>',
    b'<!DOCTYPE scene [<!ENTITY % a "x"><!ENTITY % b "%a;%a;%a;%a;">]>',
    # quadratic blow-up (one big entity used many times)
    b'<!DOCTYPE scene [<!ENTITY big "' + b"x" * 100_000 + b'">]>',
    # a DOCTYPE without entities (allowed)
    b'<!DOCTYPE scene [<!ELEMENT scene ANY>]>',
]
ENTITY_REFS = [b"&h;", b"&xxe;", b"&big;" * 2000, b"&undefined;", b"&#0;", b"&#x110000;", b"&lt;&gt;&amp;"]

XML_SNIPPETS = [
    b'<shape type="sphere"><float name="radius" value="1e308"/></shape>',
    b'<shape type="sphere"><point name="center" x="nan" y="0" z="0"/></shape>',
    b'<shape type="sphere"><float name="radius" value="0"/></shape>',
    b'<shape type="rectangle"><transform name="to_world"><scale value="0"/></transform></shape>',
    b'<shape type="rectangle"><transform name="to_world"><matrix value="nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/>'
    b'</transform></shape>',
    b'<shape type="rectangle"><transform name="to_world"><matrix value="1 2 3"/></transform></shape>',
    b'<shape type="rectangle"><transform name="to_world"><rotate x="0" y="0" z="0" angle="90"/></transform></shape>',
    b'<shape type="rectangle"><transform name="to_world"><scale value="1e200"/><scale value="1e200"/></transform>'
    b'</shape>',
    b'<shape type="cube"><emitter type="area"><rgb name="radiance" value="nan, 1, 1"/></emitter></shape>',
    b'<shape type="cube"><emitter type="area"><rgb name="radiance" value="1e39, 1, 1"/></emitter></shape>',
    b'<shape type="obj"><string name="filename" value="/dev/zero"/></shape>',
    b'<shape type="obj"><string name="filename" value="."/></shape>',
    b'<shape type="obj"><string name="filename" value="/etc/passwd"/></shape>',
    b'<shape type="ply"><string name="filename" value="/dev/urandom"/></shape>',
    b'<shape type="ply"><string name="filename" value="scene.xml"/></shape>',
    b'<shape type="obj"><string name="filename" value="scene.xml"/></shape>',
    b'<shape type="obj"/>',
    b'<shape type="teapot"/>',
    b'<emitter type="point"><rgb name="intensity" value="1e39"/><point name="position" x="0" y="1" z="0"/></emitter>',
    b'<emitter type="point"><point name="position" x="inf" y="1" z="0"/></emitter>',
    b'<emitter type="spot"><float name="cutoff_angle" value="-5"/><float name="beam_width" value="400"/></emitter>',
    b'<emitter type="directional"><vector name="direction" x="0" y="0" z="0"/></emitter>',
    b'<emitter type="constant"><rgb name="radiance" value="-1"/></emitter>',
    b'<emitter type="envmap"><string name="filename" value="/dev/zero"/></emitter>',
    b'<emitter type="area"/>',
    b'<include filename="scene.xml"/>',
    b'<include filename="/dev/zero"/>',
    b'<include/>',
    b'<default name="a" value="$a"/><float name="x" value="$a"/>',
    b'<default name="a" value="$b"/><default name="b" value="$a"/><float name="x" value="$a"/>',
    b'<bsdf type="diffuse" id="t"><texture type="bitmap" name="reflectance">'
    b'<string name="filename" value="/dev/zero"/></texture></bsdf><shape type="cube"><ref id="t"/></shape>',
    b'<bsdf type="diffuse" id="t2"><texture type="bitmap" name="reflectance">'
    b'<string name="filename" value="scene.xml"/></texture></bsdf><shape type="cube"><ref id="t2"/></shape>',
    b'<bsdf type="roughplastic" id="rp"><float name="alpha" value="-1"/><float name="int_ior" value="0"/></bsdf>'
    b'<shape type="cube"><ref id="rp"/></shape>',
    b'<bsdf type="dielectric" id="d"><string name="int_ior" value="unobtainium"/></bsdf><shape type="cube"><ref id="d"/></shape>',
    b'<bsdf type="conductor" id="c"><string name="material" value="Xx"/></bsdf><shape type="cube"><ref id="c"/></shape>',
    b'<spectrum name="reflectance" value="400:0.5, 500:nan"/>',
    b'<shape type="cube"><ref id="nonexistent"/></shape>',
    b'<shape type="cube"><ref/></shape>',
    b'<shape type="cube" id="dup"/><shape type="cube" id="dup"/>',
    b'<sensor type="perspective"><float name="fov" value="180"/></sensor>',
    b'<sensor type="perspective"><float name="fov" value="0"/></sensor>',
    b'<sensor type="perspective"><float name="fov" value="nan"/><film type="hdrfilm">'
    b'<integer name="width" value="0"/><integer name="height" value="-5"/></film></sensor>',
    b'<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="99999999999"/></film></sensor>',
    b'<sensor type="perspective"><transform name="to_world"><lookat origin="0,0,0" target="0,0,0" up="0,1,0"/>'
    b'</transform></sensor>',
    b'<sensor type="perspective"><transform name="to_world"><lookat origin="0,0,0" target="0,0,1" up="0,0,1"/>'
    b'</transform></sensor>',
    b'<integrator type="path"><integer name="max_depth" value="99999999999999999999"/></integrator>',
    b'<float/>', b'<rgb name="x"/>', b'<transform/>', b'<matrix value=""/>', b'<scene/>',
]

OBJ_LINES = [
    b"f 0 0 0", b"f -100000 1 2", b"f 1 2 99999999999999999999", b"f 1/1/1 2/2/2 3/3/3", b"f 1//1 2//2 3//3",
    b"f 1 2", b"f 1", b"f", b"f a b c", b"f 1/2/3/4 1 1", b"f -1 -2 -3", b"v 1e39 0 0", b"v nan nan nan",
    b"v inf 0 0", b"v 1 2", b"v", b"vn nan nan nan", b"vn 0 0 0", b"vt inf inf", b"vt 1e308 -1e308",
    b"usemtl", b"usemtl \xff\xfe", b"mtllib /dev/zero", b"mtllib .", b"mtllib ../../../../../../etc/passwd",
    b"mtllib nonexistent.mtl", b"o", b"g", b"s off", b"l 1 2", b"p 1", b"curv 0 1 1 2", b"\x00\x00\x00",
    b"f " + b" ".join(str(i % 7 + 1).encode() for i in range(100_000)),
    b"v " + b" ".join([b"1"] * 100_000),
]
MTL_LINES = [
    b"Kd nan 0 0", b"Ke 1e999 1 1", b"Ke -5 -5 -5", b"Ni 0", b"Ni -1", b"Ni nan", b"Ns 1e30", b"Ns -1",
    b"map_Kd /dev/zero", b"map_Kd .", b"map_Kd ../../../../etc/passwd", b"map_Kd CornellBox-Original.obj",
    b"newmtl", b"illum 99", b"illum -1", b"Tf", b"d nan", b"Kd", b"Kd 1", b"Ks 1 1 1 1 1", b"\x00",
]


def _pick_span(data: bytes, rng: random.Random, pattern: re.Pattern) -> re.Match | None:
    ms = list(pattern.finditer(data, 0, min(len(data), 1 << 20)))
    return rng.choice(ms) if ms else None


def m_byte_flip(data, rng, kind):
    if not data:
        return b"\xff"
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(b))
        b[i] ^= rng.randint(1, 255)
    return bytes(b)


def m_truncate(data, rng, kind):
    return data[:rng.randrange(len(data) + 1)] if data else data


def m_delete_tag(data, rng, kind):
    if kind == "xml":
        m = _pick_span(data, rng, _TAG)
        return data[:m.start()] + data[m.end():] if m else data
    lines = data.split(b"\n")
    del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


def _replace_numbers(data, rng, pool, count):
    ms = list(_NUM.finditer(data, 0, min(len(data), 1 << 20)))
    if not ms:
        return data
    chosen = sorted(rng.sample(ms, min(count, len(ms))), key=lambda m: m.start(), reverse=True)
    for m in chosen:
        data = data[:m.start()] + rng.choice(pool) + data[m.end():]
    return data


def m_number_garbage(data, rng, kind):
    return _replace_numbers(data, rng, GARBAGE_NUMBERS, rng.randint(1, 4))


def m_huge_number(data, rng, kind):
    return _replace_numbers(data, rng, HUGE_NUMBERS, rng.randint(1, 4))


def _after_xml_decl(data: bytes) -> int:
    m = re.match(rb"\s*<\?xml[^>]*\?>", data)
    return m.end() if m else 0


def _before_scene_end(data: bytes) -> int:
    i = data.rfind(b"</scene>")
    return i if i >= 0 else len(data)


def m_entity(data, rng, kind):
    i = _after_xml_decl(data)
    attack = rng.choice(ENTITY_ATTACKS)
    out = data[:i] + b"\n" + attack + b"\n" + data[i:]
    j = _before_scene_end(out)
    ref = rng.choice(ENTITY_REFS)
    return out[:j] + b'<string name="x" value="' + ref + b'"/>' + ref + out[j:]


def m_deep_nesting(data, rng, kind):
    depth = rng.choice([50, 300, 1000, 5000, 100_000])
    tag = rng.choice([b"bsdf", b"shape", b"scene", b"transform", b"x"])
    block = (b"<" + tag + b' type="diffuse">') * depth + (b"</" + tag + b">") * depth
    if kind != "xml":
        return data + b"\n" + b"f " * depth
    j = _before_scene_end(data)
    return data[:j] + block + data[j:]


def m_wide(data, rng, kind):
    n = rng.choice([1000, 20_000])
    if kind == "xml":
        j = _before_scene_end(data)
        block = b"".join(b'<bsdf type="diffuse" id="w%d"/>' % i for i in range(n))
        return data[:j] + block + data[j:]
    line = rng.choice([x for x in (OBJ_LINES if kind == "obj" else MTL_LINES) if len(x) < 200])
    return data + b"\n" + (line + b"\n") * n


def m_snippet(data, rng, kind):
    if kind == "xml":
        j = _before_scene_end(data)
        return data[:j] + rng.choice(XML_SNIPPETS) + data[j:]
    lines = data.split(b"\n")
    pool = OBJ_LINES if kind == "obj" else MTL_LINES
    for _ in range(rng.randint(1, 3)):
        lines.insert(rng.randrange(len(lines) + 1), rng.choice(pool))
    return b"\n".join(lines)


def m_odd_path(data, rng, kind):
    if kind == "xml":
        pat = re.compile(rb'(name="filename"\s+value=")([^"]*)(")')
    else:
        pat = re.compile(rb"^((?:mtllib|map_\w+)\s+)(\S.*?)(\r?)$", re.M)
    ms = list(pat.finditer(data))
    if not ms:
        return m_snippet(data, rng, kind)
    m = rng.choice(ms)
    return data[:m.start(2)] + rng.choice(ODD_PATHS) + data[m.end(2):]


def m_duplicate_chunk(data, rng, kind):
    if not data:
        return data
    i = rng.randrange(len(data))
    j = min(len(data), i + rng.randint(1, 4000))
    at = rng.randrange(len(data))
    return data[:at] + data[i:j] * rng.randint(1, 3) + data[at:]


def m_random_bytes(data, rng, kind):
    n = rng.choice([0, 1, 16, 4096])
    junk = bytes(rng.randrange(256) for _ in range(n))
    return junk if rng.random() < 0.5 else data[:rng.randrange(len(data) + 1)] + junk


def m_encoding(data, rng, kind):
    if kind == "xml":
        decl = rng.choice([b'<?xml version="1.0" encoding="utf-32"?>', b'<?xml version="1.0" encoding="bogus"?>',
                           b'<?xml version="2.0"?>', b"\xef\xbb\xbf", b"\xff\xfe", b'<?xml version="1.0" encoding="utf-16"?>'])
        i = _after_xml_decl(data)
        return decl + data[i:]
    return rng.choice([b"\xef\xbb\xbf", b"\xff\xfe", b""]) + data.replace(b"\n", rng.choice([b"\r", b"\r\n", b"\n\x00"]))


MUTATORS = {
    "byte_flip": m_byte_flip, "truncate": m_truncate, "delete_tag_or_line": m_delete_tag,
    "number_garbage": m_number_garbage, "huge_number": m_huge_number, "entity_expansion": m_entity,
    "deep_nesting": m_deep_nesting, "wide": m_wide, "hostile_snippet": m_snippet, "odd_path": m_odd_path,
    "duplicate_chunk": m_duplicate_chunk, "random_bytes": m_random_bytes, "encoding": m_encoding,
}
MUTATOR_WEIGHTS = {"byte_flip": 3, "truncate": 2, "delete_tag_or_line": 2, "number_garbage": 3, "huge_number": 2,
                   "entity_expansion": 1, "deep_nesting": 0.5, "wide": 0.3, "hostile_snippet": 3, "odd_path": 1,
                   "duplicate_chunk": 1, "random_bytes": 0.5, "encoding": 0.5}
XML_ONLY = {"entity_expansion"}


def plan(entries: list[Entry], n: int, seed: int) -> list[tuple[int, Entry, Target, str]]:
    """The first n mutations of the deterministic sequence for ``seed``: (index, entry, target, mutator)."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        e = rng.choices(entries, weights=[x.weight for x in entries])[0]
        t = rng.choices(e.targets, weights=[x.weight for x in e.targets])[0]
        names = [m for m in MUTATORS if t.kind == "xml" or m not in XML_ONLY]
        m = rng.choices(names, weights=[MUTATOR_WEIGHTS[x] for x in names])[0]
        out.append((i, e, t, m))
    return out


def mutate(data: bytes, kind: str, mutator: str, seed: int, index: int) -> bytes:
    """Mutant ``index`` of the sequence for ``seed`` (deterministic), at most MAX_MUTANT_BYTES."""
    return MUTATORS[mutator](data, random.Random(seed * 1_000_003 + index), kind)[:MAX_MUTANT_BYTES]


# ------------------------------------------------------------------------ the loading child

def scene_problems(scene) -> list[str]:
    """Inconsistencies a loaded Scene must not have (the renderer would index or divide by them)."""
    import numpy as np

    probs = []
    nm = len(scene.materials)
    ne = len(scene.emitters)
    for m in scene.meshes:
        f = np.asarray(m.faces)
        v = np.asarray(m.vertices)
        if f.size and (f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v)):
            probs.append(f"mesh {m.name!r}: face index out of range")
            continue
        if f.size and not np.isfinite(v[f]).all():
            probs.append(f"mesh {m.name!r}: a triangle uses a non-finite vertex")
        for what, arr, width in (("normals", m.normals, 3), ("uvs", m.uvs, 2)):
            if arr is not None and np.shape(arr) != (len(v), width):
                probs.append(f"mesh {m.name!r}: {what} shape {np.shape(arr)} for {len(v)} vertices")
        if not (0 <= m.material < nm):
            probs.append(f"mesh {m.name!r}: material index {m.material} of {nm}")
        if not (-1 <= m.emitter < ne):
            probs.append(f"mesh {m.name!r}: emitter index {m.emitter} of {ne}")
    for e in scene.emitters:
        for what in ("radiance", "intensity", "irradiance", "position", "direction"):
            if not np.isfinite(np.asarray(getattr(e, what), float)).all():
                probs.append(f"emitter {e.name or e.kind}: non-finite {what}")
    for mat in scene.materials:
        vals = [mat.alpha, mat.int_ior, mat.ext_ior, *np.ravel(mat.eta), *np.ravel(mat.k)]
        for tex in (mat.diffuse, mat.specular, mat.specular_transmittance):
            if tex.rgb is not None:
                vals.extend(np.ravel(tex.rgb))
        if not np.isfinite(np.asarray(vals, float)).all():
            probs.append(f"material {mat.name!r}: non-finite parameter")
        elif not (mat.int_ior > 0 and mat.ext_ior > 0 and mat.alpha >= 0):
            probs.append(f"material {mat.name!r}: ior {mat.int_ior:g}/{mat.ext_ior:g}, alpha {mat.alpha:g}")
    cam = scene.camera
    if not np.isfinite(np.asarray(cam.to_world, float)).all():
        probs.append("camera: non-finite to_world")
    if not (np.isfinite(cam.fov) and 0 < cam.fov < 180):
        probs.append(f"camera: fov {cam.fov}")
    if not (int(cam.width) >= 1 and int(cam.height) >= 1):
        probs.append(f"camera: film {cam.width}x{cam.height}")
    return probs


def _render_tiny(scene) -> "tuple[bool, str]":
    import numpy as np

    from igi.master.inprocess import render_local

    # one VPL/photon set (interleave 1): 5-10x cheaper than the default 3x3 sets, same code paths
    img = render_local(scene, {"photons": 50, "indirect_vpls": 8, "interleave": 1}, 1, width=12, height=12)
    ok = bool(np.all(np.isfinite(img)))
    return ok, "" if ok else f"{int(np.count_nonzero(~np.isfinite(img)))} non-finite pixel values"


def _child_main(mem_limit_mb: int | None) -> None:
    """The loading child: one JSON request per stdin line, one JSON answer per line on the
    original stdout (anything the loader prints goes to stderr)."""
    import logging
    import resource

    if mem_limit_mb:
        lim = int(mem_limit_mb) * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    logging.disable(logging.CRITICAL)  # loader warnings are expected here
    import warnings

    warnings.simplefilter("ignore")
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    sys.stdout = sys.stderr
    from igi.common.loader import load_scene
    from igi.common.scene import SceneError

    for line in sys.stdin:
        req = json.loads(line)
        path, render = req["path"], req.get("render", False)
        res: dict = {"stage": "load"}
        t0 = time.perf_counter()
        try:
            scene = load_scene(path)
            res["load_seconds"] = time.perf_counter() - t0
            probs = scene_problems(scene)
            res["outcome"] = "ok"
            if probs:
                # Accepted although inconsistent: recorded, and always rendered (must not crash
                # or give non-finite pixels).
                res["problems"] = probs[:5]
            if render or probs:
                res["stage"] = "render"
                try:
                    ok, why = _render_tiny(scene)
                    res["rendered"] = True
                    if not ok:
                        res["outcome"], res["message"] = "nonfinite_image", why
                except SceneError as e:
                    res["rendered"] = True
                    res["render_error"] = str(e)
        except SceneError as e:
            res["outcome"], res["type"], res["message"] = "scene_error", "SceneError", str(e)
        except BaseException as e:  # noqa: BLE001 - classifying every other exception is the point
            res["outcome"], res["type"] = "crash", type(e).__name__
            res["message"] = str(e)[:500]
            res["traceback"] = "".join(traceback.format_exception(type(e), e, e.__traceback__, limit=-4))[-2000:]
        res.setdefault("load_seconds", time.perf_counter() - t0)
        res["seconds"] = time.perf_counter() - t0
        res["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        answers.write(json.dumps(res, default=str) + "\n")
        answers.flush()


class LoadWorker:
    """A child process that loads scene files; killed and replaced after a hang or a death.

    A plain ``python -c`` subprocess speaking JSON lines (no multiprocessing: the caller's
    ``__main__`` is never re-imported), with an address-space limit."""

    def __init__(self, mem_limit_mb: int | None = MEMORY_LIMIT_MB):
        self.mem_limit_mb = mem_limit_mb
        self.restarts = 0
        self._start()

    def _start(self) -> None:
        import subprocess

        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        code = f"from bench.stress import _child_main; _child_main({self.mem_limit_mb!r})"
        self.proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, env=env, cwd=str(REPO_ROOT), text=True, bufsize=1)

    def _restart(self) -> None:
        self._stop(kill=True)
        self.restarts += 1
        self._start()

    def _stop(self, kill: bool) -> None:
        try:
            if kill:
                self.proc.kill()
            else:
                self.proc.stdin.close()
            self.proc.wait(10)
        except Exception:  # noqa: BLE001
            self.proc.kill()
            self.proc.wait(10)
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except Exception:  # noqa: BLE001
                pass

    def load(self, path: Path, timeout: float, render: bool = False) -> dict:
        import select

        t0 = time.perf_counter()
        try:
            self.proc.stdin.write(json.dumps({"path": str(path), "render": bool(render)}) + "\n")
            self.proc.stdin.flush()
            ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
            if not ready:
                self._restart()
                return {"outcome": "hang", "seconds": time.perf_counter() - t0,
                        "message": f"no answer within {timeout:g} s"}
            line = self.proc.stdout.readline()
            if not line:
                raise EOFError
            return json.loads(line)
        except (EOFError, BrokenPipeError, ConnectionResetError, OSError, ValueError):
            code = self.proc.poll()
            self._restart()
            return {"outcome": "died", "seconds": time.perf_counter() - t0,
                    "message": f"loader process died (exit code {code})"}

    def close(self) -> None:
        self._stop(kill=False)


# ------------------------------------------------------------------------------- the fuzz run

_FILE_RE = re.compile(r"[\w./\\~-]+\.(?:xml|obj|mtl|ply|png|jpe?g|exr|hdr|tga|bmp)\b|/dev/\w+|\(referenced at ",
                      re.IGNORECASE)
FAILURES = ("crash", "hang", "died", "nonfinite_image", "unclear_message")


_PATH_RE = re.compile(r"(?:^|[\s'\"(])[^\s'\"()]*[/\\][^\s'\"()]+|^[^\s:]+:\d+:")


def message_is_clear(msg: str) -> bool:
    """One line, not empty, not huge, and names a file (the scene file, a mesh, a texture…):
    a name with a scene-file extension, a path, or a leading ``file:line:``."""
    msg = (msg or "").strip()
    return (bool(msg) and "\n" not in msg and len(msg) <= 2000
            and bool(_FILE_RE.search(msg) or _PATH_RE.search(msg)))


def _error_kind(msg: str) -> str:
    """A SceneError message without its file names, line numbers and values, for grouping."""
    s = re.sub(r"^\S+?:\d+:\s*", "", msg.strip())  # file:line:
    s = re.sub(r"^[^\s:]+\.(xml|obj|mtl|ply)(?: \([^)]*\))?:\s*", "", s)
    s = _FILE_RE.sub("FILE", s)
    s = re.sub(r"'[^']*'|\"[^\"]*\"", "'…'", s)
    s = re.sub(r"[-+]?\d[\d.eE+-]*", "N", s)
    return s[:90]


def run_fuzz(mutations: int = 2000, seed: int = 0, timeout: float = 20.0, render_every: int = 10,
             workdir: Path | None = None, keep_failures: Path | None = None, progress=None,
             shared: Path = SHARED_SCENES, entries: list[str] | None = None) -> dict:
    """Mutate and load ``mutations`` files; returns the counts (see the module docstring).
    ``entries`` restricts the corpus to those entry names (e.g. ``["cornell-box.xml"]``)."""
    own_tmp = workdir is None
    workdir = Path(tempfile.mkdtemp(prefix="igi-fuzz-")) if own_tmp else Path(workdir)
    try:
        names = entries
        entries = [e for e in make_corpus(workdir, shared) if not names or e.name in names]
        if not entries:
            raise ValueError(f"no corpus entry among {names}")
        worker = LoadWorker()
        outcomes: Counter = Counter()
        by_type: Counter = Counter()
        kinds: Counter = Counter()
        by_mutator: dict = defaultdict(Counter)
        by_kind: dict = defaultdict(Counter)
        failures: list[dict] = []
        load_times: list[float] = []
        max_rss = 0.0
        rendered = 0
        ok_seen = 0
        accepted_bad = 0
        accepted_examples: list[dict] = []
        t_start = time.perf_counter()
        try:
            # the unmutated seeds must load (a broken corpus would make every mutation an error)
            for e in entries:
                r = worker.load(e.scene, timeout)
                if r.get("outcome") != "ok":
                    raise RuntimeError(f"seed scene {e.scene} does not load: {r}")
            for i, entry, target, mname in plan(entries, mutations, seed):
                original = target.path.read_bytes()
                data = mutate(original, target.kind, mname, seed, i)
                target.path.write_bytes(data)
                try:
                    # hostile snippets target the renderer as much as the loader: always rendered
                    render = (render_every > 0 and ok_seen % render_every == 0) or mname == "hostile_snippet"
                    r = worker.load(entry.scene, timeout, render=render)
                finally:
                    target.path.write_bytes(original)
                out = r.get("outcome", "crash")
                if out == "scene_error" and not message_is_clear(r.get("message", "")):
                    out = "unclear_message"
                if out in ("ok", "nonfinite_image") or r.get("stage") == "render":
                    ok_seen += 1
                if r.get("problems"):
                    accepted_bad += 1
                    if len(accepted_examples) < 20:
                        accepted_examples.append({"index": i, "entry": entry.name, "target": target.path.name,
                                                  "mutator": mname, "problems": r["problems"],
                                                  "outcome": out})
                rendered += bool(r.get("rendered"))
                outcomes[out] += 1
                by_mutator[mname][out] += 1
                by_kind[target.kind][out] += 1
                if r.get("type"):
                    by_type[r["type"]] += 1
                if r.get("outcome") == "scene_error":
                    kinds[_error_kind(r.get("message", ""))] += 1
                if "load_seconds" in r:
                    load_times.append(r["load_seconds"])
                elif out == "hang":
                    load_times.append(r["seconds"])
                max_rss = max(max_rss, r.get("rss_mb", 0.0))
                if out in FAILURES:
                    rec = {"index": i, "entry": entry.name, "target": target.path.name, "mutator": mname,
                           "outcome": out, "stage": r.get("stage"), "type": r.get("type"),
                           "message": r.get("message", "")[:300], "problems": r.get("problems"),
                           "traceback": r.get("traceback", "")[-1200:]}
                    failures.append(rec)
                    if keep_failures is not None:
                        kd = Path(keep_failures)
                        kd.mkdir(parents=True, exist_ok=True)
                        (kd / f"{i:06d}-{mname}-{target.path.name}").write_bytes(data)
                if progress is not None:
                    progress(i + 1, mutations, outcomes)
        finally:
            worker.close()
        total = sum(outcomes.values())
        return {
            "files_tried": total,
            "seed": seed,
            "timeout_s": timeout,
            "memory_limit_mb": MEMORY_LIMIT_MB,
            "corpus": [{"entry": e.name, "targets": [t.path.name for t in e.targets]} for e in entries],
            "outcomes": dict(outcomes),
            "errors_by_type": dict(by_type),
            "scene_error_kinds": dict(kinds.most_common(25)),
            "by_mutator": {k: dict(v) for k, v in sorted(by_mutator.items())},
            "by_file_kind": {k: dict(v) for k, v in sorted(by_kind.items())},
            "crashes": outcomes["crash"] + outcomes["died"],
            "hangs": outcomes["hang"],
            "accepted_with_problems": accepted_bad,
            "accepted_examples": accepted_examples,
            "nonfinite_images": outcomes["nonfinite_image"],
            "unclear_messages": outcomes["unclear_message"],
            "rendered": rendered,
            "max_load_seconds": max(load_times) if load_times else 0.0,
            "mean_load_seconds": sum(load_times) / len(load_times) if load_times else 0.0,
            "max_child_rss_mb": max_rss,
            "loader_restarts": worker.restarts,
            "seconds": time.perf_counter() - t_start,
            "failures": failures[:50],
        }
    finally:
        if own_tmp:
            shutil.rmtree(workdir, ignore_errors=True)


# ---------------------------------------------------------------------------- stress scenes

def run_stress(width: int = 48, height: int = 48, names: list[str] | None = None, progress=None) -> dict:
    """Render every stress case (or ``names``); finite images, relMSE against the references."""
    import numpy as np

    from igi.common.metrics import relmse

    from . import stress_scenes as ss
    refs: dict = {}
    results = []
    tmp = Path(tempfile.mkdtemp(prefix="igi-stress-"))
    try:
        for case in ss.CASES:
            if names and case.name not in names:
                continue
            t0 = time.perf_counter()
            rec = {"name": case.name, "base": case.base, "frames": case.frames}
            try:
                scene = case.build(tmp / case.name)
                img = ss.render(scene, case.frames, case.params, width=width, height=height)
                rec["finite"] = bool(np.all(np.isfinite(img)))
                rec["mean"] = float(np.nanmean(img))
                rec["max"] = float(np.nanmax(img))
                rec["warnings"] = len(scene.warnings)
                if case.expect_black:
                    rec["black"] = not bool(img.any())
                if case.reference:
                    key = (case.reference, case.frames)
                    if key not in refs:
                        refs[key] = ss.render(ss.load_shared(case.reference), case.frames, width=width, height=height)
                    ref = refs[key]
                    rec["relmse"] = relmse(img, ref)
                    rec["bound"] = case.bound
                    rec["mean_rel_diff"] = abs(float(img.mean()) - float(ref.mean())) / max(float(ref.mean()), 1e-12)
                    rec["within_bound"] = rec["relmse"] <= case.bound
            except Exception as e:  # noqa: BLE001 - a failing case is recorded, the run goes on
                rec["finite"] = False
                rec["error"] = f"{type(e).__name__}: {e}"
            rec["seconds"] = time.perf_counter() - t0
            results.append(rec)
            if progress is not None:
                progress(rec)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    bad = [r["name"] for r in results
           if not r.get("finite") or r.get("within_bound") is False or r.get("black") is False]
    return {"cases": len(results), "finite": sum(bool(r.get("finite")) for r in results),
            "within_bound": sum(bool(r.get("within_bound")) for r in results if "bound" in r),
            "compared": sum("bound" in r for r in results), "failed": bad,
            "max_relmse": max((r["relmse"] for r in results if "relmse" in r), default=None),
            "width": width, "height": height, "results": results}


# ----------------------------------------------------------------------------- wire fuzzing

def _fuzz_scene(width: int = 24, height: int = 18):
    from .stress_scenes import mini_cornell

    return mini_cornell(width, height)


def wire_templates(direction: str, scene_blob: bytes | None = None) -> list[bytes]:
    """Valid frames of every message kind a peer sends in ``direction`` ("to_master" or
    "to_worker"); the mutants are derived from them."""
    from igi.common import protocol as P
    from igi.common.params import make_params, params_to_dict

    h = "ab" * 32
    if direction == "to_master":
        return [
            P.encode(P.HELLO, {"name": "fz", "host": "h", "pid": 1, "threads": 2, "credit": 6, "scenes": [h],
                               "renderer": "igi", "cores": 2}),
            P.encode(P.RESULT, {"frame": 0, "task": 3, "epoch": 7, "count": 4, "data": b"\x00" * 64,
                                "timings": {"render": 0.5}, "sets": [[0, 1]], "rays": 99}),
            P.encode(P.HEARTBEAT, {"queued": 2}),
            P.encode(P.ERROR, {"code": "task_failed", "message": "x", "frame": 0, "task": 1, "epoch": 2}),
            P.encode(P.BYE, {"reason": "fuzz"}),
            P.encode(P.HEARTBEAT, {}),
        ]
    blob = scene_blob if scene_blob is not None else b"IGSC" + os.urandom(64)
    return [
        P.encode(P.WELCOME, {"worker": "w", "heartbeat": 1.0, "liveness": 1000}),
        P.encode(P.SCENE, {"hash": h, "blob": None, "base_version": 0, "edits": []}),
        P.encode(P.SCENE, {"hash": h, "blob": blob, "base_version": 0, "edits": []}),
        P.encode(P.EDIT, {"hash": h, "version": 1, "edit": {"op": "set_material", "material": 0,
                                                              "param": "diffuse", "value": 0.5}}),
        P.encode(P.FRAME, {"frame": 5, "hash": h, "scene_version": 0, "seed": 1, "camera": [0.0] * 16,
                           "fov_x": 40.0, "width": 8, "height": 8, "params": params_to_dict(make_params()),
                           "jitter": [0.5, 0.5]}),
        P.encode(P.TASK, {"frame": 5, "task": 0, "epoch": 1, "k": 0, "tile": [0, 0, 3, 3]}),
        P.encode(P.HEARTBEAT, {}),
        P.encode(P.ERROR, {"code": "x", "message": "y"}),
    ]


_WIRE_GARBAGE = [None, True, -1, 0, 2**31, 2**53, 2**64 - 1, -(2**63), 1e308, float("nan"), float("inf"), -0.0,
                 "", "x" * 300, "\u0000", b"", b"\xff" * 70, [], [[[[[]]]]], {}, {"a": 1},
                 [1.0] * 17, [0, 0, 0, 0], [5, 5, 1, 1], {"op": "transform_mesh", "mesh": 10**9, "matrix": [1] * 16}]


def wire_mutant(templates: list[bytes], seed: int, index: int) -> tuple[str, list[bytes]]:
    """Mutant ``index`` for ``seed``: (mutator name, frames of one ZeroMQ message)."""
    import msgpack

    rng = random.Random(seed * 7_000_003 + index)
    base = rng.choice(templates)
    op = rng.choices(["byte_flip", "truncate", "random_bytes", "field_garbage", "field_extra", "field_missing",
                      "kind", "version", "shape", "deep", "container_bomb", "multipart", "valid"],
                     weights=[4, 2, 2, 5, 1, 1, 1, 1, 1, 0.5, 0.5, 0.5, 1])[0]
    if op == "byte_flip":
        return op, [m_byte_flip(base, rng, "wire")]
    if op == "truncate":
        return op, [base[:rng.randrange(len(base))]]
    if op == "random_bytes":
        return op, [bytes(rng.randrange(256) for _ in range(rng.choice([0, 1, 3, 40, 1000])))]
    if op == "multipart":
        return op, [base, base[:5]]
    if op == "deep":  # nested arrays deeper than any unpacker stack
        d = rng.choice([100, 2000, 100_000])
        return op, [b"\x93\x01\xa4TASK" + b"\x91" * d + b"\xc0"]
    if op == "container_bomb":  # headers announcing 2^32-1 entries / bytes, no payload
        return op, [rng.choice([b"\xdd\xff\xff\xff\xff", b"\xdf\xff\xff\xff\xff", b"\xc6\xff\xff\xff\xff",
                                b"\x93\x01\xa4TASK\xdf\xff\xff\xff\xff", b"\xdb\xff\xff\xff\xff" + b"a" * 10])]
    version, kind, body = msgpack.unpackb(base, raw=False)
    if op == "field_garbage" and body:
        body[rng.choice(list(body))] = rng.choice(_WIRE_GARBAGE)
    elif op == "field_extra":
        body[rng.choice(["extra", "x" * 100, "", "blob"])] = rng.choice(_WIRE_GARBAGE)
    elif op == "field_missing" and body:
        del body[rng.choice(list(body))]
    elif op == "kind":
        kind = rng.choice(["HELLO", "RESULT", "TASK", "FRAME", "SCENE", "WELCOME", "EDIT", "NOPE", "", "hello",
                           "x" * 1000, 5, None])
    elif op == "version":
        version = rng.choice([0, 2, -1, 2**64 - 1, "1", None, 1.0, True])
    elif op == "shape":
        return op, [msgpack.packb(rng.choice([[version, kind], [version, kind, body, 1], {"v": version},
                                              [version, kind, [body]], "text", 1, None]), use_bin_type=True)]
    return op, [msgpack.packb([version, kind, body], use_bin_type=True)]


def expected_rejection(frames: list[bytes], max_size: int) -> str | None:
    """How the receiving side must treat the message: None (valid), "drop" or "refuse"."""
    from igi.common import protocol as P

    if len(frames) != 1:
        return "drop"
    try:
        P.decode(frames[0], max_size=max_size)
    except P.VersionMismatch:
        return "refuse"
    except P.ProtocolError:
        return "drop"
    return None


class _CountLog:
    """Counts WARNING+ records of a logger whose message contains ``needle``."""

    def __init__(self, name: str, needle: str):
        import logging

        self.logger = logging.getLogger(name)
        self.needle = needle
        self.count = 0
        self.total = 0
        self.handler = logging.Handler(logging.WARNING)
        self.handler.emit = self._emit
        self._old_level = self.logger.level

    def _emit(self, record) -> None:
        self.total += 1
        if self.needle in record.getMessage():
            self.count += 1

    def __enter__(self):
        import logging

        self.logger.addHandler(self.handler)
        if self.logger.getEffectiveLevel() > logging.WARNING:
            self.logger.setLevel(logging.WARNING)
        return self

    def __exit__(self, *exc) -> None:
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self._old_level)


def _zmtp_greeting(as_server: bool) -> bytes:
    return b"\xff" + b"\x00" * 8 + b"\x7f" + b"\x03\x00" + b"NULL".ljust(20, b"\x00") + bytes([as_server]) + b"\x00" * 31


def _zmtp_ready(socket_type: bytes) -> bytes:
    import struct

    def prop(n: bytes, v: bytes) -> bytes:
        return bytes([len(n)]) + n + struct.pack(">I", len(v)) + v

    body = b"\x05READY" + prop(b"Socket-Type", socket_type) + prop(b"Identity", b"")
    return bytes([0x04, len(body)]) + body


def _recv_exact(s, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise ConnectionError("closed")
        out += chunk
    return out


def zmtp_oversize_refused(s, as_server: bool, socket_type: bytes, size: int = 1 << 40, wait: float = 10.0) -> bool:
    """Over a connected TCP socket ``s``: ZMTP 3 handshake (NULL security), then a message frame
    header announcing ``size`` bytes. True when the peer closes the connection at once (the
    size is refused before anything is allocated or read)."""
    import struct

    s.settimeout(wait)
    s.sendall(_zmtp_greeting(as_server))
    _recv_exact(s, 64)
    s.sendall(_zmtp_ready(socket_type))
    flags, n = _recv_exact(s, 2)
    _recv_exact(s, n if not flags & 0x02 else struct.unpack(">Q", bytes([n]) + _recv_exact(s, 7))[0])
    s.sendall(bytes([0x02]) + struct.pack(">Q", size) + b"\x00" * 64)
    try:
        while True:  # the peer may have queued messages of its own (a worker's HELLO): skip them
            if s.recv(65536) == b"":
                return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except OSError:  # timeout: the peer kept the connection open, waiting for 1 TiB
        return False


def fuzz_master(messages: int = 500, seed: int = 0, oversize: bool = True) -> dict:
    """Random and mutated messages to a live Broker's ROUTER from several peers; then the
    broker must still render a frame with a real worker. Counts per expected treatment."""
    import socket as pysocket
    import threading

    import zmq

    from igi.common import protocol as P
    from igi.master.broker import Broker
    from igi.worker.node import WorkerNode

    ctx = zmq.Context()
    broker = Broker(_fuzz_scene(), bind="tcp://127.0.0.1:*", heartbeat=0.5, context=ctx).start()
    templates = wire_templates("to_master")
    expect: Counter = Counter()
    ops: Counter = Counter()
    res: dict = {"messages_tried": 0}
    t0 = time.perf_counter()
    try:
        with _CountLog("igi.master", "dropped message from") as drops, \
                _CountLog("igi.master", "refused peer") as refusals:
            before = broker.stats()
            peers = []
            for i in range(messages):
                if i % 50 == 0:
                    p = ctx.socket(zmq.DEALER)
                    p.setsockopt(zmq.LINGER, 0)
                    p.connect(broker.endpoint)
                    peers.append(p)
                op, frames = wire_mutant(templates, seed, i)
                ops[op] += 1
                expect[expected_rejection(frames, P.MAX_MESSAGE_SIZE) or "valid"] += 1
                peers[-1].send_multipart(frames)
            res["messages_tried"] = messages

            def settled():
                st = broker.stats()
                return (st["messages_dropped"] - before["messages_dropped"] >= expect["drop"]
                        and st["refused"] - before["refused"] >= expect["refuse"])

            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not settled():
                time.sleep(0.05)
            time.sleep(0.3)  # let the valid-but-misplaced ones be logged as well
            after = broker.stats()
            res.update({
                "expected": dict(expect), "mutators": dict(ops),
                "dropped": after["messages_dropped"] - before["messages_dropped"],
                "refused": after["refused"] - before["refused"],
                "drop_log_lines": drops.count, "refusal_log_lines": refusals.count,
                "warning_log_lines": drops.total,
            })
            for p in peers:
                p.close(0)
        if oversize:
            # over the limit by one byte through ZeroMQ itself, then a raw 1 TiB header
            p = ctx.socket(zmq.DEALER)
            p.setsockopt(zmq.LINGER, 0)
            p.connect(broker.endpoint)
            st = broker.stats()
            p.send(b"\x00" * (P.MAX_MESSAGE_SIZE + 1))
            time.sleep(1.0)
            p.close(0)
            res["oversize_delivered"] = broker.stats()["messages_dropped"] != st["messages_dropped"]
            host, port = broker.endpoint.rsplit("/", 1)[-1].rsplit(":", 1)
            with pysocket.create_connection((host, int(port)), timeout=10) as s:
                res["oversize_header_refused"] = zmtp_oversize_refused(s, False, b"DEALER")
        # still alive: a real worker joins and a frame renders
        wctx = zmq.Context()
        node = WorkerNode(broker.endpoint, threads=1, heartbeat=0.5, context=wctx)
        th = threading.Thread(target=node.run, daemon=True)
        th.start()
        try:
            fr = broker.render_frame(broker.frame_spec(0, {}), timeout=120)
            res["serves_after"] = fr.tasks > 0 and bool(np.isfinite(fr.image()).all())
        except Exception as e:  # noqa: BLE001
            res["serves_after"] = False
            res["serves_after_error"] = f"{type(e).__name__}: {e}"
        finally:
            node.stop()
            th.join(15)
            wctx.term()
        res["crashes"] = int(not res["serves_after"])
    finally:
        broker.stop()
        ctx.term()
    res["seconds"] = time.perf_counter() - t0
    return res


def fuzz_worker(messages: int = 500, seed: int = 0, oversize: bool = True) -> dict:
    """Random and mutated messages from a fake master (ROUTER) to a live WorkerNode; then the
    worker must still render a task. Mutants the worker must obey by design — a well-formed
    REFUSE, BYE or WELCOME, or another protocol version (it then refuses and exits) — are
    skipped; no scene is valid during the fuzz, so no mutant can make it render."""
    import socket as pysocket
    import threading

    import zmq

    from igi.common import protocol as P
    from igi.common.scene_codec import encode_scene, scene_hash
    from igi.worker.node import WorkerNode

    scene = _fuzz_scene()
    blob = encode_scene(scene)
    h = scene_hash(blob)
    ctx = zmq.Context()
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    port = router.bind_to_random_port("tcp://127.0.0.1")
    wctx = zmq.Context()
    node = WorkerNode(f"tcp://127.0.0.1:{port}", threads=1, heartbeat=0.5, max_backoff=1.0, context=wctx)
    th = threading.Thread(target=node.run, daemon=True)
    state = {"ident": None, "hellos": 0}
    welcome = P.encode(P.WELCOME, {"worker": "w", "heartbeat": 1.0, "liveness": 1000})

    def pump(timeout_ms: int = 0):
        """Receive everything pending; answer HELLO with WELCOME; return the other messages."""
        out = []
        while router.poll(timeout_ms):
            ident, frame = router.recv_multipart()
            timeout_ms = 0
            m = P.decode(frame)
            if m.kind == P.HELLO:
                state["ident"], state["hellos"] = ident, state["hellos"] + 1
                router.send_multipart([ident, welcome])
            else:
                out.append(m)
        return out

    res: dict = {"messages_tried": 0}
    expect: Counter = Counter()
    ops: Counter = Counter()
    t0 = time.perf_counter()
    try:
        with _CountLog("igi.worker", "dropped") as drops:
            th.start()
            deadline = time.monotonic() + 30
            while state["ident"] is None and time.monotonic() < deadline:
                pump(100)
            if state["ident"] is None:
                raise RuntimeError("the worker never said HELLO")
            templates = wire_templates("to_worker")
            sent = 0
            for i in range(messages):
                op, frames = wire_mutant(templates, seed, i)
                how = expected_rejection(frames, P.MAX_SCENE_MESSAGE_SIZE)
                if how is None:
                    kind = P.decode(frames[0], max_size=P.MAX_SCENE_MESSAGE_SIZE).kind
                    if kind in (P.REFUSE, P.BYE, P.WELCOME):
                        expect["skipped_by_design"] += 1
                        continue
                    how = "drop" if kind in (P.HELLO, P.RESULT) else "valid"
                elif how == "refuse":
                    expect["skipped_by_design"] += 1
                    continue
                if len(frames) != 1:
                    how = "multipart"  # the worker's DEALER takes the first frame; see below
                expect[how] += 1
                ops[op] += 1
                router.send_multipart([state["ident"]] + frames)
                sent += 1
                if i % 20 == 0:
                    pump()
            res["messages_tried"] = sent
            # wait for the worker to have taken every dropped message (its own count: the log
            # lines are rate-limited, a handful for hundreds of drops)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and node._rl.counts["dropped"] < expect["drop"]:
                pump(50)
            pump(300)
            res.update({"expected": dict(expect), "mutators": dict(ops), "drop_log_lines": drops.count,
                        "dropped_counted": node._rl.counts["dropped"], "warning_log_lines": drops.total, "reconnects": state["hellos"] - 1,
                        "alive": th.is_alive()})
        if oversize:
            # a fake master on a raw socket: the worker must close the connection when a frame
            # header announces 1 TiB (its limit is MAX_SCENE_MESSAGE_SIZE), then reconnect
            lst = pysocket.create_server(("127.0.0.1", 0))
            rctx = zmq.Context()
            raw_node = WorkerNode(f"tcp://127.0.0.1:{lst.getsockname()[1]}", threads=1, heartbeat=0.5,
                                  context=rctx)
            rth = threading.Thread(target=raw_node.run, daemon=True)
            rth.start()
            lst.settimeout(20)
            try:
                conn, _ = lst.accept()
                with conn:
                    res["oversize_header_refused"] = zmtp_oversize_refused(conn, True, b"ROUTER")
                conn2, _ = lst.accept()  # ZeroMQ reconnects by itself: the worker is fine
                conn2.close()
                res["reconnected_after_oversize"] = True
            except OSError as e:
                res.setdefault("oversize_header_refused", False)
                res["reconnected_after_oversize"] = False
                res["oversize_error"] = str(e)
            finally:
                raw_node.stop()
                rth.join(15)
                lst.close()
                rctx.term()
        # still alive: a valid scene, frame and task give a RESULT
        from igi.common.frame import FrameSpec
        from igi.common.params import make_params, params_to_dict

        cam = scene.camera
        spec = FrameSpec(frame=10**6, seed=0, camera_to_world=tuple(float(x) for x in cam.to_world.ravel()),
                         fov_x=cam.fov_x, width=24, height=18, params=params_to_dict(make_params()))
        ident = state["ident"]
        router.send_multipart([ident, P.encode(P.SCENE, {"hash": h, "blob": blob, "base_version": 0, "edits": []},
                                               check=False)])
        router.send_multipart([ident, P.encode(P.FRAME, P.frame_body(spec, h))])
        router.send_multipart([ident, P.encode(P.TASK, {"frame": spec.frame, "task": 0, "epoch": 1, "k": 0,
                                                         "tile": [0, 0, 8, 6]})])
        got = None
        deadline = time.monotonic() + 120
        seen: Counter = Counter()
        while got is None and time.monotonic() < deadline:
            for m in pump(200):
                seen[f"{m.kind}:{m.body.get('code', '')}"] += 1
                if m.kind in (P.RESULT, P.ERROR) and m.body.get("frame") == spec.frame:
                    got = m
        res["validation_messages"] = dict(seen)
        res["serves_after"] = got is not None and got.kind == P.RESULT
        res["worker_tasks_done"] = node.tasks_done
        res["worker_state"] = {"heartbeat": node.heartbeat, "liveness": node.liveness, "session": node._session}
        if got is not None and got.kind == P.ERROR:
            res["serves_after_error"] = got.body["message"]
        res["crashes"] = int(not (res["serves_after"] and res.get("alive", False)))
    finally:
        node.stop()
        th.join(15)
        router.close(0)
        ctx.term()
        wctx.term()
    res["seconds"] = time.perf_counter() - t0
    return res


def fuzz_decode(messages: int = 20000, seed: int = 0) -> dict:
    """The pure decoder on many mutants: a Message or a ProtocolError, never anything else."""
    from igi.common import protocol as P

    out: Counter = Counter()
    examples = []
    t0 = time.perf_counter()
    tpl = wire_templates("to_master") + wire_templates("to_worker")
    for i in range(messages):
        _, frames = wire_mutant(tpl, seed, i)
        try:
            P.decode(frames[0], max_size=P.MAX_SCENE_MESSAGE_SIZE)
            out["message"] += 1
        except P.VersionMismatch:
            out["version_mismatch"] += 1
        except P.ProtocolError:
            out["protocol_error"] += 1
        except Exception as e:  # noqa: BLE001
            out["crash"] += 1
            if len(examples) < 10:
                examples.append({"index": i, "type": type(e).__name__, "message": str(e)[:200]})
    return {"messages_tried": messages, "outcomes": dict(out), "crashes": out["crash"], "crash_examples": examples,
            "seconds": time.perf_counter() - t0}


def run_wire_fuzz(messages: int = 1000, seed: int = 0) -> dict:
    return {"decode": fuzz_decode(messages * 20, seed), "master": fuzz_master(messages, seed),
            "worker": fuzz_worker(messages, seed)}


# -------------------------------------------------------------------------------------- CLI

HOSTILE_CASES = ("rogue-silent", "rogue-wrong", "serve-rogue", "moves-5000", "viewer-validation",
                 "host-rebinding", "scene-root")  # bench/stress_hostile.py


def select_cases(spec: str | None) -> tuple[set[str], list[str]]:
    """``--cases`` -> (parts to run among stress/fuzz/wire, hostile case names in order); None =
    everything. UsageError for an unknown name."""
    from igi.master.errors import UsageError

    if spec is None:
        return {"stress", "fuzz", "wire"}, list(HOSTILE_CASES)
    parts, hostile = set(), []
    for name in (n.strip() for n in spec.split(",") if n.strip()):
        if name in ("stress", "fuzz", "wire"):
            parts.add(name)
        elif name == "hostile":
            hostile += [c for c in HOSTILE_CASES if c not in hostile]
        elif name in HOSTILE_CASES:
            if name not in hostile:
                hostile.append(name)
        else:
            raise UsageError(f"--cases: unknown case '{name}' (known: stress, fuzz, wire, hostile, "
                             + ", ".join(HOSTILE_CASES) + ")")
    if not parts and not hostile:
        raise UsageError("--cases: name at least one case")
    return parts, hostile


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mutations", type=int, default=2000, help="mutated scene files to load (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the mutation sequence (default 0)")
    p.add_argument("--timeout", type=float, default=20.0, help="seconds before a load counts as a hang (default 20)")
    p.add_argument("--render-every", type=int, default=10,
                   help="render every N-th successfully loaded mutant at 12x12 (0: never; default 10)")
    p.add_argument("--size", default="48x48", help="stress-scene render size WxH (default 48x48)")
    p.add_argument("--skip-stress", action="store_true", help="fuzzing only")
    p.add_argument("--skip-fuzz", action="store_true", help="no scene-file fuzzing")
    p.add_argument("--wire-messages", type=int, default=1000,
                   help="mutated messages to the master and to a worker (x20 to the bare decoder; 0: none)")
    p.add_argument("--keep-failures", default=None, help="directory to write every failing mutant into")
    p.add_argument("--cases", default=None, metavar="NAMES",
                   help="run only these comma-separated cases (no stress scenes, fuzzing or wire fuzzing "
                        "unless named: stress, fuzz, wire); issue 20's hostile cases: "
                        "hostile (all of them), " + ", ".join(HOSTILE_CASES))
    p.add_argument("-o", "--out", default=DEFAULT_OUT, help=f"output prefix: writes PREFIX.json (default {DEFAULT_OUT})")


def run(args: argparse.Namespace) -> int:
    from igi.master.errors import UsageError
    from .report import machine_info

    try:
        w, _, h = args.size.lower().partition("x")
        width, height = int(w), int(h)
    except ValueError:
        raise UsageError("--size is WxH") from None
    if args.mutations < 0 or width < 1 or height < 1 or args.timeout <= 0:
        raise UsageError("--mutations >= 0, --size >= 1x1 and --timeout > 0 are required")
    parts, hostile = select_cases(getattr(args, "cases", None))
    if (parts & {"stress", "fuzz"}) and not SHARED_SCENES.exists():
        raise UsageError(f"the shared scenes are needed: {SHARED_SCENES} not found")
    t0 = time.perf_counter()
    result = {"benchmark": "stress", "machine": machine_info(),
              "settings": {"mutations": args.mutations, "seed": args.seed, "timeout_s": args.timeout,
                           "render_every": args.render_every, "size": f"{width}x{height}",
                           "cases": sorted(parts) + hostile}}
    if not args.skip_stress and "stress" in parts:
        def show(rec):
            extra = f", relMSE {rec['relmse']:.2e} (bound {rec['bound']:g})" if "relmse" in rec else ""
            print(f"  {rec['name']}: {'finite' if rec.get('finite') else 'NOT FINITE'}{extra}"
                  f"{' ' + rec['error'] if 'error' in rec else ''}", file=sys.stderr, flush=True)

        print("igi bench stress: stress scenes …", file=sys.stderr, flush=True)
        result["stress"] = run_stress(width, height, progress=show)
    if not args.skip_fuzz and "fuzz" in parts:
        print(f"igi bench stress: fuzzing {args.mutations} scene files …", file=sys.stderr, flush=True)
        step = max(1, args.mutations // 20)

        def tick(i, n, outcomes):
            if i % step == 0 or i == n:
                print(f"  {i}/{n} {dict(outcomes)}", file=sys.stderr, flush=True)

        result["fuzz"] = run_fuzz(args.mutations, args.seed, args.timeout, args.render_every,
                                  keep_failures=Path(args.keep_failures) if args.keep_failures else None,
                                  progress=tick)
    if args.wire_messages > 0 and "wire" in parts:
        import logging

        print(f"igi bench stress: wire fuzzing, {args.wire_messages} messages per side …", file=sys.stderr, flush=True)
        quiet = [logging.getLogger(n) for n in ("igi.master", "igi.worker")]
        null = logging.NullHandler()
        for lg in quiet:  # one warning per dropped message is the behaviour under test, not output
            lg.propagate = False
            lg.addHandler(null)
        try:
            wire = run_wire_fuzz(args.wire_messages, args.seed)
        finally:
            for lg in quiet:
                lg.propagate = True
                lg.removeHandler(null)
        wire["crashes"] = sum(int(wire[k].get("crashes", 0)) for k in ("decode", "master", "worker"))
        wire["messages_tried"] = sum(int(wire[k]["messages_tried"]) for k in ("decode", "master", "worker"))
        result["wire"] = wire
    if hostile:
        from .stress_hostile import run_hostile

        def shown(rec):
            print(f"  {rec['name']}: {'pass' if rec['passed'] else 'FAIL'}, {rec['unit']} {rec['figure']} "
                  f"({rec['seconds']:.1f} s){' ' + rec['detail']['error'] if 'error' in rec['detail'] else ''}",
                  file=sys.stderr, flush=True)

        print(f"igi bench stress: hostile cases (issue 20): {', '.join(hostile)} …", file=sys.stderr, flush=True)
        result["hostile"] = run_hostile(hostile, progress=shown)
    result["seconds"] = time.perf_counter() - t0
    out = Path(args.out if args.out.endswith(".json") else args.out + ".json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    f = result.get("fuzz", {})
    s = result.get("stress", {})
    if s or f:
        print(f"igi bench stress: stress {s.get('finite', '-')}/{s.get('cases', '-')} finite, "
              f"{s.get('within_bound', '-')}/{s.get('compared', '-')} within bound; fuzz {f.get('files_tried', '-')} files, "
              f"crashes {f.get('crashes', '-')}, hangs {f.get('hangs', '-')}, accepted with problems "
              f"{f.get('accepted_with_problems', '-')}, "
              f"max load {f.get('max_load_seconds', 0):.2f} s -> {out}", file=sys.stderr)
    wr = result.get("wire", {})
    if wr:
        print(f"igi bench stress: wire {wr['messages_tried']} messages, crashes {wr['crashes']}", file=sys.stderr)
    hs = result.get("hostile", {})
    if hs:
        print(f"igi bench stress: hostile {hs['passed']}/{len(hs['cases'])} passed"
              + (f" (failed: {', '.join(c['name'] for c in hs['cases'] if not c['passed'])})" if hs["failed"] else ""),
              file=sys.stderr)
    failed = bool(s.get("failed")) or bool(wr.get("crashes")) or bool(hs.get("failed")) or any(
        f.get(k) for k in ("crashes", "hangs", "nonfinite_images", "unclear_messages"))
    return 1 if failed else 0
