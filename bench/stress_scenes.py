"""Stress scenes for numerical stability (issue 8), derived from the shared benchmark scenes.

Every builder takes a loaded :class:`common.scene.Scene` and returns a modified deep copy; the
input is never mutated (``common.bsdf`` caches material tables by object identity, so edited
materials are always new objects). File-level cases write modified copies of the scene files
into a directory the caller gives (a pytest ``tmp_path``, or a temporary directory of
``igi bench stress``) and load them through :func:`common.loader.load_scene`.

:data:`CASES` lists every stress case as a :class:`StressCase`; ``build(tmp)`` returns the
scene to render and, for the cases that must reproduce an untransformed image, ``reference``
names the base scene and ``bound`` the largest allowed relMSE against it (the reasoning for
each bound is in ``why``). ``tests/worker/test_stress.py`` and ``bench/stress.py`` both run
this list.
"""
from __future__ import annotations

import copy
import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from igi.common.scene import (AREA, CONSTANT, DIELECTRIC, DIFFUSE, PLASTIC, POINT, ROUGHDIELECTRIC, ROUGHPLASTIC,
                          SPOT, THINDIELECTRIC, Emitter, Material, Scene, Texture)

from .paths import SHARED_SCENES



# ---------------------------------------------------------------------------------------- loading

_CACHE: dict[str, Scene] = {}


def scene_path(name: str) -> Path:
    return SHARED_SCENES / name / "scene.xml"


def load_shared(name: str) -> Scene:
    """A shared scene (loaded once per process; callers get a deep copy)."""
    from igi.common.loader import load_scene

    if name not in _CACHE:
        _CACHE[name] = load_scene(scene_path(name))
    return copy.deepcopy(_CACHE[name])


def _copy(scene: Scene, tag: str) -> Scene:
    out = copy.deepcopy(scene)
    out.source = f"{scene.source or 'scene'} [{tag}]"
    out.warnings = list(scene.warnings)
    return out


def _replace_materials(scene: Scene, fn: Callable[[Material], Material | None]) -> Scene:
    """Replace materials by ``fn(material)`` (None keeps it); new objects, never in place."""
    for i, m in enumerate(scene.materials):
        new = fn(m)
        if new is not None:
            scene.materials[i] = new
    return scene


# ------------------------------------------------------------------------ similarity transforms

def transformed(scene: Scene, scale: float = 1.0, offset=(0.0, 0.0, 0.0)) -> Scene:
    """The scene under x -> scale * x + offset, camera included, so the image stays the same.

    Radiance (area, constant) and irradiance (directional) are invariant under a similarity
    transform; point/spot intensities scale by scale² (the irradiance I/d² must not change).
    The camera keeps its orientation (camera_rays normalizes directions), its origin moves
    with the scene; the near clip scales.
    """
    s = float(scale)
    off = np.asarray(offset, np.float64)
    out = _copy(scene, f"scale {s:g}, offset {off.tolist()}")
    for m in out.meshes:
        m.vertices = np.asarray(m.vertices, np.float64) * s + off
        # Shading normals are unchanged by a uniform scale and a translation.
    for e in out.emitters:
        e.position = np.asarray(e.position, np.float64) * s + off
        if e.kind in (POINT, SPOT):
            e.intensity = np.asarray(e.intensity, np.float64) * s * s
    cam = out.camera
    m = np.array(cam.to_world, np.float64)
    m[:3, 3] = m[:3, 3] * s + off
    cam.to_world = m
    cam.near_clip = cam.near_clip * s
    return out


def translated(scene: Scene, by: float = 1e5) -> Scene:
    return transformed(scene, 1.0, (by, by, by))


def scaled(scene: Scene, factor: float) -> Scene:
    return transformed(scene, factor)


# --------------------------------------------------------------------------- broken geometry

