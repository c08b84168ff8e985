"""README's first command from a bare clone: nothing beside it (no ../shared), a fresh venv.

The repository's committed HEAD is cloned into an empty temporary folder; a virtual environment
with ``--system-site-packages`` reuses the dependencies already installed (nothing is
downloaded: the install step runs without network when ``unshare -n`` is available); then the
first line of README.md's first ``bash`` block is run as written, and the image it writes must
exist and not be black.

The clone starts with this checkout's compiled kernels (:func:`seed_kernel_cache`): compiling
them from nothing is CI's own first step (``.ci/run`` compiles before the tests, in a fresh venv),
and doing it again here took 2–4 minutes of both cores, the suite's longest test. What this test
proves is the install and the command from a bare clone."""
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


def seed_kernel_cache(root: Path, clone: Path) -> int:
    """Copy ``root``'s compiled kernels (numba's cache beside the kernel sources, with
    common.kernel_cache's source-hash stamps) into ``clone``, and give each of the clone's kernel
    sources that is byte for byte ``root``'s the same modification time — numba's key for a
    cached kernel. A source that differs keeps the clone's own time, so its kernels compile
    again. Returns the number of cache files copied (0: ``root`` has no cache beside its sources)."""
    from igi.common.kernel_cache import KERNEL_PACKAGES

    copied = 0
    for pkg in KERNEL_PACKAGES:
        src, dst = root / pkg, clone / pkg
        cache = src / "__pycache__"
        if not cache.is_dir() or not dst.is_dir():
            continue
        for py in src.glob("*.py"):
            twin = dst / py.name
            if twin.is_file() and twin.read_bytes() == py.read_bytes():
                st = py.stat()
                os.utime(twin, ns=(st.st_atime_ns, st.st_mtime_ns))
        (dst / "__pycache__").mkdir(exist_ok=True)
        for f in cache.iterdir():
            if f.suffix in (".nbi", ".nbc") or f.name.endswith(".igi-sources.sha1"):
                shutil.copy2(f, dst / "__pycache__" / f.name)
                copied += 1
    return copied


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
    seed_kernel_cache(ROOT, clone)
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


def test_the_seeded_cache_keys_only_sources_equal_byte_for_byte(tmp_path):
    """seed_kernel_cache copies the cache files and gives a clone's kernel source the checkout's
    modification time only where the two are byte for byte equal: a changed source keeps its
    own time, so numba does not take the checkout's kernels for it."""
    root, clone = tmp_path / "root", tmp_path / "clone"
    for d in (root, clone):
        (d / "worker" / "kernels").mkdir(parents=True)
    cache = root / "worker" / "kernels" / "__pycache__"
    cache.mkdir()
    for name in ("same.f-3.py311.nbi", "same.f-3.py311.1.nbc", "same.igi-sources.sha1", "same.cpython-311.pyc"):
        (cache / name).write_bytes(b"x")
    for name, text in (("same.py", "a = 1\n"), ("changed.py", "b = 1\n")):
        (root / "worker" / "kernels" / name).write_text(text)
        os.utime(root / "worker" / "kernels" / name, ns=(1_000_000_000, 1_000_000_000))
    (clone / "worker" / "kernels" / "same.py").write_text("a = 1\n")
    (clone / "worker" / "kernels" / "changed.py").write_text("b = 2\n")
    assert seed_kernel_cache(root, clone) == 3  # the .pyc is not numba's
    assert (clone / "worker" / "kernels" / "same.py").stat().st_mtime_ns == 1_000_000_000
    assert (clone / "worker" / "kernels" / "changed.py").stat().st_mtime_ns != 1_000_000_000
    assert sorted(p.name for p in (clone / "worker" / "kernels" / "__pycache__").iterdir()) == [
        "same.f-3.py311.1.nbc", "same.f-3.py311.nbi", "same.igi-sources.sha1"]
