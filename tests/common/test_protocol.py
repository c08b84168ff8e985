"""The wire protocol: framing, version refusal, schema validation of every message kind."""
from __future__ import annotations

import math
import random

import msgpack
import pytest

from igi.common import protocol as P
from igi.common.params import make_params, params_to_dict

H = "ab" * 32


def valid_bodies() -> dict[str, dict]:
    return {
        P.HELLO: {"name": "w", "host": "h", "pid": 1, "threads": 2, "credit": 6, "scenes": [H]},
        P.WELCOME: {"worker": "w/1", "heartbeat": 1.0, "liveness": 3},
        P.SCENE: {"hash": H, "blob": b"x" * 10, "base_version": 0,
                  "edits": [{"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [1, 2, 3]}]},
        P.EDIT: {"hash": H, "version": 1, "edit": {"op": "transform_mesh", "mesh": "box",
                                                    "matrix": [1.0] + [0.0] * 15}},
        P.FRAME: {"frame": 3, "hash": H, "scene_version": 0, "seed": 7, "camera": [0.0] * 16, "fov_x": 40.0,
                  "width": 64, "height": 48, "params": params_to_dict(make_params()), "jitter": [0.5, 0.5]},
        P.TASK: {"frame": 3, "task": 0, "epoch": 9, "k": 4, "tile": [0, 0, 8, 8]},
        P.RESULT: {"frame": 3, "task": 0, "epoch": 9, "count": 64, "data": b"\0" * 100,
                   "timings": {"render": 0.01}, "sets": [[7, 4]]},
        P.HEARTBEAT: {"queued": 2},
        P.BYE: {"reason": "SIGTERM"},
        P.ERROR: {"code": "task_failed", "message": "boom", "frame": 3, "task": 0, "epoch": 9},
        P.REFUSE: {"code": "version", "message": "no", "ours": 1, "theirs": 2},
    }


def test_every_kind_has_a_schema_and_round_trips():
    bodies = valid_bodies()
    assert set(bodies) == set(P.KINDS) == set(P.SCHEMAS)
    for kind, body in bodies.items():
        frame = P.encode(kind, body)
        raw = msgpack.unpackb(frame, raw=False)
        assert raw[0] == P.PROTOCOL_VERSION, "every message starts with the version"
        msg = P.decode(frame)
        assert msg.kind == kind and msg.version == P.PROTOCOL_VERSION
        assert msg.body.keys() == body.keys()


def test_wrong_version_is_refused_naming_both_versions():
    frame = P.encode(P.HELLO, valid_bodies()[P.HELLO], version=P.PROTOCOL_VERSION + 41)
    with pytest.raises(P.VersionMismatch) as e:
        P.decode(frame)
    assert e.value.theirs == P.PROTOCOL_VERSION + 41
    text = str(e.value)
    assert str(P.PROTOCOL_VERSION + 41) in text and str(P.PROTOCOL_VERSION) in text
    assert P.peek_version(frame) == P.PROTOCOL_VERSION + 41
    refusal = P.decode(P.refusal(e.value.theirs))
    assert refusal.kind == P.REFUSE
    assert refusal.body["ours"] == P.PROTOCOL_VERSION and refusal.body["theirs"] == P.PROTOCOL_VERSION + 41
    assert str(P.PROTOCOL_VERSION + 41) in refusal.body["message"]


def test_refuse_from_a_peer_of_another_version_is_readable():
    frame = msgpack.packb([7, P.REFUSE, {"code": "version", "message": "I speak 7"}], use_bin_type=True)
    m = P.decode(frame)
    assert m.kind == P.REFUSE and m.version == 7 and m.body["message"] == "I speak 7"


@pytest.mark.parametrize("frame", [
    b"", b"\x00", b"hello world", b"\xc1\xc1\xc1",  # not msgpack / reserved byte
    msgpack.packb({"a": 1}), msgpack.packb([1, 2]), msgpack.packb([1, "HELLO"]),
    msgpack.packb(["1", "HELLO", {}]), msgpack.packb([True, "HELLO", {}]),
    msgpack.packb([1, 5, {}]), msgpack.packb([1, "NOPE", {}]), msgpack.packb([1, "TASK", []]),
])
def test_garbage_is_a_protocol_error(frame):
    with pytest.raises(P.ProtocolError):
        P.decode(frame)


def test_oversize_is_refused_before_unpacking():
    big = msgpack.packb([1, P.RESULT, {"data": b"\0" * 2000}], use_bin_type=True)
    with pytest.raises(P.ProtocolError, match="exceeds"):
        P.decode(big, max_size=1000)


def _bad(kind, **changes):
    body = dict(valid_bodies()[kind])
    for k, v in changes.items():
        if v is KeyError:
            del body[k]
        else:
            body[k] = v
    return P.encode(kind, body, check=False)


@pytest.mark.parametrize("kind,changes,match", [
    (P.TASK, {"k": -1}, "TASK.k"),
    (P.TASK, {"k": 1.5}, "TASK.k"),
    (P.TASK, {"tile": [4, 0, 4, 8]}, "empty tile"),
    (P.TASK, {"tile": [0, 0, 8]}, "TASK.tile"),
    (P.TASK, {"epoch": True}, "TASK.epoch"),
    (P.TASK, {"extra": 1}, "unknown field"),
    (P.TASK, {"frame": KeyError}, "missing field"),
    (P.FRAME, {"camera": [math.nan] + [0.0] * 15}, "not finite"),
    (P.FRAME, {"camera": [0.0] * 15}, "16 items"),
    (P.FRAME, {"fov_x": 0.0}, "FRAME.fov_x"),
    (P.FRAME, {"width": 0}, "FRAME.width"),
    (P.FRAME, {"params": {"interleave": 99}}, "interleave"),
    (P.FRAME, {"params": {"no_such_param": 1}}, "no_such_param"),
    (P.FRAME, {"jitter": [0.5, 1.5]}, "FRAME.jitter"),
    (P.HELLO, {"threads": 0}, "HELLO.threads"),
    (P.HELLO, {"scenes": ["not-a-hash"]}, "HELLO.scenes"),
    (P.HELLO, {"name": "x" * 1000}, "longer"),
    (P.RESULT, {"data": "text"}, "RESULT.data"),
    (P.RESULT, {"timings": {"render": -1.0}}, "RESULT.timings"),
    (P.EDIT, {"edit": {"op": "rm -rf"}}, "edit op"),
    (P.EDIT, {"edit": {"op": "set_material", "value": [[1, 2]]}}, "edit values"),
    (P.WELCOME, {"heartbeat": 0.0}, "WELCOME.heartbeat"),
])
def test_schema_rejects_bad_fields(kind, changes, match):
    with pytest.raises(P.ProtocolError, match=match):
        P.decode(_bad(kind, **changes))


def test_outgoing_messages_are_checked_too():
    with pytest.raises(P.ProtocolError):
        P.encode(P.TASK, {"frame": 0})


def test_frame_spec_round_trip():
    from igi.common.frame import FrameSpec

    spec = FrameSpec(frame=5, seed=11, camera_to_world=tuple(float(i) for i in range(16)), fov_x=30.0,
                     width=10, height=8, params=params_to_dict(make_params(photons=7)), scene_version=2,
                     jitter=(0.25, 0.75))
    m = P.decode(P.encode(P.FRAME, P.frame_body(spec, H)))
    assert P.spec_from_body(m.body) == spec


def test_random_and_mutated_frames_never_raise_anything_but_protocol_errors():
    rng = random.Random(1234)
    seeds = [P.encode(k, b) for k, b in valid_bodies().items()]
    tried = 0
    for i in range(3000):
        if i % 2:
            frame = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 64)))
        else:
            frame = bytearray(rng.choice(seeds))
            for _ in range(rng.randrange(1, 6)):
                frame[rng.randrange(len(frame))] = rng.getrandbits(8)
            frame = bytes(frame)
        try:
            P.decode(frame)
        except P.ProtocolError:
            pass
        tried += 1
    assert tried == 3000