def with_degenerate_triangles(scene: Scene) -> Scene:
    """Every mesh (emitters included) gets zero-area triangles: a repeated index, three
    collinear vertices, three identical vertices, and a sliver of relative width 1e-20 (not
    zero, so it is kept but its normal is ill-conditioned). The visible image must not change:
    Embree never reports zero-area hits and the emitter CDF gives them zero width."""
    out = _copy(scene, "degenerate triangles")
    for m in out.meshes:
        v = np.asarray(m.vertices, np.float64)
        f = np.asarray(m.faces, np.int64)
        if len(f) == 0:
            continue
        a, b, c = v[f[0, 0]], v[f[0, 1]], v[f[0, 2]]
        base = len(v)
        extra_v = np.array([a, b, 0.5 * (a + b),  # collinear
                            c, c, c,  # one point three times
                            ])
        nv = [extra_v]
        faces = [f, np.array([[f[0, 0], f[0, 0], f[0, 1]],  # repeated index
                              [base, base + 1, base + 2],
                              [base + 3, base + 4, base + 5]], np.int64)]
        if m.emitter < 0:
            # A sliver: not zero area, but 1e-20 of the triangle's size across. Only on
            # non-emitters: on an emitter it would (correctly) add a little emitting area.
            sliver = np.array([a, b, a + 1e-20 * (c - a)])
            nv.append(sliver)
            faces.append(np.array([[base + 6, base + 7, base + 8]], np.int64))
        # Degenerate triangles first and last: both ends of the emitter CDF see them.
        deg = np.concatenate(faces[1:])
        m.faces = np.concatenate([deg[:1], f, deg[1:]]).astype(np.int32)
        new_v = np.concatenate(nv)
        m.vertices = np.concatenate([v, new_v])
        if m.normals is not None:
            n0 = np.asarray(m.normals, np.float64)
            m.normals = np.concatenate([n0, np.repeat(n0[f[0, :1]], len(new_v), axis=0)])
        if m.uvs is not None:
            m.uvs = np.concatenate([m.uvs, np.zeros((len(new_v), 2))])
    return out


def with_duplicate_vertices(scene: Scene) -> Scene:
    """Every vertex stored twice (faces alternate between the copies) and, on non-emitters,
    every triangle stored twice (coplanar duplicates, same material). Duplicated emitter
    triangles would double the emitting area, so emitters only get duplicate vertices."""
    out = _copy(scene, "duplicate vertices")
    for m in out.meshes:
        v = np.asarray(m.vertices, np.float64)
        f = np.asarray(m.faces, np.int64)
        nv = len(v)
        m.vertices = np.concatenate([v, v])
        if m.normals is not None:
            m.normals = np.concatenate([m.normals, m.normals])
        if m.uvs is not None:
            m.uvs = np.concatenate([m.uvs, m.uvs])
        alt = f.copy()
        alt[1::2] += nv  # odd triangles use the second copy
        if m.emitter < 0:
            alt = np.concatenate([alt, f + nv])
        m.faces = alt.astype(np.int32)
    return out


def with_nonfinite_vertices(scene: Scene) -> tuple[Scene, list[str]]:
    """NaN and ±Inf written into vertex positions, normals and uvs of some meshes, in memory.
    Returns (scene, names of the meshes that were poisoned)."""
    out = _copy(scene, "non-finite vertex data")
    poisoned = []
    big = [i for i, m in enumerate(out.meshes) if len(m.faces) > 0 and m.emitter < 0]
    for j, i in enumerate(big[:3]):
        m = out.meshes[i]
        v = np.array(m.vertices, np.float64)
        bad = [np.nan, np.inf, -np.inf][j % 3]
        v[m.faces[0, 1], j % 3] = bad
        m.vertices = v
        if m.normals is not None and len(m.faces) > 1:
            n = np.array(m.normals, np.float64)
            n[m.faces[-1, 2]] = np.nan
            m.normals = n
        poisoned.append(m.name)
    return out, poisoned


# -------------------------------------------------------------------------------- lights

def zero_power_lights(scene: Scene) -> Scene:
    """Every emitter emits nothing (radiance, intensity, irradiance 0)."""
    out = _copy(scene, "zero-power lights")
    for e in out.emitters:
        e.radiance = np.zeros(3)
        e.intensity = np.zeros(3)
        e.irradiance = np.zeros(3)
    return out


