"""What every benchmark writes besides its numbers: the machine it ran on, the git commit,
markdown tables and (optionally) plots.

matplotlib is the optional ``plots`` extra (``pip install igi[plots]``): :func:`pyplot` imports
it lazily and returns ``None`` when it is missing, so a benchmark then writes no plot.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
from typing import Iterable, Sequence

from .paths import REPO_ROOT


def machine_info() -> dict:
    """CPU model, cores, memory, library versions and load (written into every benchmark JSON)."""
    import numpy

    cpu = platform.processor() or ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = None
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemTotal"):
                mem = round(int(line.split()[1]) / 2**20, 1)
                break
    except OSError:
        pass
    try:
        import zmq

        zmq_v = zmq.zmq_version()
    except Exception:  # pragma: no cover
        zmq_v = None
    try:
        load = list(os.getloadavg())
    except (OSError, AttributeError):  # pragma: no cover
        load = None
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": mem, "python": platform.python_version(),
            "numpy": numpy.__version__, "zmq": zmq_v, "platform": platform.platform(), "load_avg": load}


def git_commit() -> str | None:
    """Short hash of the checkout the benchmark ran from (None outside a git checkout)."""
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, capture_output=True,
                           text=True, timeout=5)
        return r.stdout.strip() or None
    except Exception:  # pragma: no cover
        return None


def md_table(header: Sequence[str], rows: Iterable[Sequence[object]], align: str | Sequence[str] = "---") -> list[str]:
    """A markdown table as lines: ``align`` is one separator cell for every column (``"---"``,
    ``"---:"``) or one per column."""
    header = list(header)
    seps = [align] * len(header) if isinstance(align, str) else list(align)
    out = ["| " + " | ".join(header) + " |", "|" + "|".join(seps) + "|"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return out


def pyplot(bench: str):
    """``matplotlib.pyplot`` with the non-interactive Agg backend, or None (with one line on
    stderr) when the optional ``plots`` extra is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"igi bench {bench}: matplotlib not installed (pip install igi[plots]); no plot", file=sys.stderr)
        return None
    return plt
