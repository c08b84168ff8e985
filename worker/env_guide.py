"""Sky light sampled where the view can see it: an environment emitter's direct
samples drawn from the directions that escape from the camera points.

A room lit through windows sees the sky through a small solid angle; uniform environment
directions mostly hit walls, so a set's few environment samples light almost nothing and the
direct sky light is blotchy. Here, per set, cosine-distributed rays from the view's camera
points (the ones vpl_importance already traced) that leave the scene fill an equal-area
histogram of directions; the environment samples are drawn from the mixture
q(ω) = ½·uniform + ½·histogram (the first half the sky's map where it is one) and weighted 1/q —
unbiased, since q > 0 wherever the sky is lit — and the BSDF-sampled ray's MIS weight uses the
same q. Like the VPLs, it is a pure function of
(scene, seed, k, view): every worker builds the same set.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from igi.common.environment_map import EnvironmentMap, no_map
from igi.common.geometry import Geometry
from igi.common.lights import VPL_DIRECTIONAL, LightSampler, cosine_hemisphere, to_world
from igi.common.scene import CONSTANT, Scene

from .kernels.environment_bins import BINS_PHI, BINS_Z, UNIFORM_SHARE, direction_bins, guide_pdfs

RAYS_PER_POINT = 8
# Sky-only scenes take at least this many environment samples per set: each is one shadow ray
# per pixel, and the sky through a window needs more than the paper's 4 point-light samples to be
# smooth (grey-white-room ¼ size, 8 frames, direct light 4×4-block relMSE: 0.030 uniform, 0.025
# guided with 4, 0.016 guided with 16, at +5% time).
ENV_SAMPLES = 16
# A sky that is a map is guided only where fewer than this share of the camera points' rays escape
# (rooms lit through windows: 2-4%; an open scene: ~87%).
OPEN_SKY = 0.5


@dataclass(frozen=True)
class EnvGuide:
    """The mixture q over directions; ``pmf`` is the environment's emitter-choice probability."""

    cdf: np.ndarray  # (BINS_Z * BINS_PHI,) over the histogram bins
    density: np.ndarray  # (bins,) histogram pdf per steradian
    pmf: float
    # The escaped rays themselves (origins, unit directions towards the sky): where sky light
    # enters what the view sees (worker.portals starts light walks there); None: not kept.
    escape_origin: np.ndarray | None = None
    escape_direction: np.ndarray | None = None
    # the sky's environment map (common.environment_map), if it is one: the mixture's share that is
    # otherwise uniform over the sphere is drawn from the map (its bright directions: the sun)
    sky_map: EnvironmentMap | None = None

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """q(ω) per steradian for unit world directions (N, 3) (kernels.environment_bins)."""
        out = np.empty(len(d))
        tables = self.sky_map.env if self.sky_map is not None else no_map()
        guide_pdfs(self.density, tables, np.ascontiguousarray(d, np.float64), out)
        return out

    def sample(self, u: np.ndarray) -> np.ndarray:
        """Directions from q for uniforms (N, 3)."""
        n = len(u)
        z = 1 - 2 * u[:, 1]
        phi = 2 * np.pi * u[:, 2]
        guided = u[:, 0] >= UNIFORM_SHARE
        if guided.any():
            v = (u[guided, 0] - UNIFORM_SHARE) / (1 - UNIFORM_SHARE)
            b = np.minimum(np.searchsorted(self.cdf, v, side="right"), len(self.cdf) - 1)
            bz, bp = b // BINS_PHI, b % BINS_PHI
            z[guided] = -1 + 2 * (bz + u[guided, 1]) / BINS_Z
            phi[guided] = 2 * np.pi * (bp + u[guided, 2]) / BINS_PHI
        r = np.sqrt(np.maximum(0.0, 1 - z * z))
        out = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).reshape(n, 3)
        if self.sky_map is not None and not guided.all():
            out[~guided] = self.sky_map.sample(u[~guided, 1:3])[0]
        return out


def _bin(d: np.ndarray) -> np.ndarray:
    """The equal-area bin of each unit direction (N, 3) (kernels.environment_bins)."""
    out = np.empty(len(d), np.int64)
    direction_bins(np.ascontiguousarray(d, np.float64), out)
    return out


def single_environment(scene: Scene, lights: LightSampler) -> int:
    """The index of the scene's one constant emitter with power, else -1 (guiding then off)."""
    idx = [i for i, e in enumerate(scene.emitters) if e.kind == CONSTANT and lights.powers[i] > 0]
    return idx[0] if len(idx) == 1 else -1


def only_environment(scene: Scene, lights: LightSampler) -> bool:
    """Is the scene lit by one constant emitter and nothing else?"""
    ei = single_environment(scene, lights)
    return ei >= 0 and int(np.count_nonzero(lights.powers > 0)) == 1


def build_guide(scene: Scene, geom: Geometry, lights: LightSampler, end, g: np.random.Generator,
                ) -> EnvGuide | None:
    """The histogram of directions escaping from the end points ``end`` (None: no environment
    emitter, or nothing escapes — the uniform sampler is kept)."""
    ei = single_environment(scene, lights)
    if ei < 0 or len(end) == 0:
        return None
    rows = np.repeat(np.arange(len(end)), RAYS_PER_POINT)
    side = np.where(end.wi[rows, 2] >= 0, 1.0, -1.0)
    local = cosine_hemisphere(g.random((len(rows), 2)))
    d = to_world(local, end.ns[rows] * side[:, None])
    o = geom.offset(end.position[rows], end.ng[rows], d)
    hits = geom.intersect(o, d)
    escaped = ~hits.valid
    out = d[escaped]
    if len(out) == 0:
        return None
    if lights.env_map is not None and len(out) > OPEN_SKY * len(d):
        # Most of what the view sees is open sky (outdoors): the histogram is about the whole
        # hemisphere, and half the samples drawn from it miss the map's sun; the map alone does
        # better (tests/data/envmap/outdoor.xml, 80x60, 6 frames: relMSE 0.024 guided, 0.018 not).
        return None
    counts = np.bincount(_bin(out), minlength=BINS_Z * BINS_PHI).astype(np.float64)
    hist = counts / counts.sum()
    return EnvGuide(np.cumsum(hist), hist / (4 * np.pi / (BINS_Z * BINS_PHI)), float(lights.pmf[ei]),
                    o[escaped], out, lights.env_map)


def guide_environment_samples(vpls, lights: LightSampler, guide: EnvGuide, direct_vpls: int,
                              g: np.random.Generator) -> None:
    """Redraw a set's environment samples (directional VPLs with a pdf) from the guide, in place:
    direction ω ~ q, power L(ω)/(q·pmf)/D, light pdf pmf·q."""
    rows = np.nonzero((vpls.kind == VPL_DIRECTIONAL) & (vpls.light_pdf > 0))[0]
    if len(rows) == 0 or direct_vpls <= 0:
        return
    w = guide.sample(g.random((len(rows), 3)))  # the direction light comes from
    q = guide.pdf(w)
    vpls.normal[rows] = -w
    vpls.ng[rows] = -w
    vpls.power[rows] = lights.environment_radiance(w) / (q * guide.pmf)[:, None] / direct_vpls
    vpls.light_pdf[rows] = guide.pmf * q