def with_extra_lights(scene: Scene) -> Scene:
    """The scene's lights plus a zero-power area light (the back wall), a zero-intensity point
    light, a zero-radiance environment and a point light lying exactly on the floor surface."""
    out = _copy(scene, "extra and zero-power lights")
    lo, hi = out.bounds()
    for i, m in enumerate(out.meshes):
        if m.emitter < 0 and "back" in m.name.lower():
            out.emitters.append(Emitter(AREA, radiance=np.zeros(3), mesh=i, name="dark wall"))
            m.emitter = len(out.emitters) - 1
            break
    centre = 0.5 * (lo + hi)
    out.emitters.append(Emitter(POINT, intensity=np.zeros(3), position=centre, name="dark point"))
    out.emitters.append(Emitter(CONSTANT, radiance=np.zeros(3), name="dark sky"))
    on_floor = np.array([centre[0], lo[1], centre[2]])  # exactly on the floor plane
    out.emitters.append(Emitter(POINT, intensity=np.full(3, 0.5), position=on_floor, name="point on floor"))
    out.emitters.append(Emitter(SPOT, intensity=np.full(3, 2.0), position=np.array([centre[0], hi[1], centre[2]]),
                                direction=np.array([0.0, -1.0, 0.0]), cutoff_angle=30.0, beam_width=30.0,
                                name="spot, beam = cutoff"))
    return out


# ------------------------------------------------------------------------------ materials

def with_albedo(scene: Scene, value: float) -> Scene:
    """Every diffuse material (and the diffuse layer of plastics) with reflectance ``value``."""
    out = _copy(scene, f"albedo {value:g}")

    def fn(m: Material):
        if m.kind in (DIFFUSE, PLASTIC, ROUGHPLASTIC):
            return dataclasses.replace(m, diffuse=Texture.constant(value))
        return None

    return _replace_materials(out, fn)


def with_ior(scene: Scene, int_ior: float, ext_ior: float = 1.0, plastics: bool = True) -> Scene:
    """Every dielectric (and plastic coat when ``plastics``) with the given IORs: 1/1 is an
    index-matched (invisible) interface; int < ext makes total internal reflection happen on
    the outside."""
    out = _copy(scene, f"ior {int_ior:g}/{ext_ior:g}")

    def fn(m: Material):
        if m.kind in (DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC) or (plastics and m.kind in (PLASTIC, ROUGHPLASTIC)):
            return dataclasses.replace(m, int_ior=float(int_ior), ext_ior=float(ext_ior))
        return None

    return _replace_materials(out, fn)


# ---------------------------------------------------------------------------- grazing views

def grazing_camera(scene: Scene, height: float = 1e-3) -> Scene:
    """Camera just above the floor (``height`` of the scene's size), looking along it: the
    floor is seen at angles down to ~1e-3 rad from the tangent plane."""
    from igi.common.camera import look_at

    out = _copy(scene, "grazing camera")
    lo, hi = out.bounds()
    size = float(np.max(hi - lo))
    cam = out.camera
    eye_pos = np.asarray(cam.to_world, np.float64)[:3, 3].copy()
    eye_pos[1] = lo[1] + height * size
    target = np.array([0.5 * (lo[0] + hi[0]), lo[1] + height * size, lo[2]])
    cam.to_world = look_at(eye_pos, target, [0.0, 1.0, 0.0])
    return out


def grazing_light(scene: Scene) -> Scene:
    """The area light turned edge-on (rotated 90° about its centre so it emits sideways along
    the ceiling): light reaches the ceiling at exactly grazing angles."""
    out = _copy(scene, "grazing light")
    for e in out.emitters:
        if e.kind != AREA or e.mesh < 0:
            continue
        m = out.meshes[e.mesh]
        v = np.asarray(m.vertices, np.float64)
        c = v.mean(axis=0)
        # rotate about the x axis by 90 degrees
        r = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        m.vertices = (v - c) @ r.T + c
        if m.normals is not None:
            m.normals = np.asarray(m.normals, np.float64) @ r.T
    return out


# ---------------------------------------------------------------------------- file-level cases

