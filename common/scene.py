"""The scene model every loader produces and every renderer part reads.

Loaders (``mitsuba_xml.py``, ``obj_mtl.py``) turn files into a :class:`Scene`: triangle
meshes already in world space, materials with their textures, emitters, one camera.
Everything is plain numpy so a scene can be hashed, pickled and shipped to workers.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from .kernels import texture


class SceneError(ValueError):
    """A scene file or scene content that cannot be used; the message names file, line and problem."""


@dataclass
class Texture:
    """A constant RGB value or a bitmap (linear RGB float32, row 0 = top of the image)."""

    rgb: np.ndarray | None = None  # (3,) float64
    image: np.ndarray | None = None  # (H, W, 3) float32, linear
    filter: str = "bilinear"  # or "nearest"
    uv_scale: tuple[float, float] = (1.0, 1.0)
    uv_offset: tuple[float, float] = (0.0, 0.0)
    name: str = ""

    @staticmethod
    def constant(value) -> "Texture":
        v = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
        return Texture(rgb=v)

    @property
    def is_constant(self) -> bool:
        return self.image is None

    def mean(self) -> np.ndarray:
        if self.image is None:
            return self.rgb
        return self.image.reshape(-1, 3).mean(axis=0).astype(np.float64)

    def eval(self, uv: np.ndarray) -> np.ndarray:
        """Look the texture up at (N, 2) uv coordinates (Mitsuba convention: v up, repeat wrap)."""
        n = len(uv)
        if self.image is None:
            return np.broadcast_to(self.rgb, (n, 3)).astype(np.float32)
        out = np.empty((n, 3), np.float32)
        texture.lookup(np.ascontiguousarray(self.image, dtype=np.float32),
                       np.ascontiguousarray(uv, dtype=np.float64).reshape(n, 2),
                       float(self.uv_scale[0]), float(self.uv_scale[1]), float(self.uv_offset[0]),
                       float(self.uv_offset[1]), self.filter == "nearest", out)
        return out


# BSDF kinds; the integer codes are what per-point arrays carry.
DIFFUSE = 0
CONDUCTOR = 1
ROUGHCONDUCTOR = 2
DIELECTRIC = 3
THINDIELECTRIC = 4
PLASTIC = 5
ROUGHPLASTIC = 6
NULL = 7  # black / absorbing (e.g. an emitter's own black BSDF)
# Internal, never from a file: the diffuse layer of a rough plastic alone. The renderer splits a
# smooth rough plastic at the first hit into this end point and a traced glossy lobe.
ROUGHPLASTIC_DIFFUSE = 8
# Internal: the coat's glossy lobe of a rough plastic alone (its microfacet reflection), for the
# light samples of a split lobe, MIS-weighted against the lobe's own traced ray.
ROUGHPLASTIC_LOBE = 9
# A rough dielectric (Mitsuba's roughdielectric, Walter et al. 2007): followed as a chain, as
# glass is, each crossing at one microfacet normal drawn from those visible from wi.
ROUGHDIELECTRIC = 10
# Internal: a rough dielectric's reflection alone (on wi's side) and its refraction alone (to the
# other side), each with the weight and density of its drawn crossing: the lobes through which a
# hit on rough glass takes the set's emitter samples, the one facing its outside (design note 48).
ROUGHDIELECTRIC_R = 11
ROUGHDIELECTRIC_T = 12

KIND_NAMES = {
    "diffuse": DIFFUSE,
    "conductor": CONDUCTOR,
    "roughconductor": ROUGHCONDUCTOR,
    "dielectric": DIELECTRIC,
    "thindielectric": THINDIELECTRIC,
    "roughdielectric": ROUGHDIELECTRIC,
    "plastic": PLASTIC,
    "roughplastic": ROUGHPLASTIC,
    "null": NULL,
}
# delta BSDFs, and the rough dielectric sampled as one at a drawn microfacet: chains are followed
SPECULAR_KINDS = (CONDUCTOR, DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC)
GLOSSY_KINDS = (ROUGHCONDUCTOR, PLASTIC, ROUGHPLASTIC)
_N_KINDS = ROUGHDIELECTRIC_T + 1
_KIND_TABLES: dict[tuple, np.ndarray] = {}


def reflecting(materials: list, kind: np.ndarray, mat_ids: np.ndarray) -> np.ndarray:
    """Per point of BSDF ``kind`` on material row ``mat_ids`` (out of range: NULL): whether it
    reflects light onward — not mirror/glass, not NULL, not black (Material.is_black): where
    light walks leave VPLs and the final gather's levels go on (their compiled loops read the
    same per material row)."""
    black = np.array([m.is_black for m in materials] + [False], bool)
    m = np.asarray(mat_ids)
    rows = np.where((m >= 0) & (m < len(materials)), m, len(materials))
    return ~kind_in(kind, SPECULAR_KINDS) & (kind != NULL) & ~black[rows]


def kind_in(kind: np.ndarray, kinds: tuple) -> np.ndarray:
    """``np.isin(kind, kinds)`` for BSDF kind codes, as one table lookup (isin sorts per call;
    this runs per bounce of every tile). Codes outside the known kinds are in no set."""
    table = _KIND_TABLES.get(kinds)
    if table is None:
        # one entry per byte value: int8 codes are read as their bytes (negative codes land in
        # 128…255, never a known kind), so an int8 array takes one lookup and no range checks
        table = np.zeros(256, bool)
        table[[c for c in kinds if 0 <= c < _N_KINDS]] = True
        _KIND_TABLES[kinds] = table
    k = np.asarray(kind)
    if k.dtype == np.int8:
        return table.take(k.view(np.uint8))
    idx = np.where((k >= 0) & (k < _N_KINDS), k, 255)
    return table[idx]


@dataclass
class Material:
    """One BSDF in Mitsuba's parametrization.

    ``kind`` is one of the codes above. Textures: ``diffuse`` (diffuse reflectance),
    ``specular`` (specular_reflectance / specular_transmittance share it). Scalars: ``alpha``
    (roughness), ``int_ior``/``ext_ior`` (dielectric, plastic), ``eta``/``k`` (conductor,
    RGB), ``distribution`` ("ggx" or "beckmann"), ``nonlinear`` (plastics).
    ``specular_transmittance`` is kept separately only for dielectrics.
    """

    name: str
    kind: int
    diffuse: Texture = field(default_factory=lambda: Texture.constant(0.5))
    specular: Texture = field(default_factory=lambda: Texture.constant(1.0))
    specular_transmittance: Texture = field(default_factory=lambda: Texture.constant(1.0))
    alpha: float = 0.1
    int_ior: float = 1.5046
    ext_ior: float = 1.000277
    eta: np.ndarray = field(default_factory=lambda: np.zeros(3))  # conductor; zeros+k=0 -> perfect mirror
    k: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distribution: str = "beckmann"
    nonlinear: bool = False
    twosided: bool = False
    # Mitsuba's ``mask``: the surface's opacity (its luminance; a hit is kept with this
    # probability, common.kernels.opacity_mask); None: opaque
    opacity: Texture | None = None
    # Mitsuba's ``normalmap`` (RGB: the shading normal in the shading frame, 2·rgb − 1) and
    # ``bumpmap`` (a height, its luminance, × ``bump_scale``): the shading normal at a hit is
    # perturbed by them (common.kernels.bump_mapping); None: the interpolated normal
    normal_map: Texture | None = None
    bump_map: Texture | None = None
    bump_scale: float = 1.0
    flip_invalid_normals: bool = True  # a perturbed normal facing away from wi is mirrored (Mitsuba's)

    @property
    def perturbs_normal(self) -> bool:
        return self.normal_map is not None or self.bump_map is not None

    @property
    def is_specular(self) -> bool:
        return self.kind in SPECULAR_KINDS

    @property
    def is_black(self) -> bool:
        """Reflects nothing anywhere: a diffuse of constant 0 (Mitsuba's default on an emitting
        shape). Light walks leave no VPLs on it (each would cost its shadow rays for no light)."""
        return self.kind == DIFFUSE and self.diffuse.is_constant and not np.any(self.diffuse.rgb)

    @property
    def is_glossy(self) -> bool:
        return self.kind in GLOSSY_KINDS

    @property
    def has_texture(self) -> bool:
        return not (self.diffuse.is_constant and self.specular.is_constant)


# Emitter kinds
AREA = "area"
POINT = "point"
SPOT = "spot"
DIRECTIONAL = "directional"
CONSTANT = "constant"


@dataclass
class Emitter:
    """A light. Area emitters reference a mesh by index; radiance is per unit area, one-sided (front = +normal)."""

    kind: str
    radiance: np.ndarray = field(default_factory=lambda: np.ones(3))  # area, constant
    intensity: np.ndarray = field(default_factory=lambda: np.ones(3))  # point, spot
    irradiance: np.ndarray = field(default_factory=lambda: np.ones(3))  # directional
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))  # spot/directional: where light goes
    cutoff_angle: float = 20.0  # spot, degrees
    beam_width: float = 15.0  # spot, degrees (Mitsuba default: 3/4 of cutoff)
    mesh: int = -1  # area: index into Scene.meshes
    name: str = ""
    # constant with a map (Mitsuba's envmap): the lat-long image (H, W, 3) times its scale, and
    # its rotation (3, 3); radiance is then the map's solid-angle mean (common.environment_map)
    image: np.ndarray | None = None
    to_world: np.ndarray | None = None


@dataclass
class Mesh:
    """A triangle mesh in world space."""

    name: str
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int32
    material: int  # index into Scene.materials
    normals: np.ndarray | None = None  # (V, 3) per-vertex shading normals, None -> flat
    uvs: np.ndarray | None = None  # (V, 2)
    emitter: int = -1  # index into Scene.emitters, -1 if none

    @property
    def triangle_count(self) -> int:
        return len(self.faces)


@dataclass
class Camera:
    """Mitsuba's perspective sensor: ``to_world`` maps camera space (+x left, +y up, +z forward)."""

    to_world: np.ndarray  # (4, 4)
    fov: float = 39.3077  # degrees, along fov_axis
    fov_axis: str = "x"
    width: int = 768
    height: int = 576
    near_clip: float = 0.01
    # the film's reconstruction filter (common.reconstruction_filter): Mitsuba's name and its
    # parameters (box/tent: radius, gaussian: stddev, mitchell: B and C, lanczos: lobes)
    rfilter: str = "box"
    rfilter_params: tuple[float, float] = (0.5, 0.0)
    # Mitsuba's thinlens: the aperture's radius (0: a pinhole) and the distance in focus
    aperture_radius: float = 0.0
    focus_distance: float = 10000.0

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in degrees, whatever axis the file named."""
        aspect = self.width / self.height
        t = np.tan(np.radians(self.fov) / 2)
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if self.width <= self.height else "y"
        elif axis == "larger":
            axis = "x" if self.width >= self.height else "y"
        if axis == "x":
            tx = t
        elif axis == "y":
            tx = t * aspect
        elif axis == "diagonal":
            tx = t * aspect / np.sqrt(1 + aspect * aspect)
        else:
            raise SceneError(f"unknown fov_axis {self.fov_axis!r}")
        return float(np.degrees(2 * np.arctan(tx)))


@dataclass
class Scene:
    meshes: list[Mesh]
    materials: list[Material]
    emitters: list[Emitter]
    camera: Camera
    source: str = ""
    warnings: list[str] = field(default_factory=list)
    max_depth: int = -1  # from the file's integrator, informational

    def digest(self) -> str:
        """Content hash: identical scenes give identical digests in every process."""
        h = hashlib.sha256()
        for m in self.meshes:
            h.update(np.ascontiguousarray(m.vertices, np.float64).tobytes())
            h.update(np.ascontiguousarray(m.faces, np.int64).tobytes())
            h.update(f"{m.material},{m.emitter}".encode())
        for mat in self.materials:
            h.update(repr((mat.kind, mat.alpha, mat.int_ior, mat.ext_ior, mat.distribution)).encode())
            # (a mask changes what rays hit, a normal or bump map what a hit's normal is)
            for slot, t in (("", mat.opacity), ("normal map", mat.normal_map), ("bump map", mat.bump_map)):
                if t is not None:
                    h.update(slot.encode())  # (the opacity's untagged: digests of masked scenes as before)
                    h.update(np.ascontiguousarray(t.rgb if t.is_constant else t.image, np.float64).tobytes())
                    h.update(repr((t.uv_scale, t.uv_offset, t.filter)).encode())
            if mat.perturbs_normal:
                h.update(repr((mat.bump_scale, mat.flip_invalid_normals)).encode())
        for e in self.emitters:
            h.update(repr((e.kind, e.radiance.tolist(), e.intensity.tolist(), e.position.tolist())).encode())
            if e.image is not None:
                h.update(np.ascontiguousarray(e.image, np.float32).tobytes())
                h.update(np.asarray(e.to_world if e.to_world is not None else np.eye(3), np.float64).tobytes())
        h.update(np.asarray(self.camera.to_world).tobytes())
        return h.hexdigest()[:16]

    @property
    def triangle_count(self) -> int:
        return sum(m.triangle_count for m in self.meshes)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        vs = [m.vertices for m in self.meshes if len(m.vertices)]
        if not vs:
            return np.zeros(3), np.zeros(3)
        allv = np.concatenate(vs)
        return allv.min(axis=0), allv.max(axis=0)

    def diagonal(self) -> float:
        lo, hi = self.bounds()
        return float(np.linalg.norm(hi - lo)) or 1.0
