"""BSDFs matching Mitsuba 3 (diffuse, conductor, roughconductor, dielectric, thindielectric,
roughdielectric, plastic, roughplastic, twosided, null) over N points: per-point parameters
(:class:`SurfacePoints`, :func:`gather`) and the array API, evaluated by the compiled scalar
kernels of common.kernels.bsdf on the packed parameters (:func:`pack`), in float64; results
come back in the inputs' float type.

Everything works in the local shading frame (z = shading normal).
``wi`` points toward the viewer / previous path vertex and ``wo`` toward the light / next
vertex; both point away from the surface. Values returned by :func:`eval` already include the
cosine foreshortening ``|cos theta_o|`` (Mitsuba's convention).

Component layout of :func:`specular_components` (always two entries, masks say which apply):

- ``[0]`` delta reflection: conductor (Fresnel x specular), dielectric (R x specular),
  thindielectric (R' x specular), plastic (F(cos_i) x specular);
- ``[1]`` delta transmission: dielectric (T x transmittance, radiance mode x eta_ti^2),
  thindielectric (straight through, T' x transmittance).

A rough dielectric is sampled as a delta too: both entries at one microfacet normal drawn from
``u2`` (reflection F x G1(wo) x specular, refraction (1 - F) x G1(wo) x transmittance), eval and
pdf 0: it is followed as a chain, never an end point.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from igi.common import coat_tables
from igi.common.kernels import bsdf as kb
from igi.common.kernels.bsdf import _WB, _WG, _WR  # (the kernels' luminance terms, in their order)
from igi.common.scene import (
    CONDUCTOR,
    DIELECTRIC,
    NULL,
    PLASTIC,
    ROUGHCONDUCTOR,
    ROUGHDIELECTRIC,
    ROUGHDIELECTRIC_R,
    ROUGHDIELECTRIC_T,
    ROUGHPLASTIC,
    ROUGHPLASTIC_DIFFUSE,
    ROUGHPLASTIC_LOBE,
    SPECULAR_KINDS,
    THINDIELECTRIC,
    Material,
    kind_in,
)

INV_PI = 1.0 / np.pi
ROUGH_PLASTIC_KINDS = (ROUGHPLASTIC, ROUGHPLASTIC_DIFFUSE, ROUGHPLASTIC_LOBE)  # the kinds that read coat tables

# no non-delta part at all (the rough dielectric: sampled at a drawn microfacet, as a delta)
DELTA_KINDS = (CONDUCTOR, DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC)
HAS_DELTA_KINDS = DELTA_KINDS + (PLASTIC,)  # some delta component
TRANSMISSIVE_KINDS = (DIELECTRIC, THINDIELECTRIC, ROUGHDIELECTRIC)  # two-sided by nature; ``twosided`` ignored


# ----------------------------------------------------------------------------------------------
# Per-point parameters


@dataclass
class SurfacePoints:
    """Per-point BSDF parameters (textures already looked up).

    Built by :func:`gather`, the points are *material-backed*: they hold each point's material
    row and only the fields that differ from their material's (bitmap-textured colours, kinds
    or roughness set by :meth:`replaced`); any other field is taken from the per-material tables
    the first time it is read. A subset then copies one index array instead of thirteen (eye
    paths, chains and set builds subset and concatenate points many times a tile). Built from
    arrays (the constructor, ``dataclasses.replace``), every field is held. A field assigned
    is held from then on; arrays are never changed in place (:meth:`replaced` makes a changed
    copy)."""

    kind: np.ndarray  # (N,) int8 codes from common.scene
    diffuse: np.ndarray  # (N, 3) diffuse reflectance
    specular: np.ndarray  # (N, 3) specular reflectance
    transmittance: np.ndarray  # (N, 3) specular transmittance (dielectrics)
    alpha: np.ndarray  # (N,) roughness (clamped to >= 1e-4 where used)
    eta: np.ndarray  # (N,) int_ior / ext_ior
    cond_eta: np.ndarray  # (N, 3) conductor IOR, real part
    cond_k: np.ndarray  # (N, 3) conductor IOR, imaginary part (eta = k = 0: perfect mirror)
    beckmann: np.ndarray  # (N,) bool (False = GGX)
    nonlinear: np.ndarray  # (N,) bool
    twosided: np.ndarray  # (N,) bool
    # (N,) plastics' specular sampling weight s_mean / (d_mean + s_mean) from the *texture means*
    # (Mitsuba computes it once per material); None -> from the per-point values.
    spec_weight: np.ndarray | None = None
    # (N,) int64 rough-plastic coat table row (common.coat_tables; 0 elsewhere), set by gather
    # so no evaluation looks coats up per point; None -> looked up from alpha/eta/beckmann.
    # Stale if alpha, eta or beckmann are changed in place afterwards.
    coat_row: np.ndarray | None = None

    def material_rows(self) -> np.ndarray | None:
        """Each point's row of the materials' tables (its material; ``len(materials)``: none),
        or None where the points are not material-backed."""
        return self.__dict__.get("_rows")

    @classmethod
    def _backed(cls, tables: dict, rows: np.ndarray, held: dict) -> "SurfacePoints":
        """Points of material-table ``rows`` (tables of :func:`_material_tables`), with the
        fields ``held`` per point."""
        sp = object.__new__(cls)
        d = sp.__dict__
        d["_tables"], d["_rows"], d["_held"] = tables, rows, tuple(held)
        d.update(held)
        return sp

    def __getattr__(self, name: str):
        # Only reached for a field a material-backed instance has not read yet.
        d = self.__dict__
        column = _TABLE_COLUMN.get(name)
        tables = d.get("_tables")
        if column is None or tables is None:
            raise AttributeError(name)
        value = d[name] = tables[column].take(d["_rows"], axis=0)
        return value

    def __setattr__(self, name: str, value) -> None:
        # A field set on material-backed points is held per point from now on.
        d = self.__dict__
        if "_tables" in d and name in _TABLE_COLUMN and name not in d["_held"]:
            d["_held"] += (name,)
        d.pop("_packed_rows", None)
        d[name] = value

    def __len__(self) -> int:
        rows = self.__dict__.get("_rows")
        return len(self.kind) if rows is None else len(rows)

    def subset(self, mask_or_index) -> "SurfacePoints":
        rows = row_selector(mask_or_index, len(self))
        d = self.__dict__
        if "_tables" in d:
            return SurfacePoints._backed(d["_tables"], take_rows(d["_rows"], rows),
                                         {name: take_rows(d[name], rows) for name in d["_held"]})
        return SurfacePoints(*[None if v is None else take_rows(v, rows)
                               for v in (getattr(self, name) for name in _SP_FIELDS)])

    def replaced(self, **changes) -> "SurfacePoints":
        """A copy with the fields ``changes`` (per-point arrays) replaced; material-backed
        points stay backed, holding the changed fields."""
        d = self.__dict__
        if "_tables" not in d:
            return replace(self, **changes)
        held = {name: d[name] for name in d["_held"]}
        held.update(changes)
        return SurfacePoints._backed(d["_tables"], d["_rows"], held)

    @staticmethod
    def concat(parts: list["SurfacePoints"]) -> "SurfacePoints":
        """The points of ``parts`` in order (an optional field None in all: None)."""
        first = parts[0].__dict__
        if "_tables" in first and all(p.__dict__.get("_tables") is first["_tables"] for p in parts):
            held = dict.fromkeys(name for p in parts for name in p.__dict__["_held"])
            return SurfacePoints._backed(first["_tables"], np.concatenate([p.__dict__["_rows"] for p in parts]),
                                         {name: np.concatenate([getattr(p, name) for p in parts]) for name in held})
        return SurfacePoints(**{name: None if all(getattr(p, name) is None for p in parts)
                                else np.concatenate([getattr(p, name) for p in parts]) for name in _SP_FIELDS})

    def packed(self) -> tuple:
        """The per-point parameter tuple ``P`` of the compiled kernels (see :func:`pack`)."""
        return pack(self)

    @staticmethod
    def constant(material: Material, n: int) -> "SurfacePoints":
        """``n`` points of one material (textures evaluated at uv = 0 when not constant)."""
        return gather([material], np.zeros(n, np.int64), None)

    def sampling_weight(self) -> np.ndarray:
        if self.spec_weight is not None:
            return self.spec_weight
        d = self.diffuse.mean(axis=-1)
        s = self.specular.mean(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = s / (d + s)
        return np.where(np.isfinite(w), w, 0.5).astype(np.float32)


def row_selector(rows, n: int):
    """``rows`` (index array, boolean mask, slice) as :func:`take_rows` takes them for arrays of
    ``n`` rows: a mask of n rows as its index array; a mask of another length stays a mask, so
    indexing refuses it."""
    if isinstance(rows, np.ndarray) and rows.dtype == bool and len(rows) == n:
        return np.flatnonzero(rows)
    return rows


def take_rows(v: np.ndarray, rows) -> np.ndarray:
    """``v[rows]``; by take() for an index array (it copies rows ~4x faster than indexing)."""
    if isinstance(rows, np.ndarray) and rows.dtype != bool:
        return v.take(rows, axis=0)
    return v[rows]


_SP_FIELDS = tuple(f.name for f in fields(SurfacePoints))  # subset() runs per bounce: no fields() call
# The optional fields' class-level defaults (None) would shadow a material-backed instance's
# lazy lookup (__getattr__ is reached only when normal lookup fails); the constructor keeps
# its own copy of the defaults.
for _name in ("spec_weight", "coat_row"):
    delattr(SurfacePoints, _name)
# SurfacePoints field -> the per-material table it is read from (material-backed points)
_TABLE_COLUMN = {"kind": "kind", "diffuse": "diffuse", "specular": "specular", "transmittance": "transm",
                 "alpha": "alpha", "eta": "eta", "cond_eta": "cond_eta", "cond_k": "cond_k", "beckmann": "beck",
                 "nonlinear": "nonlin", "twosided": "twos", "spec_weight": "spec_weight", "coat_row": "coat"}
_TABLES: dict = {}


def _material_tables(materials: list[Material]) -> dict:
    """Per-material parameter tables, built once per materials list.

    Materials are treated as immutable (scene edits replace the Material object), so the key
    is the objects' identities; the cache holds the objects, so identities are not reused.
    """
    key = tuple(id(mat) for mat in materials)
    hit = _TABLES.get(key)
    if hit is not None:
        return hit[1]
    m = len(materials)

    def table(fn, width=None, dtype=np.float32, null=0):
        rows = [fn(mat) for mat in materials]
        shape = (m + 1,) if width is None else (m + 1, width)
        t = np.empty(shape, dtype)
        if m:
            t[:m] = np.asarray(rows, dtype=dtype).reshape((m,) + shape[1:])
        t[m] = null
        return t

    def const_rgb(tex):
        return tex.rgb if tex.is_constant else tex.mean()

    def sw(mat):
        d = float(np.mean(mat.diffuse.mean()))
        s = float(np.mean(mat.specular.mean()))
        return s / (d + s) if d + s > 0 else 0.5

    tables = {
        "kind": table(lambda t: t.kind, dtype=np.int8, null=NULL),
        "diffuse": table(lambda t: const_rgb(t.diffuse), 3),
        "specular": table(lambda t: const_rgb(t.specular), 3),
        "transm": table(lambda t: const_rgb(t.specular_transmittance), 3),
        "alpha": table(lambda t: max(float(t.alpha), 1e-4), null=0.1),
        "eta": table(lambda t: float(t.int_ior) / float(t.ext_ior), null=1.5),
        "cond_eta": table(lambda t: np.broadcast_to(np.asarray(t.eta, np.float64), (3,)), 3),
        "cond_k": table(lambda t: np.broadcast_to(np.asarray(t.k, np.float64), (3,)), 3),
        "beck": table(lambda t: str(t.distribution).lower() == "beckmann", dtype=bool, null=True),
        "nonlin": table(lambda t: bool(t.nonlinear), dtype=bool, null=False),
        "twos": table(lambda t: bool(t.twosided), dtype=bool, null=False),
        "spec_weight": table(sw, null=0.5),
    }
    rough = np.isin(tables["kind"], ROUGH_PLASTIC_KINDS)
    coat = np.zeros(m + 1, np.int64)
    if rough.any():  # tables of every rough plastic of the list, computed once per process
        coat[rough] = coat_tables.rows(tables["alpha"][rough], tables["eta"][rough], tables["beck"][rough])
    tables["coat"] = coat
    # Colours and IORs held in float64 (their float32 values, exactly): pack() hands them to the
    # kernels without a copy per call. alpha stays float32: it is compared with thresholds.
    for name in ("diffuse", "specular", "transm", "eta", "cond_eta", "cond_k", "spec_weight"):
        tables[name] = tables[name].astype(np.float64)
    # materials with a texture to look up per point (gather runs per bounce: not recomputed there)
    tables["textured"] = [i for i, mat in enumerate(materials)
                          if mat.has_texture or not mat.specular_transmittance.is_constant]
    tables["textured_mask"] = np.isin(np.arange(m + 1), tables["textured"])
    if len(_TABLES) > 16:
        _TABLES.clear()
    _TABLES[key] = (tuple(materials), tables)
    return tables



def gather(materials: list[Material], mat_ids: np.ndarray, uv: np.ndarray | None) -> SurfacePoints:
    """Build :class:`SurfacePoints` for points with material indices ``mat_ids`` (negative: NULL)
    looking textures up at ``uv`` (N, 2) (None: uv = 0). The points are material-backed (fields
    read from per-material tables when used); only bitmap textures are evaluated, once per
    material over that material's points, into colours held per point."""
    mat_ids = np.asarray(mat_ids, dtype=np.int64).ravel()
    n = len(mat_ids)
    m = len(materials)
    ids = np.where((mat_ids < 0) | (mat_ids >= m), m, mat_ids)  # m = the appended NULL row

    t = _material_tables(materials)
    held = {}
    textured = t["textured"]
    if textured and n and t["textured_mask"][ids].any():
        uvs = np.zeros((n, 2), np.float64) if uv is None else np.asarray(uv)
        for i in textured:
            sel = np.nonzero(ids == i)[0]
            if not len(sel):
                continue
            mat = materials[i]
            for tex, name, column in ((mat.diffuse, "diffuse", "diffuse"), (mat.specular, "specular", "specular"),
                                      (mat.specular_transmittance, "transmittance", "transm")):
                if not tex.is_constant:
                    if name not in held:  # take() copies rows ~4x faster than fancy indexing
                        held[name] = t[column].take(ids, axis=0)
                    held[name][sel] = np.asarray(tex.eval(uvs[sel]), np.float32)  # a texel's float32 value
    return SurfacePoints._backed(t, ids, held)