def copy_scene_dir(name: str, dest: Path) -> Path:
    """Copy shared scene ``name`` (XML, meshes, OBJ/MTL; no textures or previews larger than
    needed) to ``dest``; returns the copied scene.xml."""
    import shutil

    src = SHARED_SCENES / name
    dst = Path(dest) / name
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("preview.png"))
    return dst / "scene.xml"


_V_LINE = re.compile(rb"^v\s", re.M)


def poison_obj_text(data: bytes, values=(b"nan", b"inf", b"-1e999")) -> bytes:
    """An OBJ with some ``v`` lines' first coordinate replaced by NaN / Inf."""
    lines = data.split(b"\n")
    vi = [i for i, ln in enumerate(lines) if ln.startswith(b"v ")]
    for j, i in enumerate(vi[: len(values)]):
        parts = lines[i].split()
        parts[1] = values[j]
        lines[i] = b" ".join(parts)
    return b"\n".join(lines)


def nonfinite_obj_files(dest: Path) -> list[tuple[Path, str]]:
    """File-level NaN/Inf cases: (scene file, name of the poisoned mesh) pairs — the Mitsuba
    XML of cornell-box with its tallBox.obj poisoned, and the whole-scene OBJ
    CornellBox-Original.obj with NaN/Inf vertices."""
    xml = copy_scene_dir("cornell-box", Path(dest) / "xml")
    mesh = xml.parent / "meshes" / "tallBox.obj"
    mesh.write_bytes(poison_obj_text(mesh.read_bytes()))
    obj_dir = Path(dest) / "obj"
    obj_dir.mkdir(parents=True, exist_ok=True)
    src = SHARED_SCENES / "cornell-box"
    (obj_dir / "CornellBox-Original.mtl").write_bytes((src / "CornellBox-Original.mtl").read_bytes())
    obj = obj_dir / "CornellBox-Original.obj"
    obj.write_bytes(poison_obj_text((src / "CornellBox-Original.obj").read_bytes()))
    return [(xml, "tallBox"), (obj, "")]


# -------------------------------------------------------------------------------- the list

@dataclass
class StressCase:
    name: str
    base: str  # shared scene it is derived from
    build: Callable[[Path], Scene]  # tmp dir -> scene
    reference: str | None = None  # base scene whose image it must reproduce
    bound: float | None = None  # relMSE bound against the reference
    why: str = ""
    params: dict = field(default_factory=dict)
    expect_black: bool = False  # nothing emits: the image must be exactly 0
    frames: int = 1  # accumulated frames (2: the second one has another seed and sub-pixel jitter)


# relMSE bounds (relmse: mean over pixels and channels of (x - ref)² / (ref² + 0.01)).
# The transformed, duplicated and degenerate scenes are rendered with the same seeds, so every
# estimator draws the same random numbers and the images differ only where rounding flips a
# decision: Embree's float32 hit/miss on an edge, a shadow ray grazing a contact edge, a photon
# exactly at distance r. Measured at 48x48 (1-2 frames): translation by 1e5 gives bit-identical
# images (Geometry stores triangles relative to the scene centre), scaling by 1e-4/1e4 gives
# relMSE <= 1e-10 (largest pixel difference ~1e-4), duplicating triangles 1.5e-4 (two pixels
# on a corner edge flip, then spread by the discontinuity buffer).
# Scale of the bound: one fully flipped pixel of value ~0.5 costs ~3·0.96/(48·48·3) ≈ 4e-4;
# a 3% global brightness error costs ~1e-3·mean(ref²/(ref²+0.01)) ≈ 5e-4; a wrong offset at
# 1e-4/1e4/1e5 (surfaces shadowing themselves, rays starting behind the surface) blackens
# whole regions: relMSE 0.1-1. So 1e-3 tolerates a couple of flipped pixels and still catches
# every systematic error of a few percent; the tests also compare the image means (1e-3).
TRANSFORM_BOUND = 1e-3
TRANSFORM_WHY = ("same seeds -> same samples; only rounding at edges may flip a pixel (~4e-4 each); "
                 "measured <= 1e-10; a 3% global error gives ~5e-4, self-shadowing 0.1-1")
