"""README's first command from a bare clone: nothing beside it (no ../shared), a fresh venv.

The repository's committed HEAD is cloned into an empty temporary folder; a virtual environment
with ``--system-site-packages`` reuses the dependencies already installed (nothing is
downloaded: the install step runs without network when ``unshare -n`` is available); then the
first line of README.md's first ``bash`` block is run as written, and the image it writes must
exist and not be black."""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def readme_first_command(readme: Path) -> str:
    m = re.search(r"```bash\n(.*?)```", readme.read_text(), re.S)
    assert m, "README.md has a ```bash block"
    return m.group(1).strip().splitlines()[0].strip()


def _offline_prefix() -> list[str]:
    """``unshare -n`` (a network namespace with no interface up) when this user may use it."""
    exe = shutil.which("unshare")
    if not exe:
        return []
    try:
        ok = subprocess.run([exe, "-n", "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    return [exe, "-n"] if ok else []


def test_readme_first_command_from_a_bare_clone(tmp_path):
    if not shutil.which("git"):
        pytest.skip("git is not installed")
    if subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True).returncode != 0:
        pytest.skip("not a git checkout")
    clone = tmp_path / "igi"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=300)
    assert not (clone.parent / "shared").exists(), "nothing beside the clone"
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True, timeout=300)
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env.update(PATH=f"{bindir}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=str(venv), PIP_RETRIES="0",
               OMP_NUM_THREADS="1")
    command = readme_first_command(clone / "README.md")
    install, sep, run = command.partition("&&")
    assert sep and "pip install" in install and run.strip().startswith("igi "), command
    r = subprocess.run(_offline_prefix() + ["bash", "-c", install.strip()], cwd=clone, env=env,
                       capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, f"{install}\n{r.stdout}\n{r.stderr}"
    # the venv's igi is the clone's, not another installed copy
    r = subprocess.run(["igi", "scenes", "--paths"], cwd=clone, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and str(clone) in r.stdout, r.stdout + r.stderr
    assert shutil.which("igi", path=env["PATH"]).startswith(str(bindir))

    r = subprocess.run(["bash", "-c", run.strip()], cwd=clone, env=env, capture_output=True, text=True,
                       timeout=600, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, f"{run}\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stderr
    words = shlex.split(run)
    out = clone / words[words.index("-o") + 1]
    assert out.is_file() and out.stat().st_size > 1000, r.stderr

    from PIL import Image

    img = np.asarray(Image.open(out).convert("RGB"), np.float32)
    assert img.mean() > 20, f"the image is (nearly) black: mean {img.mean():.1f}"
    assert img.std() > 10, "the image shows something"
