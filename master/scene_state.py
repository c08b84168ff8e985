"""The master's scene: the current :class:`Scene`, the content-hashed blob workers load, and the
edits made on top of that blob (``common/scene_codec.py`` deltas).

The scene version counts every change: ``base_version`` is the version of the blob, each edit
adds one. Every :data:`FOLD_EDITS` edits the edited scene is encoded into a new blob (a *fold*),
so the SCENE a joining worker gets never carries more than that many edits (issue 20).

Written by the broker's loop thread, read from any thread: every field is guarded by one lock.
Sending the scene to workers is ``master/links.py``'s job; this module only keeps the state.
"""
from __future__ import annotations

import threading

from igi.common.scene import Scene

FOLD_EDITS = 64  # edits on top of the scene blob before they are folded into a new blob (issue 20)


def encode(scene: Scene) -> tuple[bytes, str]:
    """(blob, content hash) of ``scene`` (may take a while: call it outside the loop thread)."""
    from igi.common.scene_codec import encode_scene, scene_hash

    blob = encode_scene(scene)
    return blob, scene_hash(blob)


class SceneState:
    """Scene, blob, hash, blob version and the edits since (see the module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.scene: Scene | None = None
        self.hash: str | None = None
        self.blob: bytes | None = None
        self.base_version = 0
        self.edits: list[dict] = []

    @property
    def version(self) -> int:
        with self._lock:
            return self.base_version + len(self.edits)

    def current(self) -> Scene | None:
        with self._lock:
            return self.scene

    def current_hash(self) -> str | None:
        with self._lock:
            return self.hash

    def install(self, scene: Scene, blob: bytes, h: str) -> int:
        """A new scene (the first one is version 0, a later one the version after the current);
        returns its version."""
        with self._lock:
            first = self.scene is None
            self.base_version = 0 if first else self.base_version + len(self.edits) + 1
            self.edits = []
            self.scene, self.blob, self.hash = scene, blob, h
            return self.base_version

    def edit(self, edit: dict, apply_fn) -> tuple[Scene, int]:
        """Apply ``edit`` with ``apply_fn(scene, edit)`` (ValueError on a bad edit); returns the
        edited scene and its version."""
        if self.scene is None:
            raise ValueError("no scene loaded")
        new_scene = apply_fn(self.scene, edit)
        with self._lock:
            self.scene = new_scene
            self.edits.append(edit)
            return new_scene, self.base_version + len(self.edits)

    def fold_due(self) -> bool:
        return len(self.edits) >= FOLD_EDITS

    def fold(self, version: int, base_hash: str, blob: bytes, h: str) -> bool:
        """``blob`` (hash ``h``) is the scene at ``version``: it becomes the base, with the edits
        made since. False (nothing changed) when the scene was replaced meanwhile."""
        if self.hash != base_hash or not self.base_version <= version <= self.version:
            return False
        with self._lock:
            self.edits = self.edits[version - self.base_version:]
            self.base_version = version
            self.blob, self.hash = blob, h
        return True