IDENTITY_BOUND = 1e-3
IDENTITY_WHY = ("the same surfaces (plus triangles Embree never hits / coincident copies): only "
                "which of two coincident triangles is hit may change, flipping a few edge pixels; "
                "measured 1.5e-4")


def _shared(name: str, fn: Callable[[Scene], Scene]) -> Callable[[Path], Scene]:
    return lambda tmp: fn(load_shared(name))


def _transform(name: str, base: str, fn: Callable[[Scene], Scene]) -> StressCase:
    return StressCase(name, base, _shared(base, fn), base, TRANSFORM_BOUND, TRANSFORM_WHY, frames=2)


def _nonfinite_in_memory(tmp: Path) -> Scene:
    return with_nonfinite_vertices(load_shared("cornell-box"))[0]


def _nonfinite_file_xml(tmp: Path) -> Scene:
    from igi.common.loader import load_scene

    return load_scene(nonfinite_obj_files(tmp)[0][0])


def _nonfinite_file_obj(tmp: Path) -> Scene:
    from igi.common.loader import load_scene

    return load_scene(nonfinite_obj_files(tmp)[1][0])


CASES: list[StressCase] = [
    # transformed scenes: must reproduce the untransformed image
    _transform("sphere-translate-1e5", "cornell-box-sphere", translated),
    _transform("sphere-scale-1e-4", "cornell-box-sphere", lambda s: scaled(s, 1e-4)),
    _transform("sphere-scale-1e4", "cornell-box-sphere", lambda s: scaled(s, 1e4)),
    _transform("sphere-scale-1e-4-translate-1e5", "cornell-box-sphere",
               lambda s: transformed(s, 1e-4, (1e5, -1e5, 1e5))),
    _transform("glossy-translate-1e5", "cornell-box-glossy", translated),
    _transform("glossy-scale-1e-4", "cornell-box-glossy", lambda s: scaled(s, 1e-4)),
    _transform("glossy-scale-1e4", "cornell-box-glossy", lambda s: scaled(s, 1e4)),
    # broken geometry
    StressCase("sphere-degenerate-triangles", "cornell-box-sphere",
               _shared("cornell-box-sphere", with_degenerate_triangles), "cornell-box-sphere",
               IDENTITY_BOUND, IDENTITY_WHY),
    StressCase("box-duplicate-vertices", "cornell-box", _shared("cornell-box", with_duplicate_vertices),
               "cornell-box", IDENTITY_BOUND, IDENTITY_WHY),
    StressCase("box-nonfinite-in-memory", "cornell-box", _nonfinite_in_memory),
    StressCase("box-nonfinite-xml-obj-file", "cornell-box", _nonfinite_file_xml),
    StressCase("box-nonfinite-whole-obj-file", "cornell-box", _nonfinite_file_obj),
    # lights
    StressCase("box-zero-power", "cornell-box", _shared("cornell-box", zero_power_lights), expect_black=True),
    StressCase("box-extra-lights", "cornell-box", _shared("cornell-box", with_extra_lights)),
    StressCase("bidir-zero-power", "veach-bidir", _shared("veach-bidir", zero_power_lights), expect_black=True),
    # materials
    StressCase("box-albedo-0", "cornell-box", _shared("cornell-box", lambda s: with_albedo(s, 0.0))),
    StressCase("box-albedo-1", "cornell-box", _shared("cornell-box", lambda s: with_albedo(s, 1.0))),
    StressCase("glossy-albedo-1", "cornell-box-glossy", _shared("cornell-box-glossy", lambda s: with_albedo(s, 1.0))),
    StressCase("sphere-ior-1", "cornell-box-sphere", _shared("cornell-box-sphere", lambda s: with_ior(s, 1.0, 1.0))),
    StressCase("glossy-ior-1", "cornell-box-glossy", _shared("cornell-box-glossy", lambda s: with_ior(s, 1.0, 1.0))),
    StressCase("sphere-ior-inverted-tir", "cornell-box-sphere",
               _shared("cornell-box-sphere", lambda s: with_ior(s, 1.0, 1.6))),
    StressCase("sphere-ior-10-tir", "cornell-box-sphere", _shared("cornell-box-sphere", lambda s: with_ior(s, 10.0))),
    StressCase("water-tir", "cornell-box-water", lambda tmp: load_shared("cornell-box-water")),
    # grazing angles
    StressCase("box-grazing-camera", "cornell-box", _shared("cornell-box", grazing_camera)),
    StressCase("glossy-grazing-camera", "cornell-box-glossy", _shared("cornell-box-glossy", grazing_camera)),
    StressCase("box-grazing-light", "cornell-box", _shared("cornell-box", grazing_light)),
]

