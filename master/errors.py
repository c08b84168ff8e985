"""The errors the ``igi`` command turns into one line on stderr (``master/cli.py: main``).

Their own module so that the CLI's helpers (``record.py``, ``viewer.py``, ``local_workers.py``,
the benchmarks) can raise them without importing ``cli.py``.
"""
from __future__ import annotations


class UsageError(Exception):
    """A bad input: reported as one line and exit status 2."""


class RenderError(Exception):
    """The render could not finish (e.g. every local worker died): one line, exit status 1."""
