"""Mitsuba BSDFs and textures -> :class:`common.scene.Material` / :class:`common.scene.Texture`
(the subset and fallbacks are listed in :mod:`common.mitsuba_xml`). Plain functions of the
loader at work (:class:`common.mitsuba_xml._Loader`): its scene lists, caches and diagnostics."""
from __future__ import annotations

import math

import numpy as np

from . import transform as tf
from .mitsuba_doc import Node, Props, fmt_rgb
from .mitsuba_principled import load_principled
from .scene import (CONDUCTOR, DIELECTRIC, DIFFUSE, NULL, PLASTIC, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC,
                    THINDIELECTRIC, Material, SceneError, Texture)

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


def load_texture(loader, node: Node) -> Texture:
    node = loader.deref(node)
    if node.tag != "texture":
        return Texture.constant(loader.color(node))
    key = id(node)
    if key in loader.texture_of:
        return loader.texture_of[key]
    p = Props(loader, node)
    kind = p.type
    if kind == "bitmap":
        fn = p.string("filename")
        if fn is None:
            raise loader.error(node, "<texture type='bitmap'> needs a 'filename'")
        path = loader.resolve(fn, node)
        raw = p.bool("raw", False)
        ft = p.string("filter_type", "bilinear")
        if ft not in ("bilinear", "nearest"):
            loader.warn(node, f"filter_type '{ft}'", "using bilinear")
            ft = "bilinear"
        wrap = p.string("wrap_mode", "repeat")
        if wrap != "repeat":
            loader.warn(node, f"wrap_mode '{wrap}' is not supported", "using repeat")
        uv_scale, uv_offset = _to_uv(loader, p)
        ikey = (str(path.resolve()), raw)
        if ikey not in loader.images:
            from .image_io import read_image

            try:
                loader.images[ikey] = read_image(path, raw=raw)
            except SceneError as e:
                raise SceneError(f"{e} (referenced at {node.where})") from None
        t = Texture(image=loader.images[ikey], filter=ft, uv_scale=uv_scale, uv_offset=uv_offset, name=fn)
        p.finish(ignore=("format",))
    elif kind == "checkerboard":
        # Mitsuba's: color0 where (u mod 1 > ½) == (v mod 1 > ½), else color1 — a 2 × 2 bitmap
        # looked up nearest (rows as Mitsuba's bitmaps: row j covers v in [j/2, (j+1)/2))
        c0 = p.rgb("color0", 0.4)
        c1 = p.rgb("color1", 0.2)
        uv_scale, uv_offset = _to_uv(loader, p)
        image = np.array([[c0, c1], [c1, c0]], np.float32)
        t = Texture(image=image, filter="nearest", uv_scale=uv_scale, uv_offset=uv_offset, name="checkerboard")
        p.finish()
    else:
        vals = [loader.color(c) for c in node.children if c.tag in ("rgb", "spectrum", "float")]
        mean = np.mean(vals, axis=0) if vals else np.full(3, 0.5)
        loader.warn(node, f"texture '{kind}' is not supported", f"using constant {fmt_rgb(mean)}")
        t = Texture.constant(mean)
    loader.texture_of[key] = t
    return t


def _to_uv(loader, p: Props) -> tuple[tuple[float, float], tuple[float, float]]:
    """A texture's ``to_uv`` as the (uv_scale, uv_offset) of :class:`Texture` (scale and
    translation; rotation and shear are dropped with a warning)."""
    m = p.transform("to_uv")
    if tf.is_identity(m):
        return (1.0, 1.0), (0.0, 0.0)
    if abs(m[0, 1]) > 1e-12 or abs(m[1, 0]) > 1e-12:
        loader.warn(p.named["to_uv"], "rotated/sheared to_uv is not supported", "using its diagonal")
    sx, sy, tx, ty = m[0, 0], m[1, 1], m[0, 3], m[1, 3]
    # Meshes store v_scene = 1 - v_mitsuba; Mitsuba looks up row (sy v + ty) H.
    return (float(sx), float(sy)), (float(tx), float(1.0 - sy - ty))


