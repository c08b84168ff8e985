"""Where a source checkout keeps things the benchmarks read: the repository root and the
shared scenes and references next to it (``../shared``). Product code does not need these."""
from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED = REPO_ROOT.parent / "shared"
SHARED_SCENES = SHARED / "scenes"
REFERENCES = SHARED / "references"


def shared_scene(name: str) -> Path:
    """The scene file of a shared benchmark scene, e.g. ``shared_scene("cornell-box")``."""
    return SHARED_SCENES / name / "scene.xml"
