#!/usr/bin/env python
"""Generate the envmap test assets in this folder (see README.md).

Usage (from the repository root or anywhere):

    python tests/data/envmap/make_assets.py                 # everything, full spp
    python tests/data/envmap/make_assets.py --no-render     # maps, XML, npz, lookup_ref only
    python tests/data/envmap/make_assets.py --outdoor-spp 64 --room-spp 64   # quick preview

Needs the ``mitsuba`` Python package (3.x; made with 3.9.1) and igi (for its EXR/PNG writers).
The assets were made with the ``scalar_rgb`` variant, which is the default (``--variant auto``):
``llvm_ad_rgb`` aborted inside LLVM 15 on the machine they were made on. ``--variant llvm_ad_rgb``
works where that backend does; results then differ only by Monte Carlo noise.
Run information (variant, spp, render seconds, sun directions, self-check errors) is merged into
``info.json`` next to this script.

Everything is deterministic for a given variant: the procedural maps are pure numpy, the random
directions use ``numpy.random.default_rng(0)``, renders use Mitsuba's ``independent`` sampler with
``seed=0``.
"""
from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]

from igi.common.image_io import read_image, write_exr, write_png  # noqa: E402

# ----------------------------------------------------------------------------------------------
# Procedural maps
# ----------------------------------------------------------------------------------------------
SKY_W, SKY_H = 128, 64
ZENITH = np.array([0.6, 0.8, 1.4])
HORIZON = np.array([1.2, 1.1, 0.9])
GROUND = np.array([0.15, 0.12, 0.10])
SUN_RADIANCE = np.array([4000.0, 3600.0, 3000.0])
# The sun is the 2x2 block of texels rows SUN_ROWS x columns SUN_COLS (row 0 = top of the image).
SUN_ROWS = (19, 20)
SUN_COLS = (42, 43)


def mitsuba_texel_uv(w, h):
    """Mitsuba 3 envmap texel positions: column i at u = (i + 0.5) / w, row j at v = j / (h - 1).

    (Mitsuba bilinearly interpolates with a half-texel shift in u only; in v the first row sits
    exactly on the zenith and the last row exactly on the nadir.)
    """
    u = (np.arange(w) + 0.5) / w
    v = np.arange(h) / (h - 1)
    return np.meshgrid(u, v)  # (h, w) each


def uv_to_local(u, v):
    """Mitsuba's lat-long convention: local direction (sin phi sin theta, cos theta, -cos phi sin theta)."""
    phi, theta = 2 * np.pi * np.asarray(u), np.pi * np.asarray(v)
    return np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], -1)


def sun_local_direction():
    """Centre of the sun's 2x2 block under Mitsuba's bilinear lookup (local frame, unit)."""
    u = (SUN_COLS[0] + 1.0) / SKY_W            # between the two column centres
    v = (SUN_ROWS[0] + 0.5) / (SKY_H - 1)      # between the two row positions
    return uv_to_local(u, v)


def make_sky():
    u, v = mitsuba_texel_uv(SKY_W, SKY_H)
    d = uv_to_local(u, v)
    phi = 2 * np.pi * u
    elev = np.pi / 2 - np.pi * v
    s = np.sin(np.clip(elev, 0, None))[..., None]
    t = (1.0 - s) ** 2
    sky = ZENITH * (1 - t) + HORIZON * t
    sun_d = sun_local_direction()
    sun_phi = np.arctan2(sun_d[0], -sun_d[2])
    # azimuthal variation: brighter towards the sun's azimuth, plus a small 3-fold ripple
    az = 1.0 + 0.25 * np.cos(phi - sun_phi) + 0.08 * np.cos(3 * phi)
    sky = sky * az[..., None]
    # warm circumsolar glow (smooth; the sun itself is the 2x2 block below)
    cosg = np.clip(d @ sun_d, -1, 1)
    gamma = np.arccos(cosg)
    sky = sky + np.array([1.5, 1.1, 0.6]) * np.exp(-(gamma / 0.3) ** 2)[..., None]
    ground = GROUND * (1.0 + 0.2 * np.cos(2 * phi))[..., None]
    img = np.where((elev > 0)[..., None], sky, ground)
    for r in SUN_ROWS:
        for c in SUN_COLS:
            img[r, c] = SUN_RADIANCE
    return img.astype(np.float32)


