"""``--scene-root DIR``: the folder a scene's files must lie in (issue 20).

A scene file names other files: a Mitsuba XML its ``<include>``s, ``obj``/``ply`` meshes, bitmap
textures and envmaps; an OBJ its ``mtllib``s, an MTL its ``map_Kd`` textures. Every such path
must resolve, after symlinks and ``..``, inside the scene root (by default the scene file's own
folder); one that does not is refused with a :class:`SceneRootError` naming the file and line
that refer to it, the path as written and where it leads. The check comes before any existence
test, so a refused path says nothing about whether the file exists.

The loaders check the path they are about to read and then read the resolved (real) path, so a
symlink inside the root that points outside is refused too.
"""
from __future__ import annotations

import os
from pathlib import Path

from .scene import SceneError


class SceneRootError(SceneError):
    """A scene names a file outside its scene root (or the scene file itself lies outside it).
    Loaders that turn an unreadable file into a warning re-raise this one."""


class SceneRoot:
    """The folder a scene may read from; ``check`` refuses a path that leads outside it."""

    def __init__(self, root: str | Path):
        self.given = Path(root)
        self.real = Path(os.path.realpath(root))
        if not self.real.is_dir():
            raise SceneError(f"scene root {self.given}: not a folder")

    @classmethod
    def for_scene(cls, scene_path: str | Path, root: str | Path | None = None) -> "SceneRoot":
        """The root of the scene at ``scene_path``: ``root``, or the scene file's folder. The scene
        file itself must lie inside it."""
        scene_path = Path(scene_path)
        r = cls(root if root is not None else scene_path.parent)
        if not r.contains(scene_path):
            raise SceneRootError(f"{scene_path}: the scene file is outside the scene root {r.real} "
                                 f"(it resolves to {os.path.realpath(scene_path)})")
        return r

    def contains(self, path: str | Path) -> bool:
        real = os.path.realpath(path)
        root = str(self.real)
        return real == root or real.startswith(root.rstrip(os.sep) + os.sep)

    def check(self, path: str | Path, where: str, written: str, what: str = "file") -> Path:
        """``path`` resolved (symlinks, ``..``) when it lies inside the root, else
        :class:`SceneRootError` ``WHERE: WHAT 'WRITTEN' is outside the scene root ROOT (...)``."""
        real = Path(os.path.realpath(path))
        if not self.contains(real):
            raise self.error(path, where, written, what)
        return real

    def error(self, path: str | Path, where: str, written: str, what: str = "file") -> SceneRootError:
        real = os.path.realpath(path)
        leads = "" if str(real) == written else f", it resolves to {real}"
        return SceneRootError(f"{where}: {what} '{written}' is outside the scene root {self.real}{leads} "
                              f"(--scene-root DIR widens the root)")


__all__ = ["SceneRoot", "SceneRootError", "read_bytes"]


def read_bytes(path: str | Path, display: str) -> bytes:
    """The bytes of a file a scene names, or a SceneError that says why not, named ``display``."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{display}: file not found") from None
    except IsADirectoryError:
        raise SceneError(f"{display}: is a directory, not a file") from None
    except OSError as e:
        raise SceneError(f"{display}: cannot read ({e.strerror or e})") from None
