"""One validation of every size and camera, shared by the CLI, the scene loader and the viewer.

A memory budget (``--memory-budget``, else ``$IGI_MEMORY_BUDGET``, else 8 GiB; e.g. ``512M``,
``16G``, a plain number of bytes) bounds what a render may ask for:

- resolution: ``width × height × BYTES_PER_PIXEL`` (the master's accumulation, frame-assembly and
  encoding buffers, plus a worker's per-tile working set) must fit, and each side is at most
  :data:`MAX_SIDE` (the wire protocol's limit);
- VPLs and photons: the per-worker sets (``interleave² × (VPLs + photons × emitters)``) must fit
  in a quarter of it;
- frames: at most :data:`MAX_FRAMES` (a frame adds no memory; the bound only stops nonsense);
- an environment map: ``width × height × ENV_MAP_BYTES_PER_PIXEL`` (the image, its lookup and
  sampling tables, its copy in the scene blob each worker receives) within half of it.

Cameras must be finite (and not absurdly large: ``|x| ≤ MAX_COORD``), with a non-zero forward
direction, a non-zero up that is not parallel to it, and ``0 < fov < 180``. A scene must have at
least one triangle.

Every check raises :class:`LimitError` (a ``ValueError``) with one line that names the limit.
"""
from __future__ import annotations

import math
import os
import re

import numpy as np

from igi.common.params import boosted_photon_bound

GiB = 1 << 30
DEFAULT_BUDGET = 8 * GiB
ENV = "IGI_MEMORY_BUDGET"
BYTES_PER_PIXEL = 196  # master: float64 mean + even/odd halves, the edge-stopping guide's float64 sums and
# its planes, float32 layers (lobe incl.), 8-bit encode; worker tile
MAX_SIDE = 16384  # == common.protocol.MAX_IMAGE_SIDE
MAX_FRAMES = 10_000_000
MAX_COORD = 1e9  # camera coordinates beyond this lose every digit of a scene in float32
VPL_BYTES = 96  # position, normal, power, kind, pdf … per VPL
PHOTON_BYTES = 64  # position, direction, power + the hash-grid entry
ENV_MAP_BYTES_PER_PIXEL = 80  # float32 image + padded texture + blob copy, float64 density, CDFs, temporaries

_override: int | None = None


class LimitError(ValueError):
    """A request beyond a limit (or a degenerate camera); the message is one line."""


