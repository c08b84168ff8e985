"""A scene's load warnings (common.scene_warnings): every one kept in Scene.warnings, the log
shows the first few of a kind and how many more — not one line per mesh of a large scene."""
from __future__ import annotations

import logging

from igi.common.loader import load_scene
from igi.common.scene_warnings import SHOWN, SceneWarnings, kind_of

# One good triangle and one of zero area (two equal corners).
_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 2 2\nf 1 2 3\nf 1 2 2\n"


def test_per_mesh_messages_are_one_kind_and_other_messages_are_not():
    a = kind_of("Mesh709: removed 2 degenerate (zero-area) triangle(s)")
    b = kind_of("scene.obj (floor lamp): removed 18 degenerate (zero-area) triangle(s)")
    assert a == b
    assert kind_of("Mesh709: dropped 2 triangle(s) with non-finite (NaN/Inf) vertex data") != a
    # empty shapes with their own ids are one kind; shapes of another type are another
    empty = [kind_of(f"<shape type='obj' id='{i}'> has no triangles at s.xml:{n}, skipped")
             for i, n in (("lamp_shade", 12), ("Mesh7", 40))]
    assert empty[0] == empty[1] != kind_of("<shape type='ply' id='x'> has no triangles at s.xml:3, skipped")


def test_a_scene_of_many_flawed_meshes_logs_a_few_lines_and_keeps_every_warning(tmp_path, caplog):
    n = 12
    for i in range(n):
        (tmp_path / f"m{i}.obj").write_text(_OBJ)
    shapes = "".join(f'<shape type="obj"><string name="filename" value="m{i}.obj"/></shape>' for i in range(n))
    (tmp_path / "s.xml").write_text(f'<scene version="3.0.0"><emitter type="constant"/>{shapes}</scene>')
    with caplog.at_level(logging.WARNING, logger="igi.scene"):
        scene = load_scene(tmp_path / "s.xml")
    degenerate = [w for w in scene.warnings if "degenerate" in w]
    assert sorted(w.split(":")[0] for w in degenerate) == sorted(f"m{i}" for i in range(n))
    lines = [r.getMessage() for r in caplog.records if "degenerate" in r.getMessage()]
    assert len(lines) == SHOWN + 1, lines
    assert lines[-1].startswith(f"… {n - SHOWN} more like the above")
    assert "no <sensor>" in " ".join(r.getMessage() for r in caplog.records)  # another kind: in full


def test_fewer_than_shown_write_no_summary(caplog):
    w = SceneWarnings(logging.getLogger("igi.scene"))
    with caplog.at_level(logging.WARNING, logger="igi.scene"):
        for i in range(SHOWN):
            w.add(f"Mesh{i}: removed 1 degenerate (zero-area) triangle(s)")
        w.summarize()
    assert len(caplog.records) == SHOWN and list(w) == [r.getMessage() for r in caplog.records]
