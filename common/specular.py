"""The scene's mirror and glass objects as targets: caustic photons are aimed at them
(``worker/caustics.py``) and the render plan decides from them whether a photon pass is needed
(``common/render_plan.py``)."""
from __future__ import annotations

import numpy as np

from .geometry import Geometry
from .scene import SPECULAR_KINDS, Scene


def specular_targets(scene: Scene, geom: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Bounding spheres (centres, radii) of the meshes with a mirror or glass BSDF."""
    centres, radii = [], []
    for i, m in enumerate(scene.meshes):
        if len(m.faces) == 0 or scene.materials[m.material].kind not in SPECULAR_KINDS:
            continue
        v = geom.vertices[geom.faces[geom.mesh_of == i]].reshape(-1, 3)
        c = 0.5 * (v.min(axis=0) + v.max(axis=0))
        r = float(np.linalg.norm(v - c, axis=1).max()) * (1 + 1e-6) + geom.eps
        centres.append(c)
        radii.append(r)
    return np.array(centres).reshape(-1, 3), np.array(radii)