def make_pattern(w=16, h=8):
    x, y = np.meshgrid(np.arange(w), np.arange(h))
    img = np.stack([(x + 1) / w, (y + 1) / h, 0.5 + ((x * 7 + y * 3) % 5) / 10], -1)
    return img.astype(np.float32)


# ----------------------------------------------------------------------------------------------
# Scenes
# ----------------------------------------------------------------------------------------------
OUTDOOR_ROTATION = '<rotate y="1" angle="40"/>'
ROOM_ROTATION = '<rotate y="1" angle="190"/>'
LOOKUP_ROTATION = '<rotate x="1" angle="30"/>\n            <rotate y="1" angle="70"/>'

def _path_and_camera(max_depth: int, fov: float, origin: str, target: str, width: int, height: int) -> str:
    """The scenes' integrator and perspective sensor (fov along x, box-filtered RGB film)."""
    return f"""    <integrator type="path">
        <integer name="max_depth" value="{max_depth}"/>
    </integrator>

    <sensor type="perspective">
        <string name="fov_axis" value="x"/>
        <float name="fov" value="{fov:g}"/>
        <transform name="to_world">
            <lookat origin="{origin}" target="{target}" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="{width}"/>
            <integer name="height" value="{height}"/>
            <string name="pixel_format" value="rgb"/>
            <rfilter type="box"/>
        </film>
    </sensor>
"""


OUTDOOR_XML = f"""<?xml version="1.0" encoding="utf-8"?>
<!--
  igi envmap test scene "outdoor": a grey ground plane with a diffuse sphere and a diffuse cube,
  lit ONLY by the lat-long environment map sky.exr (procedural sky + a 2x2-texel sun), rotated by
  to_world. Own work for igi (tests/data/envmap/make_assets.py). Licence: CC0 1.0.
-->
<scene version="3.0.0">
{_path_and_camera(6, 50, "0, 1.8, 7", "0, 0.4, 0", 160, 120)}
    <bsdf type="diffuse" id="grey">
        <rgb name="reflectance" value="0.5, 0.5, 0.5"/>
    </bsdf>
    <bsdf type="diffuse" id="reddish">
        <rgb name="reflectance" value="0.7, 0.3, 0.2"/>
    </bsdf>
    <bsdf type="diffuse" id="greenish">
        <rgb name="reflectance" value="0.3, 0.6, 0.3"/>
    </bsdf>

    <shape type="rectangle" id="ground">
        <transform name="to_world">
            <scale x="30" y="30"/>
            <rotate x="1" angle="-90"/>
        </transform>
        <ref id="grey"/>
    </shape>
    <shape type="sphere" id="ball">
        <point name="center" x="-0.6" y="0.7" z="0.9"/>
        <float name="radius" value="0.7"/>
        <ref id="reddish"/>
    </shape>
    <shape type="cube" id="box">
        <transform name="to_world">
            <scale x="0.6" y="0.6" z="0.6"/>
            <rotate y="1" angle="30"/>
            <translate x="1.4" y="0.6" z="-0.6"/>
        </transform>
        <ref id="greenish"/>
    </shape>

    <emitter type="envmap" id="sky">
        <string name="filename" value="sky.exr"/>
        <float name="scale" value="1"/>
        <transform name="to_world">
            {OUTDOOR_ROTATION}
        </transform>
    </emitter>
</scene>
"""

LOOKUP_XML = f"""<?xml version="1.0" encoding="utf-8"?>
<!--
  igi envmap test scene "lookup": no geometry; a 90-degree camera at the origin looks straight at
  the 16x8 pattern.exr environment map (every texel a distinct colour), rotated by two rotations.
  For checking the lat-long lookup convention. Own work for igi (make_assets.py). Licence: CC0 1.0.
-->
<scene version="3.0.0">
{_path_and_camera(1, 90, "0, 0, 0", "0.8, 0.45, -0.6", 64, 48)}
    <emitter type="envmap" id="pattern">
        <string name="filename" value="pattern.exr"/>
        <transform name="to_world">
            {LOOKUP_ROTATION}
        </transform>
    </emitter>
</scene>
"""