def packed_rows(sp: SurfacePoints) -> tuple[tuple, np.ndarray]:
    """``(P, row)``: the kernels' packed parameters holding point j's at row ``row[j]``.
    Material-backed points that hold no field of their own read their material's row of one P
    per materials list (built once): no per-point copy of the 17 parameter arrays. Otherwise
    ``(pack(sp), arange)``, kept on the points until a field of theirs is set (a tile's end
    points are packed for their albedo, their BSDF rays and their gather). The values are the
    same either way."""
    d = sp.__dict__
    if "_tables" in d and not d["_held"]:
        t = d["_tables"]
        P = t.get("packed")
        if P is None:
            m = len(t["kind"]) - 1
            P = t["packed"] = pack(SurfacePoints._backed(t, np.arange(m + 1, dtype=np.int64), {}))
        return P, d["_rows"]
    hit = d.get("_packed_rows")
    if hit is None:
        hit = d["_packed_rows"] = (pack(sp), np.arange(len(sp), dtype=np.int64))
    return hit


def material_packed(materials: list[Material]) -> tuple[tuple, np.ndarray]:
    """``(P, textured)``: the kernels' packed parameters with material i's at row i (the NULL
    kind at row len(materials)) — what :func:`packed_rows` hands out for material-backed points
    — and per row whether the material looks a texture up per point (its points' row of P
    would not hold their values)."""
    t = _material_tables(materials)
    P, _rows = packed_rows(SurfacePoints._backed(t, np.zeros(0, np.int64), {}))
    return P, t["textured_mask"]


