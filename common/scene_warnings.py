"""A scene's load warnings: every one kept, the first few of each kind written to the log.

A real scene of 700 meshes wrote 55 warning lines as it loaded (one per mesh with a degenerate
triangle, one per empty shape), burying the one line that mattered. The kind of a message is
its text with the numbers and the leading "name: " taken out, so "Mesh709: removed 2 degenerate
(zero-area) triangle(s)" and "Mesh546: removed 8 …" are one kind; :meth:`SceneWarnings.summarize`
then writes one line per kind of how many more there were. ``Scene.warnings`` keeps them all.
"""
from __future__ import annotations

import collections
import logging
import re

SHOWN = 3  # messages of one kind written in full before the rest are only counted

_NUMBER = re.compile(r"\d+")
_INSTANCE = re.compile(r"\b(id|name)='[^']*'")  # an element's own name, not its type


def kind_of(msg: str) -> str:
    """The message's kind: its text after the first ``": "`` (what a mesh or file name and line
    lead), numbers as ``#`` and elements' ids and names as ``*``."""
    return _NUMBER.sub("#", _INSTANCE.sub(r"\1='*'", msg.split(": ", 1)[-1]))


class SceneWarnings(list):
    """The warnings of one scene load (a list of str, as ``Scene.warnings`` is), logged as they
    come by :meth:`add`, at most SHOWN of a kind."""

    def __init__(self, logger: logging.Logger):
        super().__init__()
        self._log = logger
        self._kinds: collections.Counter = collections.Counter()

    def add(self, msg: str) -> None:
        self.append(msg)
        kind = kind_of(msg)
        self._kinds[kind] += 1
        if self._kinds[kind] <= SHOWN:
            self._log.warning(msg)

    def summarize(self) -> None:
        """One line per kind of which more came than were written."""
        for kind, n in self._kinds.items():
            if n > SHOWN:
                self._log.warning("… %d more like the above: %s", n - SHOWN, kind)
        self._kinds.clear()
