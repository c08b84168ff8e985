"""``--scene-root`` (issue 20): a scene may read only files inside its root (default: the scene
file's folder), after symlinks and ``..``. Refusals name the referring file and line, the path as
written and the root; through the CLI they are one line, exit status 2."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from igi.common.loader import load_scene
from igi.common.scene import SceneError
from igi.common.scene_root import SceneRootError

from tests.support.paths import ROOT, SHARED

TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
SENSOR = """<sensor type="perspective"><float name="fov" value="45"/>
  <transform name="to_world"><lookat origin="0.3,0.3,3" target="0.3,0.3,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/></film>
</sensor>"""


def write_scene(folder: Path, body: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "scene.xml"
    p.write_text(f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{SENSOR}\n{textwrap.dedent(body)}\n</scene>\n')
    return p


def mesh(filename: str, extra: str = "") -> str:
    return f'<shape type="obj"><string name="filename" value="{filename}"/>{extra}</shape>'


def line_of(path: Path, needle: str) -> int:
    return next(i for i, ln in enumerate(path.read_text().splitlines(), 1) if needle in ln)


def test_the_scene_folder_is_the_default_root(tmp_path):
    (tmp_path / "s" / "meshes").mkdir(parents=True)
    (tmp_path / "s" / "meshes" / "tri.obj").write_text(TRI)
    p = write_scene(tmp_path / "s", mesh("meshes/tri.obj") + "\n" + mesh("meshes/../meshes/tri.obj"))
    assert len(load_scene(p).meshes) == 2


def test_etc_passwd_as_a_texture_is_refused_with_file_line_and_path(tmp_path):
    (tmp_path / "tri.obj").write_text(TRI)
    tex = '<bsdf type="diffuse"><texture type="bitmap" name="reflectance">' \
          '<string name="filename" value="/etc/passwd"/></texture></bsdf>'
    p = write_scene(tmp_path, mesh("tri.obj", tex))
    with pytest.raises(SceneRootError) as e:
        load_scene(p)
    msg = str(e.value)
    assert "/etc/passwd" in msg and "outside the scene root" in msg and str(tmp_path.resolve()) in msg
    assert f"{p}:{line_of(p, '/etc/passwd')}" in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize("name", ["../../x.obj", "../x.obj"])
def test_dot_dot_mesh_is_refused_whether_or_not_it_exists(tmp_path, name):
    (tmp_path / "x.obj").write_text(TRI)  # ../x.obj exists, ../../x.obj does not: same refusal
    p = write_scene(tmp_path / "s", mesh(name))
    with pytest.raises(SceneRootError, match=r"outside the scene root") as e:
        load_scene(p)
    assert f"'{name}'" in str(e.value) and f"{p}:{line_of(p, name)}" in str(e.value)


def test_a_symlink_inside_the_root_that_leads_outside_is_refused(tmp_path):
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "tri.obj").write_text(TRI)
    (tmp_path / "s").mkdir()
    os.symlink(tmp_path / "outside" / "tri.obj", tmp_path / "s" / "link.obj")
    os.symlink(tmp_path / "outside", tmp_path / "s" / "dir")
    for name in ("link.obj", "dir/tri.obj"):
        p = write_scene(tmp_path / "s", mesh(name))
        with pytest.raises(SceneRootError) as e:
            load_scene(p)
        assert f"'{name}'" in str(e.value) and str(tmp_path / "outside" / "tri.obj") in str(e.value)
    # a symlink that stays inside the root is fine
    os.symlink(tmp_path / "s" / "real.obj", tmp_path / "s" / "inner.obj")
    (tmp_path / "s" / "real.obj").write_text(TRI)
    assert len(load_scene(write_scene(tmp_path / "s", mesh("inner.obj"))).meshes) == 1


def test_scene_root_widens_to_a_sibling_folder(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text(TRI)
    p = write_scene(tmp_path / "scenes" / "a", mesh("../../meshes/tri.obj"))
    with pytest.raises(SceneRootError):
        load_scene(p)
    assert len(load_scene(p, root=tmp_path).meshes) == 1
    with pytest.raises(SceneRootError):  # a root beside the scene's folder, not above it
        load_scene(p, root=tmp_path / "meshes")
    with pytest.raises(SceneError, match="not a folder"):
        load_scene(p, root=tmp_path / "nope")


def test_includes_and_search_paths_are_confined(tmp_path):
    (tmp_path / "other.xml").write_text('<scene version="3.0.0"/>')
    p = write_scene(tmp_path / "s", '<include filename="../other.xml"/>')
    with pytest.raises(SceneRootError, match=r"'../other.xml'"):
        load_scene(p)
    (tmp_path / "tri.obj").write_text(TRI)
    p = write_scene(tmp_path / "s", f'<path value="{tmp_path}"/>' + mesh("tri.obj"))
    with pytest.raises(SceneRootError, match=r"'tri.obj'"):
        load_scene(p)
    assert len(load_scene(p, root=tmp_path).meshes) == 1


def test_envmap_outside_the_root_is_an_error_not_a_warning(tmp_path):
    p = write_scene(tmp_path / "s", '<emitter type="envmap"><string name="filename" value="/etc/hostname"/></emitter>')
    with pytest.raises(SceneRootError, match="/etc/hostname"):
        load_scene(p)


def test_obj_scene_mtllib_and_map_kd_are_confined(tmp_path):
    (tmp_path / "outside.mtl").write_text("newmtl m\nKd 1 0 0\n")
    s = tmp_path / "s"
    s.mkdir()
    obj = s / "scene.obj"
    obj.write_text(f"# comment\nmtllib ../outside.mtl\n{TRI}")
    with pytest.raises(SceneRootError) as e:
        load_scene(obj)
    assert f"{obj}:2:" in str(e.value) and "'../outside.mtl'" in str(e.value)
    (s / "m.mtl").write_text("newmtl m\nKd 1 0 0\n\nmap_Kd /etc/passwd\n")
    obj.write_text(f"mtllib m.mtl\nusemtl m\n{TRI}")
    with pytest.raises(SceneRootError) as e:
        load_scene(obj)
    assert "m.mtl:4:" in str(e.value) and "'/etc/passwd'" in str(e.value)
    assert len(load_scene(obj, root="/").meshes) == 1  # widened to / the texture is read (and unusable: a warning)


def igi(*args, timeout=300):
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), e.get("PYTHONPATH", "")) if p)
    return subprocess.run([sys.executable, "-m", "igi.master.cli", *args], cwd=ROOT, env=e, capture_output=True,
                          text=True, timeout=timeout)


def test_cli_refuses_with_one_line_and_scene_root_widens(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text(TRI)
    p = write_scene(tmp_path / "scenes" / "a", mesh("../../meshes/tri.obj") +
                    '<emitter type="point"><point name="position" x="0" y="0" z="2"/></emitter>')
    for cmd in (["render", str(p), "-o", str(tmp_path / "x.png"), "--workers", "0"],
                ["serve", str(p), "--workers", "0", "--http", "127.0.0.1:0"],
                ["master", str(p), "--bind", "tcp://127.0.0.1:0"]):
        r = igi(*cmd)
        assert r.returncode == 2, (cmd, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("igi: error: ") and "Traceback" not in r.stderr, r.stderr
        assert "../../meshes/tri.obj" in lines[0] and "outside the scene root" in lines[0], lines[0]
    r = igi("render", str(p), "--plan", "--scene-root", str(tmp_path))
    assert r.returncode == 0, r.stderr
    r = igi("serve", "--help")
    assert "--scene-root" in r.stdout


@pytest.mark.skipif(not (SHARED / "scenes").is_dir(), reason="shared scenes not available")
def test_every_shared_and_bundled_scene_loads_under_its_default_root():
    from igi.common import bundled

    shared = SHARED / "scenes"
    paths = sorted(shared.glob("*/scene.xml")) + sorted(shared.glob("*/*.obj")) + [p for _, _, p in bundled.scenes()]
    assert len(paths) >= 10
    for p in paths:
        assert load_scene(p).meshes, p