ROOM_HEADER = """<!--
  igi envmap test scene "room": the bundled scene common/scenes/window-room/scene.xml with its two
  emitters (directional sun + constant sky) replaced by ONE lat-long environment map (sky.exr,
  procedural sky + 2x2-texel sun) whose to_world rotation sends the sun through the window opening
  onto the floor; film reduced to 160x120 with a box filter. Everything else is unchanged.
  Room: x in [-2, 2], y in [0, 2.5], z in [-3, 3]; window: x = -2, z in [-1.5, 0], y in [0.8, 2].
  Own work for igi (tests/data/envmap/make_assets.py). Licence: CC0 1.0.
-->"""

ROOM_EMITTER = f"""<emitter type="envmap" id="sky">
        <string name="filename" value="sky.exr"/>
        <float name="scale" value="1"/>
        <transform name="to_world">
            {ROOM_ROTATION}
        </transform>
    </emitter>"""


def make_room_xml():
    src = (REPO / "common" / "scenes" / "window-room" / "scene.xml").read_text()

    def sub1(pattern, repl, text, flags=re.S):
        out, n = re.subn(pattern, lambda m: repl, text, count=1, flags=flags)
        if n != 1:
            raise RuntimeError(f"room.xml: pattern not found: {pattern!r}")
        return out

    out = sub1(r"<!--.*?-->", ROOM_HEADER, src)
    out = sub1(r'<emitter type="directional" id="sun">.*?</emitter>\s*'
               r'<emitter type="constant" id="sky">.*?</emitter>', ROOM_EMITTER, out)
    out = sub1(r'<film type="hdrfilm">.*?</film>',
               '<film type="hdrfilm">\n'
               '            <integer name="width" value="160"/>\n'
               '            <integer name="height" value="120"/>\n'
               '            <string name="pixel_format" value="rgb"/>\n'
               '            <rfilter type="box"/>\n'
               '        </film>', out)
    if 'name="max_depth"' not in out:
        out = sub1(r'<integrator type="path">',
                   '<integrator type="path">\n        <integer name="max_depth" value="8"/>', out)
    return out


# ----------------------------------------------------------------------------------------------
# Mitsuba helpers
# ----------------------------------------------------------------------------------------------
def set_variant(mi, name):
    if name == "auto":
        # llvm_ad_rgb aborted inside LLVM (instruction selection) on the machine these assets were
        # made on; probing it in-process would kill this script, so "auto" means scalar_rgb unless
        # the llvm variant is asked for explicitly.
        name = "scalar_rgb"
    mi.set_variant(name)
    return name


def to_world_matrix(mi, scene):
    """The (single) emitter's to_world as a 4x4 float64 matrix."""
    (emitter,) = scene.emitters()
    params = mi.traverse(scene)
    key = f"{emitter.id()}.to_world"
    return np.array(params[key].matrix, dtype=np.float64)


def render(mi, scene_path, spp, seed=0):
    scene = mi.load_file(str(scene_path))
    t0 = time.time()
    img = mi.render(scene, spp=spp, seed=seed)
    img = np.array(img, dtype=np.float32)[..., :3]
    return np.ascontiguousarray(img), time.time() - t0


