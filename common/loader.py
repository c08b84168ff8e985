"""Scene loading entry point: dispatch on the file extension."""
from __future__ import annotations

from pathlib import Path

from .scene import Scene, SceneError

LOADERS = {".xml": "Mitsuba 3 scene XML", ".obj": "Wavefront OBJ (+ MTL) as a whole scene"}


def load_scene(path: str | Path, defaults: dict[str, str] | None = None, *,
               root: str | Path | None = None) -> Scene:
    """Load a scene: ``.xml`` -> :func:`common.mitsuba_xml.load_mitsuba` (``defaults`` override its
    ``<default>`` parameters), ``.obj`` -> :func:`common.obj_mtl.load_obj_scene`.

    ``root`` (``--scene-root``; None = the scene file's folder) confines what the scene may read:
    every file it names (includes, meshes, textures, MTL libraries) must resolve inside it, after
    symlinks and ``..``, else :class:`common.scene_root.SceneRootError` (a :class:`SceneError`)
    names the file, the line and the path outside the root.

    Raises :class:`SceneError` for a missing file or an unknown extension, and for a scene that
    :func:`common.limits.check_scene` refuses (no triangles, a degenerate camera, a film beyond
    the memory budget).
    """
    from .limits import LimitError, check_scene

    try:
        scene = _load(Path(path), defaults, root)
        check_scene(scene, str(path))
        return scene
    except LimitError as e:
        raise SceneError(str(e)) from None
    except OSError as e:
        # e.g. ENAMETOOLONG from a file name inside the scene: name it, don't crash.
        raise SceneError(f"{path}: cannot read a file of this scene: {e.strerror or e} "
                         f"({(e.filename or '')[:120]})") from None


def _load(path: Path, defaults: dict[str, str] | None, root: str | Path | None) -> Scene:
    ext = path.suffix.lower()
    if ext not in LOADERS:
        known = ", ".join(f"{k} ({v})" for k, v in LOADERS.items())
        raise SceneError(f"{path}: unknown scene format '{ext or '(no extension)'}'; supported: {known}")
    if not path.exists():
        raise SceneError(f"{path}: file not found")
    if not path.is_file():
        raise SceneError(f"{path}: not a file")
    if ext == ".xml":
        from .mitsuba_xml import load_mitsuba

        return load_mitsuba(path, defaults, root)
    if defaults:
        raise SceneError(f"{path}: parameter defaults only apply to Mitsuba XML scenes")
    from .obj_mtl import load_obj_scene

    return load_obj_scene(path, root)