def material_index(loader, node: Node | None, emitting: bool = False) -> int:
    """The material row of a shape's BSDF ``node``. Without one, Mitsuba's default: a diffuse of
    reflectance 0.5 — or 0 on a shape that carries an emitter (Mitsuba 3's Shape does so: a lamp
    does not reflect the room's light; 0.5 there made light walks bounce off it, +8% indirect
    light in an open scene lit by a bare rectangle)."""
    if node is None:
        key = "default emitter" if emitting else "default"
        if key not in loader.default_materials:
            loader.materials.append(Material(name=key, kind=DIFFUSE,
                                             diffuse=Texture.constant(0.0 if emitting else 0.5)))
            loader.default_materials[key] = len(loader.materials) - 1
        return loader.default_materials[key]
    node = loader.deref(node)
    key = id(node)
    if key not in loader.material_of:
        mat = load_bsdf(loader, node)
        loader.materials.append(mat)
        loader.material_of[key] = len(loader.materials) - 1
    return loader.material_of[key]


def _nested_bsdfs(loader, p: Props) -> list[Node]:
    out = []
    for c in p.children + list(p.named.values()):
        t = loader.deref(c)
        if t.tag == "bsdf":
            out.append(t)
    return out


def load_bsdf(loader, node: Node, name: str | None = None) -> Material:
    if node.tag != "bsdf":
        raise loader.error(node, f"{node.describe()} is not a <bsdf>")
    p = Props(loader, node)
    kind = p.type
    name = name or node.attrib.get("id", f"{kind}@{node.line}")
    if kind == "twosided":
        inner = _nested_bsdfs(loader, p)
        for k in list(p.named):
            p.get(k)
        if not inner:
            raise loader.error(node, "<bsdf type='twosided'> needs a nested BSDF")
        if len(inner) > 1:
            loader.warn(node, "twosided with two different BSDFs is not supported", "using the front BSDF on both sides")
        mat = load_bsdf(loader, inner[0], name)
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
                loader.warn(p.named["material"], "conductor with both 'material' and 'eta'/'k'", "using eta/k")
        elif material == "none":
            mat.eta, mat.k = np.zeros(3), np.zeros(3)  # perfect mirror (scene.py convention)
        elif material in CONDUCTORS:
            eta, k = CONDUCTORS[material]
            mat.eta, mat.k = np.array(eta), np.array(k)
        else:
            raise loader.error(p.named["material"], f"unknown conductor material '{material}' "
                                                  f"(known: none, {', '.join(sorted(CONDUCTORS))})")
        if kind == "roughconductor":
            _roughness(loader, p, mat, node)
    elif kind in ("dielectric", "thindielectric", "roughdielectric"):
        mat = Material(name=name, kind={"dielectric": DIELECTRIC, "thindielectric": THINDIELECTRIC,
                                        "roughdielectric": ROUGHDIELECTRIC}[kind],
                       int_ior=p.ior("int_ior", 1.5046), ext_ior=p.ior("ext_ior", 1.000277),
                       specular=p.texture("specular_reflectance", 1.0),
                       specular_transmittance=p.texture("specular_transmittance", 1.0))
        if p.has("eta"):
            eta = p.float("eta")
            mat.int_ior, mat.ext_ior = float(eta), 1.0
        if kind == "roughdielectric":
            _roughness(loader, p, mat, node)
    elif kind in ("plastic", "roughplastic"):
        mat = Material(name=name, kind=PLASTIC if kind == "plastic" else ROUGHPLASTIC,
                       diffuse=p.texture("diffuse_reflectance", 0.5),
                       specular=p.texture("specular_reflectance", 1.0),
                       int_ior=p.ior("int_ior", 1.49), ext_ior=p.ior("ext_ior", 1.000277),
                       nonlinear=p.bool("nonlinear", False))
        if kind == "roughplastic":
            _roughness(loader, p, mat, node)
    elif kind in ("principled", "principledthin"):
        return load_principled(loader, node, p, name, thin=kind == "principledthin")
    elif kind == "null":
        loader.warn(node, "bsdf 'null' (pass-through) is not supported", "using a black (NULL) material")
        mat = Material(name=name, kind=NULL, diffuse=Texture.constant(0.0))
    elif kind == "mask":
        inner = _nested_bsdfs(loader, p)
        opacity = p.texture("opacity", 0.5)
        if inner:
            mat = load_bsdf(loader, inner[0], name)
        else:
            loader.warn(node, "bsdf 'mask' without a nested BSDF", "using diffuse 0.5 under the mask")
            mat = Material(name=name, kind=DIFFUSE)
        mat.opacity = opacity
        src = p.named.get("opacity")
        if src is not None and loader.deref(src).attrib.get("type") == "checkerboard":
            loader.warn(src, "a checkerboard opacity is read as Mitsuba's checkerboard paints colours (eval)",
                        "Mitsuba 3.9.1's mask reads it through eval_1, which swaps its colours")
        p.finish()
        return mat
    elif kind in ("normalmap", "bumpmap"):
        return _load_perturbed(loader, node, p, name, kind)
    elif kind == "blendbsdf":
        inner = _nested_bsdfs(loader, p)
        if kind == "blendbsdf" and len(inner) > 1:
            # (1 - weight) × the first + weight × the second: the one weighing more stands for both
            t = p.texture("weight", 0.5) if p.has("weight") else Texture.constant(0.5)
            w = float(np.mean(t.mean()))
            pick = int(w > 0.5)
            mean_of = "" if t.is_constant else ", its texture's mean"
            loader.warn(node, "bsdf 'blendbsdf' is not supported",
                        f"using its {('first', 'second')[pick]} nested BSDF (weight {w:.3g}{mean_of})")
            return load_bsdf(loader, inner[pick], name)
        if inner:
            loader.warn(node, f"bsdf '{kind}' is not supported", "using its (first) nested BSDF")
            return load_bsdf(loader, inner[0], name)
        loader.warn(node, f"bsdf '{kind}' is not supported", "using diffuse 0.5")
        return Material(name=name, kind=DIFFUSE)
    else:
        loader.warn(node, f"unsupported bsdf '{kind}'", "using diffuse 0.5")
        return Material(name=name, kind=DIFFUSE)
    p.finish(ignore=("sample_visible", "specular_sampling_weight"))
    return mat


