"""CURVE through the command line: `igi keys`, then `igi serve --curve-keys` with its local worker."""
from __future__ import annotations

import socket
import subprocess
import sys
import time


from tests.support.paths import ROOT, SCENES

SCENE = SCENES / "cornell-box" / "scene.xml"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_igi_keys_writes_master_and_worker_keys(tmp_path):
    out = subprocess.run([sys.executable, "-m", "igi.master.cli", "keys", str(tmp_path / "k"), "--worker", "a",
                          "--worker", "b"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    k = tmp_path / "k"
    assert (k / "master.key_secret").exists() and (k / "master.key").exists()
    assert (k / "a.key_secret").exists() and (k / "b.key_secret").exists()
    assert len(list((k / "workers").glob("*.key"))) == 2


def test_serve_with_curve_keys_renders_with_an_authenticated_local_worker(tmp_path):
    port = _free_port()
    cmd = [sys.executable, "-m", "igi.master.cli", "serve", str(SCENE), "--workers", "1", "--width", "32",
           "--height", "32", "--bind", f"tcp://127.0.0.1:{port}", "--http", "", "--stats-interval", "1",
           "--curve-keys", str(tmp_path / "keys")]
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            line = p.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "1 workers" in line and " 0 accumulated" not in line:
                break
        assert any("1 workers" in ln and " 0 accumulated" not in ln for ln in lines), "".join(lines)
    finally:
        p.terminate()
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            p.kill()
    assert (tmp_path / "keys" / "master.key_secret").exists()
