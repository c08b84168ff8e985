"""The render plan: which passes a scene needs, decided once from the scene, read by the renderer.

Each rule is a small function of the scene (and, for frames, of what changed); the plan is
data, so `igi render --plan` prints it, the viewer shows it and the renderer only reads flags.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .lights import LightSampler
from .scene import AREA, CONSTANT, DIRECTIONAL, GLOSSY_KINDS, POINT, SPECULAR_KINDS, SPOT, Scene
from .specular import specular_targets

MANY_LIGHTS = 8  # more emitters than this: direct VPLs subsample them by power (paper §5.1.4)
SMALL_EMITTER = 0.01  # emitter extent below this fraction of the scene diagonal acts as a point


@dataclass(frozen=True)
class RenderPlan:
    caustics: bool
    specular_chains: bool
    glossy_vpl_eval: bool
    textures: bool
    point_light: bool
    light_subsampling: bool
    reasons: dict = field(default_factory=dict)

    def lines(self) -> list[str]:
        out = []
        for name in ("caustics", "specular_chains", "glossy_vpl_eval", "textures", "point_light",
                     "light_subsampling"):
            on = getattr(self, name)
            out.append(f"{'ON ' if on else 'off'} {name:18s} {self.reasons.get(name, '')}")
        return out

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class FramePlan:
    """What one frame must redo, from what changed since the previous one."""

    rebuild_sets: bool  # new VPL/photon sets (a new seed): scene or parameters changed, or accumulating
    accumulate: bool  # add to the running average instead of restarting it
    reason: str


def frame_plan(scene_changed: bool, params_changed: bool, camera_changed: bool,
               accumulate_enabled: bool = True, view_dependent_sets: bool = False) -> FramePlan:
    """``view_dependent_sets``: the VPLs are importance-sampled for the view (the worker's
    pilot turned vpl_importance on), so a camera move rebuilds them for the new view."""
    if scene_changed or params_changed:
        return FramePlan(True, False, "scene or parameters changed: new sets, restart accumulation")
    if camera_changed and view_dependent_sets:
        return FramePlan(True, False, "camera moved: VPL sets importance-sampled for the new view "
                                      "(same seed), restart accumulation")
    if camera_changed:
        # Sets depend on the scene and seed only: keep the seed, reuse cached sets, no flicker.
        return FramePlan(False, False, "only the camera moved: sets reused, no preprocessing")
    if accumulate_enabled:
        return FramePlan(True, True, "nothing moved: next seed, accumulate")
    return FramePlan(False, False, "nothing moved, accumulation off")


def _emitters_reach_specular(scene: Scene, geom, lights: LightSampler, rays_per_target: int = 64) -> str:
    """Which emitter first lights a mirror/glass object — seen from a local emitter, or met first
    by a sun's parallel rays (a directional light, an environment map's peak)? Its kind ("" for
    none; a few probe rays)."""
    centres, radii = specular_targets(scene, geom)
    if len(radii) == 0:
        return ""
    rng = np.random.default_rng(0)
    spec_meshes = {i for i, m in enumerate(scene.meshes) if scene.materials[m.material].kind in SPECULAR_KINDS}
    for ei, e in enumerate(scene.emitters):
        if e.kind in (AREA, POINT, SPOT) and lights.powers[ei] > 0:
            if e.kind == AREA:
                o, nrm = lights._area_points(np.full(rays_per_target * len(radii), ei),
                                             rng.random((rays_per_target * len(radii), 2)))
            else:
                o = np.broadcast_to(e.position, (rays_per_target * len(radii), 3)).copy()
                nrm = None
            tgt = _target_points(centres, radii, (), rays_per_target, rng)
            d = tgt - o
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            if nrm is not None:
                o = geom.offset(o, nrm, d)
            if _meets_specular(geom, o, d, spec_meshes):
                return f"the {e.kind} light" + (f" '{e.name}'" if e.name else "")
        elif e.kind == DIRECTIONAL and lights.powers[ei] > 0:
            if _sun_reaches(geom, lights, spec_meshes, centres, radii, e.direction[None, :], rng, rays_per_target):
                return f"the {e.kind} light" + (f" '{e.name}'" if e.name else "")
        elif e.kind == CONSTANT and e.image is not None and lights.sky_parts()[1] is not None:
            sky = lights.sky_parts()[1].sample(rng.random((rays_per_target, 2)))[0]  # the map's peak (a sun)
            if _sun_reaches(geom, lights, spec_meshes, centres, radii, -sky, rng, 1):
                return "the environment map's sun"
    return ""


def _sun_reaches(geom, lights: LightSampler, spec_meshes: set, centres: np.ndarray, radii: np.ndarray,
                 d: np.ndarray, rng: np.random.Generator, per_direction: int) -> bool:
    """Do parallel rays along any of ``d`` (travel directions) from outside the scene toward
    points in the targets first meet a mirror/glass mesh?"""
    shape = (len(d), len(radii), per_direction, 3)  # (directions, targets, rays per pair, xyz)
    d = np.broadcast_to((d / np.linalg.norm(d, axis=1, keepdims=True))[:, None, None, :], shape).reshape(-1, 3)
    tgt = _target_points(centres, radii, (shape[0],), per_direction, rng)
    back = np.einsum("ij,ij->i", tgt - lights.center, d) + 1.01 * lights.radius
    return _meets_specular(geom, tgt - d * np.maximum(back, 0)[:, None], d, spec_meshes)


def _target_points(centres: np.ndarray, radii: np.ndarray, lead: tuple, per_target: int,
                   rng: np.random.Generator) -> np.ndarray:
    """(prod(lead) × targets × per_target, 3) probe points scattered about the targets' centres
    (normal, 0.3 × each radius), target by target within each leading index."""
    noise = rng.normal(size=(*lead, len(radii), per_target, 3))
    return (centres[:, None, :] + noise * radii[:, None, None] * 0.3).reshape(-1, 3)


def _meets_specular(geom, o: np.ndarray, d: np.ndarray, spec_meshes: set) -> bool:
    """Does any ray (o, d) first meet one of the mirror/glass meshes ``spec_meshes``?"""
    hits = geom.intersect(o, d)
    return bool(np.isin(hits.mesh[hits.valid], list(spec_meshes)).any())


def analyze(scene: Scene, geom, lights: LightSampler) -> RenderPlan:
    kinds = {m.kind for m in scene.materials}
    used = {scene.materials[m.material].kind for m in scene.meshes if len(m.faces)}
    reasons = {}
    has_spec = bool(used & set(SPECULAR_KINDS))
    specular_chains = has_spec
    reasons["specular_chains"] = ("mirror/glass surfaces present: eye chains followed, light reflected through them gathered" if has_spec
                                  else "no mirror or glass surface")
    if not has_spec:
        caustics = False
        reasons["caustics"] = "no specular surface: no caustic photons, no hash grid"
    elif not (reached := _emitters_reach_specular(scene, geom, lights)):
        caustics = False
        reasons["caustics"] = "no emitter (nor sun) reaches a mirror/glass object: no caustic path to sample"
    else:
        caustics = True
        reasons["caustics"] = f"emitters reach mirror/glass objects (first found: {reached})"
    glossy = bool(used & set(GLOSSY_KINDS))
    reasons["glossy_vpl_eval"] = ("glossy surfaces: full BSDF toward each VPL" if glossy
                                  else "all non-specular surfaces Lambertian: scalar VPL gather only")
    textured = any(scene.materials[m.material].has_texture or scene.materials[m.material].perturbs_normal
                   for m in scene.meshes if len(m.faces))
    reasons["textures"] = "bitmap textures in use" if textured else "no textures: constant albedo tables"
    n_local = int(np.count_nonzero(lights.powers > 0))
    point = False
    if len(scene.emitters) == 1 and scene.emitters[0].kind == AREA:
        tris = lights.area_tris[0]
        v = geom.vertices[geom.faces[tris]].reshape(-1, 3)
        extent = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if len(v) else 0.0
        point = extent < SMALL_EMITTER * geom.diagonal
        reasons["point_light"] = (f"single emitter {extent / geom.diagonal:.4f} of the diagonal: "
                                  + ("one direct VPL per set suffices" if point else "sampled as an area"))
    elif len(scene.emitters) == 1 and scene.emitters[0].kind in (POINT, SPOT):
        point = True
        reasons["point_light"] = "a single point/spot light: one direct VPL per set"
    else:
        reasons["point_light"] = f"{len(scene.emitters)} emitters"
    many = n_local > MANY_LIGHTS
    reasons["light_subsampling"] = (f"{n_local} emitters > {MANY_LIGHTS}: direct VPLs pick emitters (by power, and by "
                                    f"their light on the view where VPL importance is on)"
                                    if many else f"{n_local} emitter(s): each can be sampled")
    del kinds
    return RenderPlan(caustics, specular_chains, glossy, textured, point, many, reasons)
