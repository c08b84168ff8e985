"""The viewer's frame stream (master.stream): how it numbers and parameterizes its frames."""
from __future__ import annotations

from types import SimpleNamespace

from igi.common.frame import accumulation_index
from igi.common.loader import load_scene
from igi.master.accumulation import accumulation_key
from igi.master.stream import Stream
from tests.support.paths import SHARED


class _Frames:
    """A frame loop that records the specs it is asked to open and never finishes them."""

    def __init__(self):
        self.specs, self.open = [], {}

    def alloc_frame(self) -> int:
        return len(self.specs)

    def open_frame(self, spec, fut, gen) -> None:
        self.specs.append(spec)
        self.open[gen] = self.open.get(gen, 0) + 1

    def open_stream_frames(self, gen) -> int:
        return self.open.get(gen, 0)

    def cancel_frames(self, which, exc) -> None:
        self.open = {}


def test_frames_of_a_moving_camera_skip_the_consistent_estimators_and_accumulating_ones_take_them():
    scene = load_scene(SHARED / "scenes" / "cornell-box" / "scene.xml")
    state = SimpleNamespace(current=lambda: scene, hash="h", version=0)
    frames = _Frames()
    stream = Stream(frames, state, lambda fn: fn(), pipeline=3)
    stream.start(width=32, height=24)
    first = list(frames.specs)
    assert [accumulation_index(s) for s in first] == [0, 1, 2]
    assert [s.params["consistent_first_frame"] for s in first] == [False, True, True]
    assert [s.params["moving_camera"] for s in first] == [True, False, False]  # fewer VPLs, then all
    assert len({accumulation_key(s) for s in first}) == 1  # and they still average together
    stream.set_camera(scene.camera.to_world * 1.0 + 0.01)  # the camera moves: a new index 0
    moved = frames.specs[len(first):]
    assert accumulation_index(moved[0]) == 0 and moved[0].params["consistent_first_frame"] is False
    assert all(s.params["consistent_first_frame"] for s in moved[1:])
    assert moved[0].params["moving_camera"] and not any(s.params["moving_camera"] for s in moved[1:])