def _load_perturbed(loader, node: Node, p: Props, name: str, kind: str) -> Material:
    """Mitsuba's ``normalmap`` (its ``normalmap`` texture) and ``bumpmap`` (its one nested texture, a
    height, × ``scale``): the nested BSDF with the texture that perturbs its shading normal."""
    inner = _nested_bsdfs(loader, p)
    for k, c in p.named.items():  # (a named nested BSDF is read here, not an unknown parameter)
        if loader.deref(c).tag == "bsdf":
            p.get(k)
    if len(inner) > 1:
        raise loader.error(node, f"bsdf '{kind}' takes exactly one nested BSDF (has {len(inner)})")
    if inner:
        mat = load_bsdf(loader, inner[0], name)
    else:
        loader.warn(node, f"bsdf '{kind}' without a nested BSDF", "using diffuse 0.5 under it")
        mat = Material(name=name, kind=DIFFUSE)
    if mat.perturbs_normal:
        loader.warn(node, f"bsdf '{kind}' around another normal or bump map", "only the outer one is used")
        mat.normal_map = mat.bump_map = None
    if kind == "normalmap":
        if not p.has("normalmap"):
            raise loader.error(node, "bsdf 'normalmap' needs a texture named 'normalmap'")
        mat.normal_map = p.texture("normalmap", None)
    else:
        textures = [c for c in p.children if loader.deref(c).tag == "texture"]
        textures += [p.get(k) for k, c in p.named.items() if loader.deref(c).tag == "texture"]
        if len(textures) != 1:
            raise loader.error(node, f"bsdf 'bumpmap' needs exactly one nested texture (has {len(textures)})")
        mat.bump_map = loader.texture(textures[0])
        mat.bump_scale = p.float("scale", 1.0)
        if not math.isfinite(mat.bump_scale):
            raise loader.error(p.named["scale"], f"bumpmap scale {mat.bump_scale} is not finite")
    mat.flip_invalid_normals = p.bool("flip_invalid_normals", True)
    # Mitsuba's terminator softening (Conty Estevez et al. 2019) scales the BSDF by a function of
    # wo and the unperturbed normal, which igi's kernels do not carry: read, not modelled
    p.bool("use_shadowing_function", True)
    p.finish()
    return mat


def _roughness(loader, p: Props, mat: Material, node: Node) -> None:
    dist = p.string("distribution", "beckmann")
    if dist not in ("beckmann", "ggx"):
        raise loader.error(p.named["distribution"], f"unknown microfacet distribution '{dist}' (beckmann or ggx)")
    mat.distribution = dist
    if p.has("alpha_u") or p.has("alpha_v"):
        au, av = p.float("alpha_u", 0.1), p.float("alpha_v", 0.1)
        if au != av:
            loader.warn(node, "anisotropic roughness (alpha_u != alpha_v) is not supported",
                      f"using alpha = {math.sqrt(au * av):.4g}")
        mat.alpha = float(math.sqrt(au * av))
    else:
        n = p.named.get("alpha")
        if n is not None and loader.deref(n).tag == "texture":
            t = load_texture(loader, p.get("alpha"))
            loader.warn(n, "textured alpha is not supported", "using its mean")
            mat.alpha = float(t.mean()[0])
        else:
            mat.alpha = float(p.float("alpha", 0.1))
