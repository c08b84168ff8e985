"""Scenes shipped inside the package (``common/scenes/<name>/scene.xml``).

    igi scenes                       lists them
    igi render cornell-box -o x.png  a bare name resolves here (an existing path always wins)
    igi serve                        with no scene streams :data:`DEFAULT_SCENE`
"""
from __future__ import annotations

from pathlib import Path

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
DEFAULT_SCENE = "cornell-box"

DESCRIPTIONS = {
    "cornell-box": "Cornell box with a mirror sphere and a glass sphere under an area light",
    "window-room": "closed room lit through a window by sun and sky (mostly indirect light)",
    "outdoor-sky": "a ball and a cube on a ground plane under an HDR environment map with a sun",
    "window-pane": "the window room behind a glass pane: the sun's patch is a caustic (photons from the sun)",
}


def names() -> list[str]:
    """Names of the bundled scenes (folders holding a scene.xml), sorted."""
    if not SCENES_DIR.is_dir():
        return []
    return sorted(p.name for p in SCENES_DIR.iterdir() if (p / "scene.xml").is_file())


def scenes() -> list[tuple[str, str, Path]]:
    """(name, one-line description, path) of every bundled scene."""
    return [(n, DESCRIPTIONS.get(n, ""), SCENES_DIR / n / "scene.xml") for n in names()]


def path_of(name: str) -> Path | None:
    """The scene.xml of bundled scene ``name``, or None."""
    if not name or "/" in name or "\\" in name or name.startswith("."):
        return None
    p = SCENES_DIR / name / "scene.xml"
    return p if p.is_file() else None


def resolve(spec: str | None) -> Path | None:
    """A scene argument -> a file path: an existing path wins, then a bundled name (with or
    without a trailing ``.xml``); None when neither (the caller names the problem)."""
    if spec is None or spec == "":
        return path_of(DEFAULT_SCENE)
    p = Path(spec)
    if p.exists():
        return p
    name = spec[:-4] if spec.endswith(".xml") else spec
    return path_of(name)


def reference_of(scene_path: str | Path) -> Path | None:
    """A converged reference image for a scene, when one lies beside it: ``reference.exr`` in the
    scene's folder, or ``<folder>.exr`` in a ``references`` folder next to the scenes folder
    (the layout of ``../shared``)."""
    p = Path(scene_path).resolve()
    for cand in (p.parent / "reference.exr", p.with_suffix(".exr") if p.stem != "scene" else None,
                 p.parent.parent.parent / "references" / f"{p.parent.name}.exr"):
        if cand is not None and cand.is_file():
            return cand
    return None
