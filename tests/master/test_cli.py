"""The igi command line: render to EXR/PNG through master + local workers, clear errors."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support.paths import ROOT, SHARED

CORNELL = SHARED / "scenes" / "cornell-box" / "scene.xml"


def igi(*args, cwd=None, timeout=300):
    """Run the ``igi`` console script (or ``python -m master.cli`` when not installed)."""
    exe = shutil.which("igi")
    cmd = [exe] if exe else [sys.executable, "-m", "igi.master.cli"]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return subprocess.run(cmd + [str(a) for a in args], cwd=cwd or ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def test_render_exr_and_png(tmp_path):
    from igi.common.image_io import read_image

    exr, png = tmp_path / "cb.exr", tmp_path / "cb.png"
    r = igi("render", CORNELL, "-o", exr, "--width", 64, "--height", 64, "--frames", 2, "--workers", 1)
    assert r.returncode == 0, r.stderr
    assert "2/2 frames" in r.stderr, "progress on stderr"
    img = read_image(exr)
    assert img.shape == (64, 64, 3) and img.dtype == np.float32
    assert np.isfinite(img).all() and img.mean() > 0
    r = igi("render", CORNELL, "-o", png, "--width", 64, "--height", 64, "--workers", 0, "--direct-only",
            "--seed", 3, "--indirect-vpls", 0)  # (in process: the workers' path is the EXR's above)
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = read_image(png)
    assert p.shape == (64, 64, 3) and p.max() > 0


def test_task_pixels_cut_the_frame_alike_in_process_and_through_the_broker(tmp_path):
    """--task-pixels reaches the broker: the same cut gives the same image in process and
    through a worker process, and the default cut another image (tiles seed their random
    streams) — so a broker that ignored the flag would render b as d, not as a. ('auto', sizing
    tasks by the threads connected, is test_broker's.)"""
    from igi.common.image_io import read_image
    from igi.master.cli import _task_pixels

    common = ["--width", 160, "--height", 120, "--photons", 0, "--indirect-vpls", 4, "-q"]
    a, b, d = (tmp_path / f"{x}.exr" for x in "abd")
    assert igi("render", CORNELL, "-o", a, "--workers", 0, "--task-pixels", 256, *common).returncode == 0
    r = igi("render", CORNELL, "-o", b, "--workers", 1, "--task-pixels", 256, *common)
    assert r.returncode == 0, r.stderr
    r = igi("render", CORNELL, "-o", d, "--workers", 1, *common)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(read_image(a), read_image(b))
    assert not np.array_equal(read_image(a), read_image(d))
    assert _task_pixels("auto") is None and _task_pixels("300") == 300


@pytest.mark.parametrize("args,needle", [
    (["render", "no/such/scene.xml", "-o", "out.exr"], "no/such/scene.xml"),
    (["render", CORNELL, "-o", "out.jpg"], "out.jpg"),
    (["render", CORNELL, "-o", "out.exr", "--interleave", "99"], "interleave"),
    (["render", CORNELL, "-o", "out.exr", "--direct-only", "--max-depth", "5"], "direct-only"),
    (["serve", "missing.xml"], "missing.xml"),
    (["render", CORNELL, "-o", "out.exr", "--task-pixels", "lots"], "task-pixels"),
    (["master", "--task-pixels", "0"], "task-pixels"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, needle):
    r = igi(*args, cwd=tmp_path)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert str(needle) in r.stderr


def test_broken_scene_file_is_exit_2(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='obj'>")
    r = igi("render", bad, "-o", tmp_path / "x.exr", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "bad.xml" in r.stderr


def test_bench_group_lists_scaling():
    r = igi("bench", "--help")
    assert r.returncode == 0 and "scaling" in r.stdout


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def test_serve_starts_workers_and_stops_them_all_on_sigterm(tmp_path):
    import signal
    import socket
    import time

    with socket.socket() as s:  # a free loopback port for the master
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    exe = shutil.which("igi")
    cmd = ([exe] if exe else [sys.executable, "-m", "igi.master.cli"]) + [
        "serve", str(CORNELL), "--workers", "2", "--bind", f"tcp://127.0.0.1:{port}", "--http", "",
        "--width", "32", "--height", "24", "--stats-interval", "0.5"]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    p = subprocess.Popen(cmd, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # wait for a stats line showing frames from 2 workers
            line = p.stderr.readline()
            if not line:
                break
            lines.append(line)
            if "2 workers" in line and " 0 accumulated" not in line and "accumulated" in line:
                break
        kids = _children(p.pid)
        assert len(kids) == 2, "".join(lines)
        p.send_signal(signal.SIGTERM)
        assert p.wait(30) == 0
        lines.append(p.stderr.read())
        deadline = time.monotonic() + 10  # serve waits for its workers; this is only a safety margin
        while time.monotonic() < deadline and any(_alive(k) for k in kids):
            time.sleep(0.1)
        assert not any(_alive(k) for k in kids), "the workers stopped with the master"
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


# ----------------------------------------------------------------------------- bundled scenes, bad input

def test_scenes_lists_the_bundled_scenes():
    r = igi("scenes")
    assert r.returncode == 0, r.stderr
    rows = {line.split()[0]: line.split(None, 1)[1:] for line in r.stdout.splitlines() if line.strip()}
    assert {"cornell-box", "window-room", "outdoor-sky", "window-pane"} <= set(rows)
    assert all(rows.values())  # each with its description


@pytest.mark.parametrize("name", ["cornell-box", "window-room", "outdoor-sky", "window-pane"])
def test_bundled_scene_renders_by_name(tmp_path, name):
    from igi.common.image_io import read_image

    out = tmp_path / f"{name}.exr"
    r = igi("render", name, "-o", out, "--width", 32, "--height", 24, "--workers", 0, "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    img = read_image(out)
    assert img.shape == (24, 32, 3) and np.isfinite(img).all() and img.mean() > 0.01


def test_an_existing_path_wins_over_a_bundled_name(tmp_path):
    (tmp_path / "cornell-box").mkdir()  # a directory of that name: the path wins, and is no file
    r = igi("render", "cornell-box", "-o", "x.exr", cwd=tmp_path)
    assert r.returncode == 2 and "not a file" in r.stderr


_TRI_SHAPE = '<shape type="cube"/><emitter type="constant"/>'
BAD_SCENES = {
    "film-width": ('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                   '<integer name="width" value="2000000000"/><integer name="height" value="2"/></film></sensor>'
                   + _TRI_SHAPE + "</scene>", "2000000000"),
    "empty": ('<scene version="3.0.0"><shape type="obj"><string name="filename" value="empty.obj"/></shape>'
              '<emitter type="constant"/></scene>', "nothing to render"),
    "camera-up-parallel": ('<scene version="3.0.0"><sensor type="perspective"><transform name="to_world">'
                           '<lookat origin="0,0,5" target="0,0,0" up="0,0,1"/></transform></sensor>'
                           + _TRI_SHAPE + "</scene>", "parallel"),
    "camera-1e308": ('<scene version="3.0.0"><sensor type="perspective"><transform name="to_world"><matrix value="'
                     + " ".join(["1e308"] * 12 + ["0", "0", "0", "1"]) + '"/></transform></sensor>'
                     + _TRI_SHAPE + "</scene>", "1e+308"),
    "camera-zero": ('<scene version="3.0.0"><sensor type="perspective"><transform name="to_world"><matrix value="'
                    + " ".join(["0"] * 15 + ["1"]) + '"/></transform></sensor>' + _TRI_SHAPE + "</scene>",
                    "forward direction is zero"),
    "malformed-xml": ('<scene version="3.0.0"><shape type="cube"></scene>', "scene.xml:1"),
    "missing-mesh": ('<scene version="3.0.0"><shape type="obj"><string name="filename" value="nowhere.obj"/>'
                     '</shape><emitter type="constant"/></scene>', "nowhere.obj"),
}


def _one_error_line(r, needle: str) -> None:
    assert r.returncode != 0
    assert "Traceback" not in r.stderr, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("igi: error:")]
    assert len(errors) == 1, r.stderr
    assert needle.lower() in errors[0].lower(), r.stderr


@pytest.mark.parametrize("case", sorted(BAD_SCENES))
@pytest.mark.parametrize("workers", [0, 1])
def test_bad_scene_is_one_line(tmp_path, case, workers):
    text, needle = BAD_SCENES[case]
    (tmp_path / "scene.xml").write_text(text)
    (tmp_path / "empty.obj").write_text("# no faces\nv 0 0 0\n")
    r = igi("render", "scene.xml", "-o", "x.png", "--workers", workers, "-q", cwd=tmp_path, timeout=120)
    _one_error_line(r, needle)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("args,needle", [
    (["--width", 100000, "--height", 100000], "16384"),
    (["--width", 10000, "--height", 10000], "memory budget"),
    (["--width", 4000, "--height", 4000, "--memory-budget", "64M"], "memory budget"),
    (["--memory-budget", "lots"], "memory budget"),
    (["--frames", 10 ** 9], "--frames"),
])
def test_absurd_sizes_are_one_line(tmp_path, args, needle):
    r = igi("render", "cornell-box", "-o", "x.png", *args, cwd=tmp_path, timeout=120)
    _one_error_line(r, needle)


def test_memory_budget_from_the_environment(tmp_path):
    env_before = os.environ.get("IGI_MEMORY_BUDGET")
    os.environ["IGI_MEMORY_BUDGET"] = "16M"
    try:
        r = igi("render", "cornell-box", "-o", "x.png", "--width", 400, "--height", 400, cwd=tmp_path)
    finally:
        if env_before is None:
            del os.environ["IGI_MEMORY_BUDGET"]
        else:
            os.environ["IGI_MEMORY_BUDGET"] = env_before
    _one_error_line(r, "IGI_MEMORY_BUDGET")


def test_serve_refuses_absurd_sizes(tmp_path):
    r = igi("serve", "--width", 100000, "--height", 10, "--workers", 0, "--http", "", cwd=tmp_path, timeout=120)
    _one_error_line(r, "16384")


def test_serve_restarts_a_killed_local_worker(tmp_path):
    """SIGKILL one of ``igi serve``'s local workers (serving the default, bundled scene): the
    supervisor logs it, starts a new one after the back-off, and the new worker joins the master."""
    import re
    import signal
    import socket
    import threading
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cmd = [sys.executable, "-m", "igi.master.cli", "serve", "--workers", "1",  # no scene: the bundled Cornell box
           "--bind", f"tcp://127.0.0.1:{port}", "--http", "", "--width", "32", "--height", "24",
           "--stats-interval", "0.5"]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    p = subprocess.Popen(cmd, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(iter(p.stderr.readline, "")), daemon=True).start()

    def wait_for(pattern, since=0, timeout=120):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in lines[since:]:
                m = re.search(pattern, line)
                if m:
                    return m
            assert p.poll() is None, "".join(lines)
            time.sleep(0.1)
        raise AssertionError(f"no line matching {pattern!r}:\n" + "".join(lines))
    try:
        first = wait_for(r"worker local0 joined \(.*pid (\d+)")
        pid = int(first.group(1))
        assert pid in _children(p.pid)
        n = len(lines)
        os.kill(pid, signal.SIGKILL)
        wait_for(r"local worker local0 \(pid %d\) killed by SIGKILL.*restarting in" % pid, since=n)
        again = wait_for(r"worker local0 joined \(.*pid (\d+)", since=n)
        new_pid = int(again.group(1))
        assert new_pid != pid and new_pid in _children(p.pid)
        wait_for(r" [1-9]\d* accumulated", since=len(lines) - 1)  # frames still come
        assert "Traceback" not in "".join(lines)
        p.send_signal(signal.SIGTERM)
        assert p.wait(30) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def test_unwritable_output_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r = igi("render", "cornell-box", "-o", blocker / "out.png", "--width", 8, "--height", 8, "--workers", 0, "-q",
            cwd=tmp_path)
    _one_error_line(r, "cannot write")


def test_unexpected_failure_is_one_line_and_traceback_only_with_v(capsys, caplog, monkeypatch):
    from igi.master import cli

    def boom(args):
        raise RuntimeError("something\nunexpected")
    monkeypatch.setattr(cli, "cmd_scenes", boom)
    assert cli.main(["scenes"]) == 1
    err = capsys.readouterr().err
    assert err.strip() == "igi: error: RuntimeError: something unexpected (-v for details)"
    assert cli.main(["-v", "scenes"]) == 1
    err = capsys.readouterr().err
    assert "igi: error: RuntimeError: something unexpected" in err
    assert "Traceback" in err + caplog.text  # (pytest's log capture takes the logging output in-process)


def test_render_plan_says_how_emitter_samples_choose_their_emitter():
    """`igi render --plan`: a many-light hall scores its emitters on the view; a one-light box
    says why its choice stays by power."""
    hall = igi("render", SHARED / "scenes" / "modern-hall" / "scene.xml", "--plan")
    assert hall.returncode == 0, hall.stderr
    assert "ON  emitter choice      13 emitters scored on the view" in hall.stdout
    box = igi("render", CORNELL, "--plan")
    assert box.returncode == 0, box.stderr
    assert "off emitter choice" in box.stdout


def test_progress_rate_counts_from_the_first_frame_not_the_launch():
    import io

    from igi.master.cli import Progress

    t = [100.0]
    out = io.StringIO()
    p = Progress(5, stream=out, clock=lambda: t[0])
    t[0] = 104.0  # start-up: the first frame after 4 s
    p.update(1)
    for k in range(2, 6):  # then one frame every 0.25 s: 4 frames/s
        t[0] = 104.0 + 0.25 * (k - 1)
        p.update(k, error=1e-3)
    lines = out.getvalue().strip().splitlines()
    assert "1/5 frames 0.25 fps" in lines[0]  # one frame: all that is known is launch to frame
    assert "3/5 frames 4.00 fps ETA 0 s" in lines[2]  # 2 frames left at 4 frames/s
    assert lines[-1].startswith("rendering [") and "5/5 frames 4.00 fps" in lines[-1]
    assert "(first frame after 4.0 s)" in lines[-1] and "noise estimate 1.00e-03" in lines[-1]
