"""End points of a shared scene and their traced BSDF rays, for tests that compare a compiled
path with its numpy form (the same draws either way)."""
from __future__ import annotations

import numpy as np

from igi.bench.stress_scenes import load_shared


def traced_end_points(monkeypatch, scene_name: str, compiled: bool, sky: bool, max_depth: int, seed: int,
                      clamp_fraction: float | None = None, width: int = 96, height: int = 72):
    """(scene, renderer, eye result, BSDF rays, clamp d², generator) for ``width``×``height``
    eye paths through ``scene_name`` (a shared scene, or a path under tests/data ending .xml): the rays through the compiled kernels (``compiled``) or
    Geometry.intersect, under a lit sky or not; the BSDF rays ``√d²`` short (d² the default
    clamp, or ``clamp_fraction`` of the squared diagonal), aimed at the mirror/glass targets."""
    from igi.common.camera import camera_rays, resolve_camera
    from igi.common.params import make_params
    from igi.worker.renderer import Renderer, clamp_distance2
    from igi.worker.shading import trace_bsdf_rays, trace_eye

    if scene_name.endswith(".xml"):  # a test scene of tests/data
        from igi.common.loader import load_scene
        from tests.support.paths import ROOT

        scene = load_scene(ROOT / scene_name)
    else:
        scene = load_shared(scene_name)
    r = Renderer(scene)
    if not compiled:
        monkeypatch.setattr(r.geom, "closest_terms", lambda: None)
    if sky:
        monkeypatch.setattr(r.lights, "environment", lambda: np.array([0.5, 0.4, 0.3]))
    cam, fov, w, h = resolve_camera(scene, None, width, height)
    ys, xs = np.divmod(np.arange(w * h), w)
    o, d = camera_rays(cam, fov, w, h, xs, ys)
    g = np.random.default_rng(seed)
    eye = trace_eye(scene, r.geom, r.lights, o, d, max_depth, 8, g, 0.3)
    d2 = (clamp_distance2(make_params(), r.geom.diagonal) if clamp_fraction is None
          else clamp_fraction * r.geom.diagonal ** 2)
    rays = trace_bsdf_rays(r.geom, r.lights, eye.end, max_depth, g, np.sqrt(d2), r._specular_targets)
    return scene, r, eye, rays, d2, g