def mitsuba_eval_np(img, to_world, d):
    """numpy re-implementation of Mitsuba 3.9's envmap eval (for the self-check)."""
    h, w, _ = img.shape
    data = np.concatenate([img, img[:, :1]], axis=1).astype(np.float64)  # periodic column
    local = d @ np.linalg.inv(to_world[:3, :3]).T
    u = np.arctan2(local[:, 0], -local[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(local[:, 1], -1, 1)) / np.pi
    u = u - 0.5 / w
    u = u - np.floor(u)
    v = v - np.floor(v)
    x, y = u * w, v * (h - 1)
    x0 = np.minimum(x.astype(int), w - 1)
    y0 = np.minimum(y.astype(int), h - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    v0 = data[y0, x0] * (1 - fx) + data[y0, x0 + 1] * fx
    v1 = data[y0 + 1, x0] * (1 - fx) + data[y0 + 1, x0 + 1] * fx
    return v0 * (1 - fy) + v1 * fy


def mitsuba_pdf_np(img, to_world, d):
    """numpy re-implementation of Mitsuba 3.9's envmap pdf_direction (solid-angle density).

    The sampling density is a Hierarchical2D (piecewise-bilinear) warp over the (W+1) x H grid of
    luminance(texel) * sin(theta_j), theta_j = j pi / (H - 1), on [0, 1]^2 (u shifted by half a
    texel), divided by 2 pi^2 sin(theta) of the actual direction.
    """
    h, w, _ = img.shape
    lum = img.astype(np.float64) @ np.array([0.212671, 0.715160, 0.072169])
    lum = np.concatenate([lum, lum[:, :1]], 1) * np.sin(np.arange(h) * np.pi / (h - 1))[:, None]
    wx = np.ones(w + 1)
    wx[[0, -1]] = 0.5
    wy = np.ones(h)
    wy[[0, -1]] = 0.5
    integral = (wy[:, None] * wx[None, :] * lum).sum() / (w * (h - 1))
    local = d @ np.linalg.inv(to_world[:3, :3]).T
    u = np.arctan2(local[:, 0], -local[:, 2]) / (2 * np.pi) - 0.5 / w
    u = u - np.floor(u)
    v = np.arccos(np.clip(local[:, 1], -1, 1)) / np.pi
    x, y = u * w, v * (h - 1)
    x0 = np.minimum(x.astype(int), w - 1)
    y0 = np.minimum(y.astype(int), h - 2)
    fx, fy = x - x0, y - y0
    val = ((lum[y0, x0] * (1 - fx) + lum[y0, x0 + 1] * fx) * (1 - fy)
           + (lum[y0 + 1, x0] * (1 - fx) + lum[y0 + 1, x0 + 1] * fx) * fy)
    sin_theta = np.maximum(np.hypot(local[:, 0], local[:, 2]), 1e-7)
    return val / integral / (2 * np.pi ** 2 * sin_theta)


def emitter_queries(mi, scene_path, n=2000, seed=0):
    """eval / pdf_direction for n random directions, and n sample_direction calls from the origin."""
    scene = mi.load_file(str(scene_path))
    emitter = scene.emitters()[0]
    to_world = to_world_matrix(mi, scene)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sample_u = rng.random((n, 2))

    it = mi.Interaction3f()
    it.p = mi.Point3f(0.0, 0.0, 0.0)
    L = np.zeros((n, 3))
    pdf = np.zeros(n)
    for i in range(n):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-d[i]))           # wi points back along the ray
        L[i] = np.array(emitter.eval(si), dtype=np.float64)
        ds = mi.DirectionSample3f()
        ds.d = mi.Vector3f(*d[i])               # direction from the reference point to the emitter
        pdf[i] = float(emitter.pdf_direction(it, ds))

    sample_d = np.zeros((n, 3))
    sample_pdf = np.zeros(n)
    sample_weight = np.zeros((n, 3))
    sample_L = np.zeros((n, 3))
    for i in range(n):
        ds, wgt = emitter.sample_direction(it, mi.Point2f(*sample_u[i]))
        sample_d[i] = np.array(ds.d, dtype=np.float64)
        sample_pdf[i] = float(ds.pdf)
        sample_weight[i] = np.array(wgt, dtype=np.float64)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-sample_d[i]))
        sample_L[i] = np.array(emitter.eval(si), dtype=np.float64)
    return dict(d=d, L=L, pdf=pdf, sample_u=sample_u, sample_d=sample_d, sample_pdf=sample_pdf,
                sample_weight=sample_weight, sample_L=sample_L, to_world=to_world)