CASE_BY_NAME = {c.name: c for c in CASES}


def render(scene: Scene, frames: int = 1, params: dict | None = None, width: int = 48,
           height: int = 48, renderer=None) -> np.ndarray:
    """A small image over the distributed path (tiles, wire codec, filter, accumulation)."""
    from igi.master.inprocess import render_local

    return render_local(scene, dict(params or {}), frames, width=width, height=height, renderer=renderer)


# ------------------------------------------------------------- VPLs on the shading point

def eye_end_points(renderer, width: int = 24, height: int = 24, max_depth: int = -1, glossy_split_alpha: float = 0.0):
    """End points of one eye ray per pixel centre of a width x height image (worker.shading;
    ``glossy_split_alpha`` > 0: smooth plastics split into their diffuse layer and lobe)."""
    from igi.common.camera import camera_rays
    from igi.common.sobol_stream import rng
    from igi.worker.shading import trace_eye

    cam = renderer.scene.camera
    ys, xs = np.mgrid[0:height, 0:width]
    o, d = camera_rays(cam.to_world, cam.fov_x, width, height, xs.ravel(), ys.ravel())
    return trace_eye(renderer.scene, renderer.geom, renderer.lights, o, d, max_depth, 8, rng(0, 1),
                     glossy_split_alpha).end


def with_nonfinite_positions(end, nan_every: int, inf_every: int):
    """End points with every ``nan_every``-th position NaN and every ``inf_every``-th from
    row 1 infinite (the kernels' hostile rows)."""
    import dataclasses

    pos = end.position.copy()
    pos[::nan_every] = np.nan
    pos[1::inf_every] = np.inf
    return dataclasses.replace(end, position=pos)


def vpls_at(end, rows: np.ndarray, kinds=("surface", "area", "point", "spot")):
    """A VPL set with VPLs of the given kinds placed exactly on the end points ``rows`` (same
    position bit for bit, the end point's own normals and BSDF for surface VPLs). Area VPLs
    carry an area pdf so the MIS weights are computed for them too."""
    from igi.common.lights import VPL_AREA, VPL_POINT, VPL_SPOT, VPL_SURFACE
    from igi.worker.vpl import VPLSet

    rows = np.asarray(rows, np.int64)
    m = len(rows)
    code = {"surface": VPL_SURFACE, "area": VPL_AREA, "point": VPL_POINT, "spot": VPL_SPOT}
    parts = {k: [] for k in ("kind", "position", "normal", "ng", "power", "depth", "wi", "pdf")}
    for k in kinds:
        parts["kind"].append(np.full(m, code[k], np.int8))
        parts["position"].append(end.position[rows])
        parts["normal"].append(end.ns[rows] if k in ("surface", "area") else np.tile([0.0, -1.0, 0.0], (m, 1)))
        parts["ng"].append(end.ng[rows])
        parts["power"].append(np.full((m, 3), 0.5))
        parts["depth"].append(np.full(m, 1 if k == "surface" else 0, np.int32))
        parts["wi"].append(end.wi[rows] if k == "surface" else np.tile([0.0, 20.0, 30.0], (m, 1)))
        parts["pdf"].append(np.full(m, 0.7 if k == "area" else 0.0))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    # surface rows come first, so the surface BSDFs are the end points' own, in order
    surface = end.sp.subset(rows) if "surface" in kinds else None
    if "surface" in kinds and kinds[0] != "surface":
        raise ValueError("surface VPLs must come first")
    return VPLSet(cat["kind"], cat["position"], cat["normal"], cat["ng"], cat["power"], cat["depth"],
                  cat["wi"], surface, bool(surface is None or np.all(surface.kind == DIFFUSE)),
                  cat["pdf"], 1)


