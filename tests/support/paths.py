"""Repository paths for the tests: the checkout's root and the shared scenes/references beside it."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
SCENES = SHARED / "scenes"
REFERENCES = SHARED / "references"
ARTIFACTS = ROOT / "artifacts"


def pythonpath_env(env: dict | None = None) -> dict:
    """``env`` (default: this process's) with the checkout first on PYTHONPATH, for subprocesses."""
    import os

    e = dict(os.environ if env is None else env)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), e.get("PYTHONPATH", "")) if p)
    return e