# ----------------------------------------------------------------------------------------------
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--variant", default="auto", help="Mitsuba variant (auto = scalar_rgb)")
    ap.add_argument("--outdoor-spp", type=int, default=4096)
    ap.add_argument("--room-spp", type=int, default=10240)
    ap.add_argument("--lookup-spp", type=int, default=64)
    ap.add_argument("--no-render", action="store_true", help="skip outdoor/room reference renders")
    ap.add_argument("--out", default=str(HERE), help="output folder (default: this folder)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    import mitsuba as mi

    variant = set_variant(mi, args.variant)
    print(f"mitsuba {mi.__version__}, variant {variant}")
    info = {"mitsuba": mi.__version__, "variant": variant}

    # 1-2. maps
    sky = make_sky()
    pattern = make_pattern()
    for name, img in (("sky.exr", sky), ("pattern.exr", pattern)):
        write_exr(out / name, img)
        back = read_image(out / name)
        assert back.shape == img.shape and np.array_equal(back, img), name

    # 3-5. scenes
    (out / "outdoor.xml").write_text(OUTDOOR_XML)
    (out / "room.xml").write_text(make_room_xml())
    (out / "lookup.xml").write_text(LOOKUP_XML)

    # sun directions
    sun_local = sun_local_direction()
    info["sun_local"] = sun_local.tolist()
    for name in ("outdoor", "room"):
        sc = mi.load_file(str(out / f"{name}.xml"))
        m = to_world_matrix(mi, sc)
        sd = m[:3, :3] @ sun_local
        info[f"sun_world_{name}"] = sd.tolist()
        info[f"to_world_{name}"] = m.tolist()
        print(f"{name}: world direction towards the sun {np.round(sd, 5).tolist()}, "
              f"elevation {np.degrees(np.arcsin(sd[1])):.3f} deg")

    # 5. lookup render + emitter queries
    img, dt = render(mi, out / "lookup.xml", args.lookup_spp)
    write_exr(out / "lookup_ref.exr", img)
    info["lookup_spp"], info["lookup_seconds"] = args.lookup_spp, round(dt, 2)
    for tag, scene_file, map_img in (("pattern", "lookup.xml", pattern), ("sky", "outdoor.xml", sky)):
        q = emitter_queries(mi, out / scene_file)
        q["scene"] = np.array(scene_file)
        np.savez_compressed(out / f"lookup_rays_{tag}.npz", **q)
        # self-checks
        ref = mitsuba_eval_np(map_img, q["to_world"], q["d"])
        err = np.abs(ref - q["L"]) / np.maximum(1e-3, np.abs(ref))
        wl = q["sample_weight"] * q["sample_pdf"][:, None]
        err2 = np.abs(wl - q["sample_L"]) / np.maximum(1e-3, np.abs(q["sample_L"]))
        pdf_ref = mitsuba_pdf_np(map_img, q["to_world"], np.concatenate([q["d"], q["sample_d"]]))
        pdf_mi = np.concatenate([q["pdf"], q["sample_pdf"]])
        err3 = np.abs(pdf_ref - pdf_mi) / np.maximum(1e-6, pdf_mi)
        print(f"lookup_rays_{tag}.npz: numpy eval vs Mitsuba max rel err {err.max():.2e}; "
              f"numpy pdf vs Mitsuba max rel err {err3.max():.2e}; "
              f"weight*pdf vs eval max rel err {err2.max():.2e}")
        info[f"selfcheck_{tag}_eval_relerr"] = float(err.max())
        info[f"selfcheck_{tag}_pdf_relerr"] = float(err3.max())

    # 6. references
    if not args.no_render:
        for name, spp, exposure in (("outdoor", args.outdoor_spp, -2.0), ("room", args.room_spp, 0.0)):
            img, dt = render(mi, out / f"{name}.xml", spp)
            write_exr(out / f"{name}_ref.exr", img)
            assert np.array_equal(read_image(out / f"{name}_ref.exr"), img)
            write_png(out / f"{name}.png", img, exposure=exposure)
            info[f"{name}_spp"], info[f"{name}_seconds"] = spp, round(dt, 1)
            print(f"{name}: {spp} spp in {dt:.1f} s, mean {img.mean(axis=(0, 1)).round(4).tolist()}")
    info_path = out / "info.json"
    merged = json.loads(info_path.read_text()) if info_path.is_file() else {}
    merged.update(info)
    info_path.write_text(json.dumps(merged, indent=1) + "\n")
    print(json.dumps(merged))
    return merged


if __name__ == "__main__":
    main()