def merge_vpl_sets(a, b):
    """Concatenation of two VPL sets (surface rows of both keep their BSDFs)."""
    from igi.worker.vpl import concat_vpls

    return concat_vpls([a, b])


# ------------------------------------------------------- photons on grid-cell borders

def lattice_photons(radius: float = 0.25, half: int = 6):
    """A PhotonSet on the plane y = 0 whose photons sit on a lattice of spacing r/2, i.e. on
    the cell borders (cell size 2r), cell centres and quarter points of the hashed grid, plus
    the query positions: the same lattice and lattice points shifted by exactly r (photons at
    distance exactly r count). ``radius`` should be dyadic so everything is exact."""
    from igi.worker.caustics import PhotonSet
    from igi.worker.hash_grid import HashGrid

    g = np.arange(-half, half + 1) * (radius / 2)
    gx, gz = np.meshgrid(g, g, indexing="ij")
    pos = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    n = len(pos)
    rng = np.random.default_rng(7)
    power = rng.random((n, 3)) + 0.1
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    photons = PhotonSet(pos, power, up.copy(), up.copy(), np.full(n, 2, np.int32), radius,
                        HashGrid(pos, radius), n)
    queries = np.concatenate([pos, pos + [radius, 0.0, 0.0], pos - [0.0, 0.0, radius]])
    return photons, queries


# ---------------------------------------------------------------------------------------- synthetic

def _quad(c, e1, e2):
    c, e1, e2 = (np.asarray(x, float) for x in (c, e1, e2))
    return np.array([c, c + e1, c + e1 + e2, c + e2]), np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def mini_cornell(width: int = 64, height: int = 48) -> Scene:
    """A 2x2x2 box open towards the camera: white floor/ceiling/back, red left, green right,
    a white block, and a small area light under the ceiling facing down."""
    from igi.common.camera import look_at
    from igi.common.scene import NULL, Camera, Mesh

    mats = [Material("white", DIFFUSE, diffuse=Texture.constant(0.7)),
            Material("red", DIFFUSE, diffuse=Texture.constant([0.7, 0.1, 0.1])),
            Material("green", DIFFUSE, diffuse=Texture.constant([0.1, 0.7, 0.1])),
            Material("light", NULL)]
    parts = [
        ("floor", _quad([0, 0, 0], [0, 0, 2], [2, 0, 0]), 0),
        ("ceiling", _quad([0, 2, 0], [2, 0, 0], [0, 0, 2]), 0),
        ("back", _quad([0, 0, 0], [2, 0, 0], [0, 2, 0]), 0),
        ("left", _quad([0, 0, 0], [0, 2, 0], [0, 0, 2]), 1),
        ("right", _quad([2, 0, 0], [0, 0, 2], [0, 2, 0]), 2),
        ("block_top", _quad([0.5, 0.6, 0.5], [0, 0, 0.6], [0.6, 0, 0]), 0),
        ("block_front", _quad([0.5, 0, 1.1], [0.6, 0, 0], [0, 0.6, 0]), 0),
        ("block_side", _quad([1.1, 0, 0.5], [0, 0.6, 0], [0, 0, 0.6]), 0),
    ]
    meshes = [Mesh(name, v, f, m) for name, (v, f), m in parts]
    lv, lf = _quad([0.7, 1.98, 0.7], [0.6, 0, 0], [0, 0, 0.6])
    meshes.append(Mesh("light", lv, lf, 3, emitter=0))
    emitters = [Emitter(AREA, radiance=np.full(3, 12.0), mesh=len(meshes) - 1, name="light")]
    cam = Camera(look_at([1.0, 1.0, 4.2], [1.0, 1.0, 0.0], [0, 1, 0]), fov=45, width=width, height=height)
    return Scene(meshes, mats, emitters, cam, source="mini-cornell")
