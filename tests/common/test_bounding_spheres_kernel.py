"""common.kernels.bounding_spheres equals the numpy original on random rays, rays starting
inside a sphere, spheres behind the ray, and a real many-light scene's emitters."""
from __future__ import annotations

import numpy as np

from igi.bench.stress_scenes import load_shared
from igi.common.geometry import Geometry
from igi.common.kernels.bounding_spheres import any_hit
from igi.common.lights import LightSampler
from tests.support.oracle_bounding_spheres import any_hit_numpy


def _kernel(o, d, c, r):
    out = np.empty(len(o), bool)
    any_hit(o, d, c, r * r, out)
    return out


def test_random_rays_and_spheres():
    g = np.random.default_rng(5)
    o = g.normal(size=(5000, 3)) * 3
    d = g.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    c = g.normal(size=(13, 3)) * 2
    r = g.random(13) * 0.8
    o[:50] = c[0]  # starting at a centre: inside
    got, want = _kernel(o, d, c, r), any_hit_numpy(o, d, c, r)
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < len(got)
    assert got[:50].all()


def test_emitters_of_modern_hall():
    scene = load_shared("modern-hall")
    geom = Geometry(scene)
    lights = LightSampler(scene, geom)
    c, r = lights.emitter_spheres()
    assert len(r) >= 8
    g = np.random.default_rng(1)
    o = geom.vertices[g.integers(0, len(geom.vertices), 4000)]
    d = g.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    np.testing.assert_array_equal(lights.may_reach_emitter(o, d), any_hit_numpy(o, d, c, r))
