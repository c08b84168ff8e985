#!/usr/bin/env python
"""Generate the sun-caustics test assets in this folder (see README.md).

Usage (from anywhere):

    python tests/data/sun_caustics/make_assets.py               # scenes and both references
    python tests/data/sun_caustics/make_assets.py --no-render   # the scenes only

Needs the ``mitsuba`` Python package (3.x; made with 3.9.1, variant ``scalar_rgb``) and igi (for
its EXR writer). The scenes are edits of two existing ones, so their comments say what changed:

- ``glass_ball.xml``: tests/data/envmap/outdoor.xml with the diffuse ball made glass (dielectric,
  IOR 1.5) and the ground 16 x 16 instead of 60 x 60; lit only by sky.exr (a copy of
  ../envmap/sky.exr: igi reads no file outside a scene's folder; a 2 x 2-texel sun). Reference:
  Mitsuba's path tracer (``path``), GLASS_BALL_SPP spp — it finds the sun's caustic under the ball
  by BSDF sampling through the glass.
- ``pane.xml``: common/scenes/window-room/scene.xml (directional sun + constant sky through a
  window opening) with a thin glass pane (``thindielectric``, IOR 1.5) in the opening, the plastic
  ball made diffuse, film 160 x 120 with a box filter. Reference: the sum of two renders, the sun
  alone by Mitsuba's light tracer (``ptracer``, PANE_SUN_SPP spp: a path tracer cannot find a
  directional light through glass; light tracing renders every pixel whose first hit is diffuse —
  all but the pane, which it leaves black) and the sky alone by its path tracer (PANE_SKY_SPP spp:
  the light tracer's sky leaks into the closed room through the seams where its walls meet, +12–19%).

Renders use Mitsuba's ``independent`` sampler with seed 0; run information goes to info.json.
"""
from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
GLASS_BALL_SPP = 16384
PANE_SUN_SPP = 16384
PANE_SKY_SPP = 4096


def _replace(text: str, old: str, new: str) -> str:
    if text.count(old) != 1:
        raise SystemExit(f"make_assets: the source scene changed; cannot find {old!r} once")
    return text.replace(old, new)


def glass_ball_xml() -> str:
    s = (REPO / "tests" / "data" / "envmap" / "outdoor.xml").read_text()
    s = _replace(s, 'igi envmap test scene "outdoor": a grey ground plane with a diffuse sphere and a diffuse cube,',
                 'igi sun-caustics test scene "glass_ball": tests/data/envmap/outdoor.xml with its sphere made\n'
                 '  glass (dielectric, IOR 1.5) and its ground 16 x 16 (was 60 x 60): a grey ground plane, a glass\n'
                 '  sphere and a diffuse cube,')
    s = _replace(s, 'to_world. Own work for igi (tests/data/envmap/make_assets.py).',
                 'to_world. Own work for igi (tests/data/sun_caustics/make_assets.py).')
    s = _replace(s, '''    <shape type="sphere" id="ball">
        <point name="center" x="-0.6" y="0.7" z="0.9"/>
        <float name="radius" value="0.7"/>
        <ref id="reddish"/>
    </shape>''', '''    <bsdf type="dielectric" id="glass">
        <float name="int_ior" value="1.5"/>
    </bsdf>
    <shape type="sphere" id="ball">
        <point name="center" x="-0.6" y="0.7" z="0.9"/>
        <float name="radius" value="0.7"/>
        <ref id="glass"/>
    </shape>''')
    s = _replace(s, '<scale x="30" y="30"/>', '<scale x="8" y="8"/>')
    return s