def material_kinds(materials: list) -> np.ndarray:
    """(m + 1,) int8: each material row's kind, NULL at row m (the materials' table, made once
    per materials list: read it, do not write it)."""
    return _material_tables(materials)["kind"]


def texture_atlas(materials: list) -> tuple:
    """The materials' bitmap textures for compiled lookups (common.kernels.texture.texel):
    ``(pixels float32 flat, tex int64 (T, 3) = base, height, width, xform float64 (T, 4) =
    uv scale and offset, nearest bool (T,), mat_tex int64 (m + 1, 3))`` — texture ids of each
    material row's diffuse, specular and transmittance (-1: constant; the NULL row none). Made
    once per materials list."""
    t = _material_tables(materials)
    if "atlas" not in t:
        parts, tex, xform, nearest = [], [], [], []
        mat_tex = np.full((len(materials) + 1, 3), -1, np.int64)
        base = 0
        for i, mat in enumerate(materials):
            for c, texture in enumerate((mat.diffuse, mat.specular, mat.specular_transmittance)):
                if texture.is_constant:
                    continue
                img = np.ascontiguousarray(texture.image, dtype=np.float32)
                mat_tex[i, c] = len(tex)
                tex.append((base, img.shape[0], img.shape[1]))
                xform.append((*texture.uv_scale, *texture.uv_offset))
                nearest.append(texture.filter == "nearest")
                parts.append(img.reshape(-1))
                base += img.size
        t["atlas"] = (np.concatenate(parts) if parts else np.zeros(0, np.float32),
                      np.array(tex, np.int64).reshape(-1, 3), np.array(xform, np.float64).reshape(-1, 4),
                      np.array(nearest, bool), mat_tex)
    return t["atlas"]


