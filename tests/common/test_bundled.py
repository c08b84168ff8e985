"""The scenes shipped in the package (common/scenes): listed, resolved by name, loadable, and
their reference images match their films."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from igi.common import bundled


def test_names_and_descriptions():
    rows = bundled.scenes()
    names = [n for n, _, _ in rows]
    assert {"cornell-box", "window-room", "outdoor-sky"} <= set(names) and bundled.DEFAULT_SCENE in names
    assert all(desc and path.is_file() for _, desc, path in rows)
    assert (bundled.SCENES_DIR / "README.md").read_text().count("CC0") >= 1


def test_resolve(tmp_path, monkeypatch):
    assert bundled.resolve(None) == bundled.SCENES_DIR / "cornell-box" / "scene.xml"
    assert bundled.resolve("window-room") == bundled.SCENES_DIR / "window-room" / "scene.xml"
    assert bundled.resolve("window-room.xml") == bundled.SCENES_DIR / "window-room" / "scene.xml"
    assert bundled.resolve("no-such-scene") is None
    assert bundled.resolve("../cornell-box") is None
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cornell-box").write_text("mine")
    assert bundled.resolve("cornell-box") == Path("cornell-box"), "an existing path wins"


@pytest.mark.parametrize("name", ["cornell-box", "window-room", "outdoor-sky"])
def test_bundled_scene_loads_and_its_reference_fits(name):
    from igi.common.image_io import read_image
    from igi.common.loader import load_scene

    path = bundled.path_of(name)
    scene = load_scene(path)
    assert not scene.warnings, scene.warnings
    assert sum(len(m.faces) for m in scene.meshes) > 0 and scene.emitters
    assert scene.camera.width * scene.camera.height <= 320 * 320, "small: the README command stays fast"
    ref = bundled.reference_of(path)
    assert ref is not None and ref.name == "reference.exr"
    img = read_image(ref)
    assert img.shape == (scene.camera.height, scene.camera.width, 3)
    assert np.isfinite(img).all() and img.min() >= 0 and img.mean() > 0.05


def test_cornell_box_has_a_mirror_and_a_glass_sphere():
    from igi.common.loader import load_scene
    from igi.common.scene import CONDUCTOR, DIELECTRIC

    scene = load_scene(bundled.path_of("cornell-box"))
    kinds = {m.name: scene.materials[m.material].kind for m in scene.meshes}
    assert kinds["mirror-sphere"] == CONDUCTOR and kinds["glass-sphere"] == DIELECTRIC