def pane_xml() -> str:
    s = (REPO / "common" / "scenes" / "window-room" / "scene.xml").read_text()
    s = _replace(s, 'igi bundled scene "window-room": a closed room lit only through a window opening in its left',
                 'igi sun-caustics test scene "pane": the bundled scene window-room with a thin glass pane\n'
                 '  (thindielectric, IOR 1.5) in its window, its plastic ball made diffuse and its film 160 x 120\n'
                 '  with a box filter (tests/data/sun_caustics/make_assets.py). The original: a closed room lit\n'
                 '  only through a window opening in its left')
    s = _replace(s, '<integer name="width" value="320"/>', '<integer name="width" value="160"/>')
    s = _replace(s, '<integer name="height" value="240"/>\n        </film>',
                 '<integer name="height" value="120"/>\n            <rfilter type="box"/>\n        </film>')
    return _replace(s, '''    <bsdf type="plastic" id="red-plastic">
        <rgb name="diffuse_reflectance" value="0.7, 0.1, 0.08"/>
        <float name="int_ior" value="1.5"/>
    </bsdf>''', '''    <bsdf type="diffuse" id="red-plastic">
        <rgb name="reflectance" value="0.7, 0.1, 0.08"/>
    </bsdf>
    <bsdf type="thindielectric" id="pane-glass">
        <float name="int_ior" value="1.5"/>
    </bsdf>
    <shape type="rectangle" id="pane">
        <transform name="to_world">
            <scale x="0.75" y="0.6"/>
            <rotate y="1" angle="90"/>
            <translate x="-1.995" y="1.4" z="-0.75"/>
        </transform>
        <ref id="pane-glass"/>
    </shape>''')


def render(scene_xml: str, spp: int, integrator: str) -> tuple:
    """(the image (H, W, 3) float32, run information) of Mitsuba 3 rendering ``scene_xml``."""
    import mitsuba as mi
    import numpy as np

    mi.set_variant("scalar_rgb")
    tmp = HERE / "_render.xml"  # (in this folder: the scene's files resolve beside it)
    tmp.write_text(scene_xml)
    try:
        scene = mi.load_file(str(tmp))
    finally:
        tmp.unlink()
    integ = mi.load_dict({"type": "ptracer", "max_depth": 8}) if integrator == "ptracer" else None
    t = time.time()
    img = mi.render(scene, spp=spp, seed=0, integrator=integ) if integ else mi.render(scene, spp=spp, seed=0)
    info = {"mitsuba": mi.__version__, "variant": "scalar_rgb", "integrator": integrator, "spp": spp,
            "render_s": round(time.time() - t, 1)}
    return np.asarray(img, np.float32)[..., :3], info


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--no-render", action="store_true", help="write the scenes only")
    ap.add_argument("--glass-ball-spp", type=int, default=GLASS_BALL_SPP)
    ap.add_argument("--pane-sun-spp", type=int, default=PANE_SUN_SPP)
    ap.add_argument("--pane-sky-spp", type=int, default=PANE_SKY_SPP)
    args = ap.parse_args(argv)
    shutil.copyfile(REPO / "tests" / "data" / "envmap" / "sky.exr", HERE / "sky.exr")
    (HERE / "glass_ball.xml").write_text(glass_ball_xml())
    (HERE / "pane.xml").write_text(pane_xml())
    if args.no_render:
        return
    from igi.common.image_io import write_exr

    img, ball = render(glass_ball_xml(), args.glass_ball_spp, "path")
    write_exr(HERE / "glass_ball_ref.exr", img)
    pane = pane_xml()
    sun, sun_info = render(_replace(pane, '<rgb name="radiance" value="0.9, 1.1, 1.5"/>',
                                    '<rgb name="radiance" value="0, 0, 0"/>'), args.pane_sun_spp, "ptracer")
    sky, sky_info = render(_replace(pane, '<rgb name="irradiance" value="9, 8, 6.5"/>',
                                    '<rgb name="irradiance" value="0, 0, 0"/>'), args.pane_sky_spp, "path")
    write_exr(HERE / "pane_ref.exr", sun + sky)
    info = {"glass_ball_ref.exr": ball, "pane_ref.exr": {"sun": sun_info, "sky": sky_info}}
    (HERE / "info.json").write_text(json.dumps(info, indent=1) + "\n")


if __name__ == "__main__":
    main()