def split_smooth(kind: np.ndarray, alpha: np.ndarray, glossy_split_alpha: float) -> np.ndarray:
    """(N,) bool: the points split at their hit per BSDF component (paper §4): rough conductors
    and plastics smoother than ``glossy_split_alpha``, and every smooth plastic (its coat a
    mirror: no VPL can light it, so unsplit it would reflect nothing but emitters, and that
    through the filter); none where ``glossy_split_alpha`` is 0. Defined once for the eye
    paths, their kernels' material tables and the filter's choice of end points."""
    rough = kind_in(kind, (ROUGHCONDUCTOR, ROUGHPLASTIC)) & (alpha < glossy_split_alpha)
    return (rough | (kind == PLASTIC)) & (glossy_split_alpha > 0)


# Along a chain a smooth plastic is split only while its path still carries this much light
# (throughput luminance): a coat's mirror ray (~4-10% of the light) that meets another smooth
# plastic ends there, the plastic whole, or a room of plastics splits every ray again at every
# bounce (stop 65: 9 end points a pixel in a plastic box, 5-7x the frame time). Rough glossy
# hits keep splitting: left whole, the VPLs light their lobes in spikes (the same rule for them
# cost modern-hall 50% more error at equal time).
SPLIT_THROUGHPUT = 0.25