def parse_size(text) -> int:
    """'8G', '512M', '1.5GiB', '1000000' -> bytes."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([kKmMgGtT]?)(i?[bB])?\s*", str(text))
    if not m:
        raise LimitError(f"memory budget {text!r}: expected a size like 8G, 512M or a number of bytes")
    v = float(m.group(1)) * {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}[m.group(2).lower()]
    if not (math.isfinite(v) and v >= 1 << 20):
        raise LimitError(f"memory budget {text!r}: at least 1M")
    return int(v)


def set_memory_budget(value) -> int:
    """Set the process-wide budget (the CLI's ``--memory-budget``); None: back to env/default."""
    global _override
    _override = None if value is None else parse_size(value)
    return memory_budget()


def memory_budget() -> int:
    if _override is not None:
        return _override
    env = os.environ.get(ENV)
    return parse_size(env) if env else DEFAULT_BUDGET


def fmt_bytes(n: float) -> str:
    for unit, size in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def _budget_hint() -> str:
    return f"memory budget {fmt_bytes(memory_budget())} (--memory-budget or ${ENV})"


def max_pixels(budget: int | None = None) -> int:
    return int((budget or memory_budget()) // BYTES_PER_PIXEL)


def _int(value, what: str) -> int:
    if isinstance(value, bool):
        raise LimitError(f"{what}: expected an integer, got {value!r}")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise LimitError(f"{what}: expected an integer, got {value!r}") from None
    if not math.isfinite(f) or f != int(f):
        raise LimitError(f"{what}: expected an integer, got {value!r}")
    return int(f)


def check_resolution(width, height, what: str = "resolution") -> tuple[int, int]:
    """(width, height) as ints, or LimitError naming the side or the memory limit."""
    w, h = _int(width, f"{what} width"), _int(height, f"{what} height")
    if w < 1 or h < 1:
        raise LimitError(f"{what} {w}x{h}: width and height must be >= 1")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise LimitError(f"{what} {w}x{h}: each side is at most {MAX_SIDE} pixels")
    need = w * h * BYTES_PER_PIXEL
    if need > memory_budget():
        side = int(math.sqrt(max_pixels()))
        raise LimitError(f"{what} {w}x{h} needs ~{fmt_bytes(need)}, over the {_budget_hint()}: "
                         f"at most {max_pixels():,} pixels (e.g. {side}x{side})")
    return w, h


def check_frames(frames, what: str = "--frames") -> int:
    n = _int(frames, what)
    if not 1 <= n <= MAX_FRAMES:
        raise LimitError(f"{what} {n}: must be in [1, {MAX_FRAMES:,}]")
    return n


def check_params(params, emitters: int = 1) -> None:
    """VPL and photon sets per worker against a quarter of the budget (``params``: Params or dict)."""
    get = (lambda k: params[k]) if isinstance(params, dict) else (lambda k: getattr(params, k))
    try:
        n2 = int(get("interleave")) ** 2
        vpls = int(get("direct_vpls")) + int(get("indirect_vpls")) * int(get("light_path_length"))
        photons = int(get("photons"))
        boost = float(get("photon_share")) > 0
        if boost:  # a scene rich in caustics may take up to this many
            photons = boosted_photon_bound(photons)
        photons *= max(1, int(emitters))
    except (KeyError, AttributeError, TypeError, ValueError):
        return  # not a full parameter set: make_params validates the values themselves
    need = n2 * (vpls * VPL_BYTES + photons * PHOTON_BYTES)
    if need > memory_budget() // 4:
        hint = " (--photon-share 0 keeps --photons)" if boost else ""
        raise LimitError(f"{n2} interleaved sets of {vpls} VPLs and {photons:,} photons{hint} need ~{fmt_bytes(need)}, "
                         f"over a quarter of the {_budget_hint()}")


def check_environment_map(width: int, height: int, what: str = "environment map") -> None:
    """An environment map of ``width`` x ``height`` pixels against half the budget (every process
    that renders holds it with its tables)."""
    need = int(width) * int(height) * ENV_MAP_BYTES_PER_PIXEL
    if need > memory_budget() // 2:
        raise LimitError(f"{what} {width}x{height} needs ~{fmt_bytes(need)}, over half the {_budget_hint()}")


def check_camera(to_world, fov=None, what: str = "camera") -> np.ndarray:
    """A finite, non-degenerate camera-to-world matrix (4×4 or 16 numbers, Mitsuba convention:
    columns left, up, forward, origin) and 0 < fov < 180; returns it as a 4×4 float64 array."""
    try:
        m = np.asarray(to_world, np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise LimitError(f"{what}: expected a 4x4 matrix (16 numbers)") from None
    if not np.isfinite(m).all():
        raise LimitError(f"{what}: the matrix has NaN or infinite entries")
    if np.abs(m).max() > MAX_COORD:
        raise LimitError(f"{what}: matrix entries up to {np.abs(m).max():g}, beyond the limit ±{MAX_COORD:g}")
    left, up, fwd = m[:3, 0], m[:3, 1], m[:3, 2]
    nl, nu, nf = (float(np.linalg.norm(v)) for v in (left, up, fwd))
    if not nf > 1e-12:
        raise LimitError(f"{what}: the forward direction is zero")
    if not nu > 1e-12:
        raise LimitError(f"{what}: the up direction is zero")
    if float(np.linalg.norm(np.cross(up, fwd))) <= 1e-9 * nu * nf:
        raise LimitError(f"{what}: the up direction is parallel to the forward direction")
    if not nl > 1e-12 or abs(float(np.linalg.det(m[:3, :3]))) <= 1e-9 * nl * nu * nf:
        raise LimitError(f"{what}: the matrix is singular (its axes do not span 3D)")
    if fov is not None:
        try:
            f = float(fov)
        except (TypeError, ValueError):
            raise LimitError(f"{what}: fov {fov!r} is not a number") from None
        if not 0 < f < 180:
            raise LimitError(f"{what}: fov {f:g} must be in (0, 180) degrees")
    return m


def check_scene(scene, source: str | None = None) -> None:
    """Refuse a scene with nothing to render, a degenerate camera or a film beyond the budget."""
    where = source or getattr(scene, "source", None) or "scene"
    if not any(len(m.faces) for m in scene.meshes):
        raise LimitError(f"{where}: nothing to render (the scene has no triangles)")
    cam = scene.camera
    if cam is not None:
        try:
            check_camera(cam.to_world, cam.fov, what="sensor")
            check_resolution(cam.width, cam.height, what="film")
        except LimitError as e:
            raise LimitError(f"{where}: {e}") from None
