"""Precomputed tables kept on disk between runs, as numba's ``cache=True`` keeps kernels.

A rough plastic's coat tables (common.microfacet.rough_plastic_tables) take ~0.5 s each to
integrate; without a cache every worker process pays that per distinct coat before its first
frame. Files live in ``$IGI_CACHE_DIR`` (empty: no cache), else ``$XDG_CACHE_HOME/igi`` or
``~/.cache/igi``; their names carry a version of the code that computed them, so a change to
that code never reads a stale table. Writes are atomic (temporary file + rename): processes
starting together may compute the same table, never read half of one. Any unreadable file is
recomputed and replaced; an unwritable directory only costs the computation.
"""
from __future__ import annotations

import hashlib
import logging
import os
import secrets
from pathlib import Path
from types import ModuleType

import numpy as np

log = logging.getLogger(__name__)

ENV = "IGI_CACHE_DIR"


def cache_dir() -> Path | None:
    """Where tables are kept; None when caching is off (``IGI_CACHE_DIR=""``)."""
    d = os.environ.get(ENV)
    if d is not None:
        return Path(d) if d else None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "igi"


def source_version(*modules: ModuleType) -> str:
    """A short hash of the modules' source files and of the numpy and scipy versions they run
    on: the version of what they compute (two environments sharing a cache never read each
    other's tables)."""
    import scipy

    h = hashlib.sha1(f"numpy {np.__version__} scipy {scipy.__version__}".encode())
    for m in modules:
        h.update(Path(m.__file__).read_bytes())
    return h.hexdigest()[:12]


def load(name: str) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``name``, or None (no cache, no file, or an unreadable one)."""
    d = cache_dir()
    if d is None:
        return None
    try:
        with np.load(d / name, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        return None
    except Exception as e:  # noqa: BLE001 - only a cache: any damage means "recompute"
        log.warning("table cache: ignoring unreadable %s (%s: %s); recomputing it", d / name,
                    type(e).__name__, e)
        return None


def store(name: str, **arrays: np.ndarray) -> None:
    """Keep ``arrays`` under ``name`` (atomically); failures are logged, never raised."""
    d = cache_dir()
    if d is None:
        return
    tmp = None
    try:
        d.mkdir(parents=True, exist_ok=True)
        # A fresh name opened exclusively with mode 0644 under the umask, as a plain file would
        # be (mkstemp's 0600 would hide a shared cache from others; changing the umask to read
        # it would race with other threads creating files).
        tmp = d / f".{name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
        with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644), "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, d / name)
        tmp = None
    except OSError as e:
        log.info("table cache: cannot write %s (%s)", d / name, e)
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