def split_eligible(kind: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows that may split along a chain: all but smooth plastics whose path's
    throughput ``thr`` (N, 3) has a luminance below SPLIT_THROUGHPUT (weighed as the compiled
    chains weigh it: the same terms in the same order)."""
    return (kind != PLASTIC) | (thr[:, 0] * _WR + thr[:, 1] * _WG + thr[:, 2] * _WB >= SPLIT_THROUGHPUT)


def split_layer(sp: SurfacePoints, layer: np.ndarray) -> SurfacePoints:
    """``sp`` with the split plastics among the points ``layer`` (bool) reduced to their diffuse
    layer, the end point of a split (the lobe goes on as a ray): a rough plastic relabelled
    ROUGHPLASTIC_DIFFUSE, a smooth one with its coat's reflection taken out (specular colour and
    sampling weight 0: its diffuse term, which holds the coat's transmission, is unchanged, and
    it never samples the mirror)."""
    rough = layer & (sp.kind == ROUGHPLASTIC)
    smooth = layer & (sp.kind == PLASTIC)
    changes = {}
    if rough.any():
        changes["kind"] = np.where(rough, ROUGHPLASTIC_DIFFUSE, sp.kind).astype(sp.kind.dtype)
    if smooth.any():
        changes["specular"] = np.where(smooth[:, None], 0.0, sp.specular)
        changes["spec_weight"] = np.where(smooth, 0.0, sp.sampling_weight())
    return sp.replaced(**changes) if changes else sp


def chain_materials(materials: list, glossy_split_alpha: float = 0.0) -> tuple | None:
    """``(P, kind, specular, smooth, P_lobe)`` per material row (the NULL kind at row
    len(materials)) for the compiled paths (worker.kernels.eye_paths, specular_chain,
    light_paths): the materials' packed parameters, kind, whether mirror/glass, whether a
    smooth glossy one split off at ``glossy_split_alpha`` (worker.shading._split_smooth), and P
    with each rough plastic's kind its lobe's (:func:`lobe_only`). None where the numpy loops
    must run: a mirror/glass material, or a smooth glossy one split off, looks its specular or
    transmittance colour up in a bitmap per point (the kernels read their material's row of P
    for those; a bitmap diffuse colour is looked up per end point after them)."""
    t = _material_tables(materials)
    key = ("chains", float(glossy_split_alpha))
    if key not in t:  # (asked per tile and chain: worked out once per materials list and alpha)
        P, _textured = material_packed(materials)
        sp = gather(materials, np.arange(len(materials) + 1), None)
        specular = kind_in(sp.kind, SPECULAR_KINDS)
        smooth = split_smooth(sp.kind, sp.alpha, glossy_split_alpha)
        P_lobe = (np.where(P[0] == ROUGHPLASTIC, ROUGHPLASTIC_LOBE, P[0]).astype(P[0].dtype),) + tuple(P[1:])
        # The kernels read the material rows of P where they sample a mirror/glass component or
        # a split lobe: the specular and transmittance colours, never the diffuse one (a split
        # plastic's diffuse layer is an end point, its colour looked up per point later).
        lobe_tex = np.array([not (mat.specular.is_constant and mat.specular_transmittance.is_constant)
                             for mat in materials] + [False], bool)
        per_point = (lobe_tex & (specular | smooth)).any()
        t[key] = None if per_point else (P, np.ascontiguousarray(sp.kind), specular, smooth, P_lobe)
    return t[key]


def carrying(weight: np.ndarray) -> np.ndarray:
    """(N,) bool: rows of the (N, 3) ``weight`` that carry light — positive in some channel,
    finite in all (column by column: numpy's axis=1 any/all cost ~9x more)."""
    w0, w1, w2 = weight[:, 0], weight[:, 1], weight[:, 2]
    return ((w0 > 0) | (w1 > 0) | (w2 > 0)) & np.isfinite(w0) & np.isfinite(w1) & np.isfinite(w2)


def finite_or_zero(a: np.ndarray) -> np.ndarray:
    """``a`` with NaN and ±Inf set to 0 (``np.nan_to_num(a, nan=0, posinf=0, neginf=0)``, the
    same values, in one pass instead of nan_to_num's four: it runs per tile and bounce)."""
    return np.where(np.isfinite(a), a, 0.0)


def is_delta(kind) -> np.ndarray:
    """Kinds that are purely delta (eval/pdf always 0): conductor, dielectric, thindielectric,
    roughdielectric (sampled as a delta)."""
    return kind_in(kind, DELTA_KINDS)


def has_delta(sp: SurfacePoints) -> np.ndarray:
    """Points whose BSDF has any delta component (the pure delta kinds and smooth plastic)."""
    return kind_in(sp.kind, HAS_DELTA_KINDS)


# ----------------------------------------------------------------------------------------------
# packing for the compiled kernels


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _coat_rows(sp: SurfacePoints) -> np.ndarray:
    """Per-point coat table rows: gather's when present, else one lookup per distinct coat."""
    if sp.coat_row is not None:
        return np.ascontiguousarray(sp.coat_row, dtype=np.int64)
    return _lookup_coat_rows(sp, np.zeros(len(sp), np.int64))


def _lookup_coat_rows(sp: SurfacePoints, rows: np.ndarray) -> np.ndarray:
    """``rows`` with every rough-plastic point lacking a row (row 0) filled in (a copy)."""
    need = kind_in(sp.kind, ROUGH_PLASTIC_KINDS) & (rows == 0)
    rows = rows.copy()
    if need.any():
        rows[need] = coat_tables.rows(sp.alpha[need], sp.eta[need], sp.beckmann[need])
    return rows


def pack(sp: SurfacePoints) -> tuple:
    """The kernels' per-point parameter tuple (common.kernels.bsdf documents the layout)::

        (kind int8[n], diffuse f64[n,3], specular f64[n,3], transm f64[n,3], alpha f64[n],
         eta f64[n], cond_eta f64[n,3], cond_k f64[n,3], beck bool[n], nonlin bool[n],
         twos bool[n], spec_weight f64[n], rtabs f64[G,R], rrefl f64[G,R], rrow int64[n],
         fdr_int f64[n], tavg f64[n])
    """
    kind = np.ascontiguousarray(sp.kind, dtype=np.int8)
    eta = _f64(sp.eta)
    rows = _coat_rows(sp)
    n = len(kind)
    fdr_int = np.empty(n)
    tavg = np.empty(n)
    rtabs, rrefl, reg_fdr, reg_tavg = coat_tables.tables()  # after the rows: covers them
    if kb.coat_columns(kind, eta, rows, reg_fdr, reg_tavg, fdr_int, tavg):
        # rough plastics without a row (relabelled or hand-built points): look them up
        rows = _lookup_coat_rows(sp, rows)
        rtabs, rrefl, reg_fdr, reg_tavg = coat_tables.tables()
        kb.coat_columns(kind, eta, rows, reg_fdr, reg_tavg, fdr_int, tavg)
    return (kind, _f64(sp.diffuse), _f64(sp.specular), _f64(sp.transmittance), _f64(sp.alpha), eta,
            _f64(sp.cond_eta), _f64(sp.cond_k), np.ascontiguousarray(sp.beckmann, dtype=bool),
            np.ascontiguousarray(sp.nonlinear, dtype=bool), np.ascontiguousarray(sp.twosided, dtype=bool),
            _f64(sp.sampling_weight()), rtabs, rrefl, rows, fdr_int, tavg)


def _dtype(*arrays) -> np.dtype:
    """The float type results are returned in: the inputs' (float32 stays float32)."""
    return np.result_type(*[np.asarray(a).dtype for a in arrays], np.float32)


def _dirs(w, n_points: int) -> np.ndarray:
    w = _f64(w).reshape(-1, 3)
    if len(w) != n_points:
        raise ValueError(f"{len(w)} directions for {n_points} surface points")
    return w


def coat_transmittance(sp: SurfacePoints) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rough plastics' coat transmittance tables t(cos θ) for a compiled evaluation:
    ``(tables (G, R) float64, row (n,) int64, t_avg (n,))`` with t_avg the cosine-weighted mean
    (as :func:`albedo` uses), so the diffuse layer per unit albedo is cos/π · t(cos)/t_avg.
    Points that are not rough plastics get row 0 (t = 1)."""
    P, row = packed_rows(sp)
    return P[12], P[14].take(row), P[16].take(row)


# ----------------------------------------------------------------------------------------------
# public API (the math: common.kernels.bsdf)


def eval(sp: SurfacePoints, wi: np.ndarray, wo: np.ndarray, mode: str = "radiance") -> np.ndarray:  # noqa: A001
    """f(wi, wo) |cos theta_o| for the non-delta components; (N, 3).

    ``mode`` is accepted for symmetry: none of the non-delta lobes here is non-symmetric."""
    return _eval_pdf(sp, wi, wo)[0]


def pdf(sp: SurfacePoints, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Solid-angle density with which :func:`sample` draws ``wo`` through a non-delta component
    (component selection included, so it integrates to the non-delta share); (N,)."""
    return _eval_pdf(sp, wi, wo)[1]


def _eval_pdf(sp, wi, wo):
    dt = _dtype(wi, wo)
    n = len(sp)
    wi, wo = _dirs(wi, n), _dirs(wo, n)
    rgb = np.empty((n, 3))
    p = np.empty(n)
    kb.eval_many(*packed_rows(sp), wi, wo, rgb, p)
    return rgb.astype(dt, copy=False), p.astype(dt, copy=False)


def sample(sp: SurfacePoints, wi: np.ndarray, u1: np.ndarray, u2: np.ndarray, mode: str = "radiance"):
    """Importance-sample ``wo`` given ``wi``; ``u1`` (N,) picks the component, ``u2`` (N, 2).

    Returns ``(wo (N,3), weight (N,3), pdf (N,), delta (N,) bool)``. Non-delta samples:
    weight = eval/pdf, pdf the solid-angle density (== :func:`pdf`). Delta samples: weight the
    delta weight (Mitsuba's, i.e. value / lobe probability), pdf the discrete lobe probability.
    Failed samples (and NULL) have weight 0, pdf 0, delta False.
    """
    dt = _dtype(wi)
    n = len(sp)
    wi = _dirs(wi, n)
    u1 = _f64(u1).ravel()
    u2 = _f64(u2).reshape(-1, 2)
    wo = np.empty((n, 3))
    weight = np.empty((n, 3))
    p = np.empty(n)
    delta = np.empty(n, bool)
    kb.sample_many(*packed_rows(sp), wi, u1, u2, mode == "radiance", wo, weight, p, delta)
    return wo.astype(dt, copy=False), weight.astype(dt, copy=False), p.astype(dt, copy=False), delta


_ALBEDO_POINTS: dict[int, np.ndarray] = {}


def albedo_points(samples: int) -> np.ndarray:
    """(samples, 3) the fixed scrambled Sobol' points of :func:`directional_albedo`."""
    pts = _ALBEDO_POINTS.get(samples)
    if pts is None:
        from scipy.stats import qmc
        pts = _ALBEDO_POINTS[samples] = qmc.Sobol(3, scramble=True, seed=0x5EED).random(samples)
    return pts


def directional_albedo(sp: SurfacePoints, wi: np.ndarray, samples: int = 256) -> np.ndarray:
    """(N, 3) directional albedo ∫ f(wi, wo) |cos θo| dωo of each point, estimated by its own
    importance sampling over one fixed set of ``samples`` scrambled Sobol' points (the same for
    every point and call, so two BSDFs compared at one wi share most of their quadrature error).
    Unlike :func:`albedo` (a smooth estimate for demodulation) it includes what single-scattering
    microfacets lose to shadowing at their roughness."""
    n = len(sp)
    if n == 0:
        return np.zeros((0, 3))
    u = albedo_points(samples)
    big = sp.subset(np.repeat(np.arange(n), samples))
    _wo, w, _p, _delta = sample(big, np.repeat(_dirs(wi, n), samples, axis=0), np.tile(u[:, 0], n),
                                np.tile(u[:, 1:], (n, 1)))
    return w.reshape(n, samples, 3).mean(axis=1)


def sample_lobe(sp: SurfacePoints, wi: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample only the glossy lobe of rough conductors and plastics (the paper's split of an
    eye path per BSDF component): ``(wo (N, 3), weight (N, 3))`` with weight = lobe value ×
    cos / lobe pdf, for a smooth plastic its coat's mirror direction and weight F × specular (a
    delta: no pdf); the diffuse layer of a plastic is left to :func:`split_layer`. Other kinds
    give weight 0."""
    dt = _dtype(wi)
    n = len(sp)
    wi = _dirs(wi, n)
    u2 = _f64(u2).reshape(-1, 2)
    wo = np.empty((n, 3))
    weight = np.empty((n, 3))
    kb.sample_lobe_many(*packed_rows(sp), wi, u2, wo, weight)
    return wo.astype(dt, copy=False), weight.astype(dt, copy=False)


def lobe_only(sp: SurfacePoints) -> SurfacePoints:
    """The glossy lobes that :func:`sample_lobe` samples, as BSDFs of their own: a rough
    plastic's coat reflection (ROUGHPLASTIC_LOBE), a rough conductor whole. eval/pdf/albedo of
    the result are the lobe's alone, its pdf the density of :func:`sample_lobe`'s directions
    (MIS between a split lobe's traced ray and its light samples)."""
    rp = sp.kind == ROUGHPLASTIC
    if not rp.any():
        return sp
    return sp.replaced(kind=np.where(rp, ROUGHPLASTIC_LOBE, sp.kind).astype(sp.kind.dtype))


def glass_lobes(sp: SurfacePoints, lobe, rows: np.ndarray | None = None) -> SurfacePoints:
    """Rough glass points (of ``rows``, a mask; None: all) as one lobe of theirs alone, ``lobe``
    (per point or one for all) ROUGHDIELECTRIC_R (the reflection, on wi's side) or
    ROUGHDIELECTRIC_T (the refraction, to the other side): eval/pdf/albedo of the result are that
    lobe's, its pdf the density with which the crossing draws the direction (design note 48)."""
    glass = sp.kind == ROUGHDIELECTRIC
    if rows is not None:
        glass &= rows
    if not glass.any():
        return sp
    return sp.replaced(kind=np.where(glass, lobe, sp.kind).astype(sp.kind.dtype))


def outward_lobe(wi: np.ndarray) -> np.ndarray:
    """Per point seen from local ``wi``, rough glass's lobe that faces its outside (ng's side,
    where the emitters are): from outside its reflection (ROUGHDIELECTRIC_R), from inside its
    refraction out (ROUGHDIELECTRIC_T) — kernels.bsdf.glass_lobe_pdf's choice for wo outside."""
    return np.where(np.asarray(wi)[:, 2] > 0, ROUGHDIELECTRIC_R, ROUGHDIELECTRIC_T)


def specular_components(sp: SurfacePoints, wi: np.ndarray, mode: str = "radiance", u2: np.ndarray | None = None):
    """Deterministic split of an eye path at delta surfaces.

    Returns ``[(wo, weight, valid), (wo, weight, valid)]``: entry 0 the delta reflection, entry 1
    the delta transmission (see the module docstring for which kinds have which). Weights carry
    the Fresnel factor and the specular textures (no lobe-selection division); the dielectric
    transmission is scaled by eta_ti^2 in radiance mode, as Mitsuba does. ``u2`` (N, 2) draws
    a rough dielectric's microfacet normal (None: none may be a rough dielectric).
    """
    dt = _dtype(wi)
    n = len(sp)
    wi = _dirs(wi, n)
    if u2 is None:
        if (sp.kind == ROUGHDIELECTRIC).any():  # (one fixed microfacet would be a biased answer)
            raise ValueError("specular_components: a rough dielectric needs u2 to draw its microfacet normals")
        u2 = np.full((n, 2), 0.5)
    u2 = _f64(u2).reshape(-1, 2)
    r_wo, r_w, t_wo, t_w = (np.empty((n, 3)) for _ in range(4))
    kb.specular_many(*packed_rows(sp), wi, mode == "radiance", u2, r_wo, r_w, t_wo, t_w)
    r_w = r_w.astype(dt, copy=False)
    t_w = t_w.astype(dt, copy=False)
    return [(r_wo.astype(dt, copy=False), r_w, np.any(r_w > 0, axis=-1)),
            (t_wo.astype(dt, copy=False), t_w, np.any(t_w > 0, axis=-1))]


def albedo(sp: SurfacePoints, wi: np.ndarray) -> np.ndarray:
    """Smooth per-point reflectance estimate (N, 3) used to demodulate radiance.

    diffuse: diffuse reflectance; conductors: Fresnel at normal incidence x specular; plastics:
    the diffuse layer's directional albedo (diffuse/(1-Fdr_int) x inv_eta^2 x T_in x mean T_out)
    + the coat's directional reflectance x specular; dielectrics: R0 x specular + (1-R0) x transmittance;
    NULL: 0. Evaluated at |cos theta_i| (clamped away from 0), so it stays > 0 on back faces and at
    grazing angles wherever the material has any nonzero reflectance.
    """
    dt = _dtype(wi)
    n = len(sp)
    wi = _dirs(wi, n)
    out = np.empty((n, 3))
    kb.albedo_many(*packed_rows(sp), wi, out)
    return out.astype(dt, copy=False)
