"""The master <-> worker protocol: one version, the message kinds and their schemas.

Transport: ZeroMQ, master ROUTER <-> worker DEALER (ZeroMQ guide: Majordomo / Paranoid
Pirate). Every message is ONE ZeroMQ frame holding one msgpack array::

    [PROTOCOL_VERSION, KIND, BODY]

``PROTOCOL_VERSION`` comes first so that any peer, of any version, can read it and answer a
mismatch with a REFUSE that names both versions. ``KIND`` is one of :data:`KINDS`, ``BODY`` a
map validated on receipt against :data:`SCHEMAS` (type and range of every field, no unknown
fields, no missing required field). A frame longer than :data:`MAX_MESSAGE_SIZE`
(:data:`MAX_SCENE_MESSAGE_SIZE` for SCENE, which only the master sends) is refused before it is
unpacked; msgpack's own container limits bound the memory an unpack may take.

Messages (W = worker, M = master)

========== ===== =====================================================================
kind       dir   body
========== ===== =====================================================================
HELLO      W->M  name, host, pid, threads, credit, scenes (hashes cached), renderer
WELCOME    M->W  worker (id the master gives it), heartbeat (s), liveness
SCENE      M->W  hash (sha256 of blob), blob (scene_codec bytes, or nil when the worker
                 listed the hash in HELLO), base_version, edits (list of edits on top of
                 the blob); the scene's version is base_version + len(edits)
EDIT       M->W  hash, version (the version this edit produces), edit (scene_codec edit)
FRAME      M->W  frame, hash, scene_version, seed, camera (16 floats), fov_x, width,
                 height, params (common.params dict), jitter (2 floats); sent to a worker
                 before the first TASK of that frame it gets
TASK       M->W  frame, task, epoch, k, tile [sx0, sy0, sx1, sy1] of sub-image k
RESULT     W->M  frame, task, epoch, count (pixels), data (common.codec bytes),
                 timings {name: seconds} (wait_scene, render, encode; sets: the part of
                 render spent building VPL/photon sets, which task timeouts allow for),
                 sets [[seed, k], ...] held by the worker (optional:
                 sent only when the list changed since the worker's last RESULT on this
                 connection; absent = unchanged plus the task's own set, which the master
                 adds — so a master keeps the last list per worker; an older worker that
                 sends it every time is still understood, hence no version bump),
                 rays (the worker's cumulative ray count, for rays/s)
HEARTBEAT  both  queued (tasks waiting or running on the worker; optional)
BYE        both  reason
ERROR      both  code, message, optional frame/task/epoch (e.g. a task that failed, or
                 "unregistered": the master does not know the sender -> send HELLO)
REFUSE     both  code ("version", "unsupported", ...), message, ours, theirs: the
                 sender will not talk to the receiver; a worker refused exits
========== ===== =====================================================================

Reliability (docs/scale-out.md, "The network contract"): each side sends HEARTBEAT when it has sent nothing else for
:data:`HEARTBEAT_INTERVAL` seconds, and any message received counts as a sign of life; a peer
silent for :data:`HEARTBEAT_LIVENESS` intervals is dead. The master gives every assignment a
fresh ``epoch``; a RESULT is accepted only for the task's current epoch of an open frame.
Credit-based flow control: a worker grants ``credit`` task slots in HELLO (default 3 per render
thread); the master never has more than that many tasks in flight on it, and every RESULT (or
task ERROR) returns one slot.
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

import msgpack

# 3: RESULT's data in common.codec version 3 (an optional lobe section); 2: codec version 2
# (channels apart). An older peer is refused at HELLO rather than having every tile refused as it
# arrives
PROTOCOL_VERSION = 3

HELLO = "HELLO"
WELCOME = "WELCOME"
SCENE = "SCENE"
EDIT = "EDIT"
FRAME = "FRAME"
TASK = "TASK"
RESULT = "RESULT"
HEARTBEAT = "HEARTBEAT"
BYE = "BYE"
ERROR = "ERROR"
REFUSE = "REFUSE"
KINDS = (HELLO, WELCOME, SCENE, EDIT, FRAME, TASK, RESULT, HEARTBEAT, BYE, ERROR, REFUSE)

HEARTBEAT_INTERVAL = 1.0  # seconds
HEARTBEAT_LIVENESS = 3  # intervals of silence before a peer is dead
CREDIT_PER_THREAD = 3

MAX_MESSAGE_SIZE = 64 << 20  # any message but SCENE
MAX_SCENE_MESSAGE_SIZE = 1 << 30
MAX_EDITS = 4096
INT53 = 2**53
MAX_IMAGE_SIDE = 16384


class ProtocolError(ValueError):
    """A message that is not valid for this protocol version; the text says why."""


class VersionMismatch(ProtocolError):
    """A well-formed message from a peer that speaks another protocol version."""

    def __init__(self, theirs: Any):
        self.theirs = theirs
        super().__init__(version_refusal_text(theirs))


def version_refusal_text(theirs: Any) -> str:
    return (f"protocol version mismatch: peer speaks igi protocol {theirs!r}, "
            f"this side speaks {PROTOCOL_VERSION}; upgrade the older side")


@dataclass(frozen=True)
class Message:
    kind: str
    body: dict
    version: int = PROTOCOL_VERSION


# --------------------------------------------------------------------------- field checks
# A checker takes (value, where) and returns the (possibly normalized) value or raises.

Checker = Callable[[Any, str], Any]


def _fail(where: str, what: str):
    raise ProtocolError(f"{where}: {what}")


def Int(lo: int = 0, hi: int = INT53) -> Checker:
    def check(v, where):
        if isinstance(v, bool) or not isinstance(v, int):
            _fail(where, f"expected an integer, got {type(v).__name__}")
        if not lo <= v <= hi:
            _fail(where, f"{v} outside [{lo}, {hi}]")
        return v
    return check


def Float(lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False) -> Checker:
    def check(v, where):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            _fail(where, f"expected a number, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v):
            _fail(where, "not finite")
        if not (lo < v if lo_open else lo <= v) or not v <= hi:
            _fail(where, f"{v} outside {'(' if lo_open else '['}{lo}, {hi}]")
        return v
    return check


def Str(maxlen: int = 256, pattern: str | None = None) -> Checker:
    rx = re.compile(pattern) if pattern else None

    def check(v, where):
        if not isinstance(v, str):
            _fail(where, f"expected a string, got {type(v).__name__}")
        if len(v) > maxlen:
            _fail(where, f"string longer than {maxlen}")
        if rx is not None and not rx.fullmatch(v):
            _fail(where, f"{v[:40]!r} is not of the expected form")
        return v
    return check


def Bytes(maxlen: int = MAX_MESSAGE_SIZE) -> Checker:
    def check(v, where):
        if not isinstance(v, (bytes, bytearray)):
            _fail(where, f"expected bytes, got {type(v).__name__}")
        if len(v) > maxlen:
            _fail(where, f"{len(v)} bytes, more than {maxlen}")
        return bytes(v)
    return check


def Nullable(inner: Checker) -> Checker:
    def check(v, where):
        return None if v is None else inner(v, where)
    return check


def List(item: Checker, maxlen: int = 1024, length: int | None = None) -> Checker:
    def check(v, where):
        if not isinstance(v, (list, tuple)):
            _fail(where, f"expected a list, got {type(v).__name__}")
        if length is not None and len(v) != length:
            _fail(where, f"expected {length} items, got {len(v)}")
        if len(v) > maxlen:
            _fail(where, f"more than {maxlen} items")
        return [item(x, f"{where}[{i}]") for i, x in enumerate(v)]
    return check


def MapOf(value: Checker, maxlen: int = 32, keylen: int = 64) -> Checker:
    key = Str(keylen)

    def check(v, where):
        if not isinstance(v, dict):
            _fail(where, f"expected a map, got {type(v).__name__}")
        if len(v) > maxlen:
            _fail(where, f"more than {maxlen} entries")
        return {key(k, f"{where} key"): value(x, f"{where}.{k}") for k, x in v.items()}
    return check


HASH = Str(64, r"[0-9a-f]{64}")
NAME = Str(128)


def _params(v, where):
    """A render parameter dict, checked against common.params declarations (full set)."""
    from .params import PARAMS, make_params, params_to_dict

    if not isinstance(v, dict) or len(v) > 4 * len(PARAMS):
        _fail(where, "expected a parameter map")
    for k in v:
        if not isinstance(k, str):
            _fail(where, "parameter names must be strings")
    try:
        return params_to_dict(make_params(**dict(v)))
    except (ValueError, TypeError) as e:
        _fail(where, str(e))


def _edit_value(v, where, depth=0):
    if isinstance(v, bool) or v is None:
        return v
    if isinstance(v, int):
        return Int(-INT53, INT53)(v, where)
    if isinstance(v, float):
        return Float()(v, where)
    if isinstance(v, str):
        return Str(128)(v, where)
    if isinstance(v, (list, tuple)) and depth == 0:
        return List(lambda x, w: _edit_value(x, w, 1), maxlen=16)(v, where)
    _fail(where, "edit values are numbers, strings or short lists of numbers")


def _edit(v, where):
    """Shape of a scene edit (semantic checks happen in scene_codec.apply_edit)."""
    from .scene_codec import EDIT_OPS

    if not isinstance(v, dict) or len(v) > 8:
        _fail(where, "expected an edit map of at most 8 entries")
    op = v.get("op")
    if op not in EDIT_OPS:
        _fail(where, f"unknown edit op {op!r}")
    return {Str(32)(k, f"{where} key"): _edit_value(x, f"{where}.{k}") for k, x in v.items()}


def _tile(v, where):
    t = List(Int(0, MAX_IMAGE_SIDE), length=4)(v, where)
    if not (t[0] < t[2] and t[1] < t[3]):
        _fail(where, f"empty tile {t}")
    return t


def _set_key(v, where):
    return List(Int(0, INT53), length=2)(v, where)


# Schemas: kind -> {field: (checker, required)}
R, O = True, False
SCHEMAS: dict[str, dict[str, tuple[Checker, bool]]] = {
    HELLO: {
        "name": (NAME, R),
        "host": (Str(255), R),
        "pid": (Int(0, 2**31), R),
        "threads": (Int(1, 1024), R),
        "credit": (Int(1, 4096), R),
        "scenes": (List(HASH, maxlen=64), R),
        "renderer": (Str(128), O),
        "cores": (Int(1, 65536), O),
    },
    WELCOME: {
        "worker": (NAME, R),
        "heartbeat": (Float(0.001, 3600, lo_open=True), R),
        "liveness": (Int(1, 1000), R),
    },
    SCENE: {
        "hash": (HASH, R),
        "blob": (Nullable(Bytes(MAX_SCENE_MESSAGE_SIZE)), R),
        "base_version": (Int(0, INT53), R),
        "edits": (List(_edit, maxlen=MAX_EDITS), R),
    },
    EDIT: {
        "hash": (HASH, R),
        "version": (Int(1, INT53), R),
        "edit": (_edit, R),
    },
    FRAME: {
        "frame": (Int(), R),
        "hash": (HASH, R),
        "scene_version": (Int(), R),
        "seed": (Int(0, 2**32 - 1), R),
        "camera": (List(Float(), length=16), R),
        "fov_x": (Float(0.0, 180.0, lo_open=True), R),
        "width": (Int(1, MAX_IMAGE_SIDE), R),
        "height": (Int(1, MAX_IMAGE_SIDE), R),
        "params": (_params, R),
        "jitter": (List(Float(0.0, 1.0), length=2), R),
    },
    TASK: {
        "frame": (Int(), R),
        "task": (Int(0, 2**31), R),
        "epoch": (Int(), R),
        "k": (Int(0, 255), R),
        "tile": (_tile, R),
    },
    RESULT: {
        "frame": (Int(), R),
        "task": (Int(0, 2**31), R),
        "epoch": (Int(), R),
        "count": (Int(0, MAX_IMAGE_SIDE * MAX_IMAGE_SIDE), R),
        "data": (Bytes(MAX_MESSAGE_SIZE), R),
        "timings": (MapOf(Float(0.0, 1e6)), O),
        "sets": (List(_set_key, maxlen=4096), O),
        "rays": (Int(0, INT53), O),
    },
    HEARTBEAT: {
        "queued": (Int(0, 1 << 20), O),
    },
    BYE: {
        "reason": (Str(256), O),
    },
    ERROR: {
        "code": (Str(64), R),
        "message": (Str(1024), R),
        "frame": (Int(), O),
        "task": (Int(0, 2**31), O),
        "epoch": (Int(), O),
    },
    REFUSE: {
        "code": (Str(64), R),
        "message": (Str(1024), R),
        "ours": (Int(0, 2**31), R),
        "theirs": (Nullable(Int(-(2**63), 2**64)), O),
    },
}


def validate(kind: str, body: Any) -> dict:
    """The checked body of a ``kind`` message; ProtocolError naming the first bad field."""
    schema = SCHEMAS.get(kind)
    if schema is None:
        raise ProtocolError(f"unknown message kind {str(kind)[:32]!r}")
    if not isinstance(body, dict):
        raise ProtocolError(f"{kind}: body is not a map")
    unknown = [k for k in body if k not in schema]
    if unknown:
        raise ProtocolError(f"{kind}: unknown field(s) {', '.join(repr(str(k))[:40] for k in unknown[:5])}")
    out = {}
    for name, (check, required) in schema.items():
        if name in body:
            out[name] = check(body[name], f"{kind}.{name}")
        elif required:
            raise ProtocolError(f"{kind}: missing field {name!r}")
    return out


# --------------------------------------------------------------------------- framing

def encode(kind: str, body: dict | None = None, *, check: bool = True,
           version: int = PROTOCOL_VERSION) -> bytes:
    """One wire frame. Outgoing bodies are validated too (``check=False`` skips it, e.g. for
    big RESULT/SCENE payloads already built from checked parts, or for tests that forge)."""
    body = {} if body is None else body
    if check:
        body = validate(kind, body)
    return msgpack.packb([version, kind, body], use_bin_type=True)


def peek_version(frame: bytes) -> Any:
    """The version a frame claims, or None when it is not an igi-shaped message."""
    try:
        up = msgpack.Unpacker(max_buffer_size=len(frame) + 1, max_bin_len=0, max_str_len=64,
                              max_array_len=3, max_map_len=0, raw=False)
        up.feed(frame)
        if up.read_array_header() != 3:
            return None
        v = up.unpack()
        return v if isinstance(v, int) and not isinstance(v, bool) else None
    except Exception:
        return None


def decode(frame: bytes, max_size: int = MAX_MESSAGE_SIZE) -> Message:
    """Parse and validate one frame.

    Raises VersionMismatch (a ProtocolError) for a well-formed message of another version —
    except a REFUSE, which is returned whatever its version so a refused peer can show why —
    and ProtocolError for anything else that is wrong.
    """
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise ProtocolError("message is not bytes")
    if len(frame) > max_size:
        raise ProtocolError(f"message of {len(frame)} bytes exceeds the limit of {max_size}")
    try:
        obj = msgpack.unpackb(bytes(frame), raw=False, strict_map_key=False, use_list=True,
                              max_bin_len=max_size, max_str_len=1 << 20,
                              max_array_len=1 << 22, max_map_len=1 << 16, max_ext_len=0)
    except Exception as e:
        raise ProtocolError(f"not a msgpack message ({type(e).__name__})") from None
    if not isinstance(obj, list) or len(obj) != 3:
        raise ProtocolError("not an igi message (expected [version, kind, body])")
    version, kind, body = obj
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProtocolError("not an igi message (version is not an integer)")
    if not isinstance(kind, str):
        raise ProtocolError("not an igi message (kind is not a string)")
    if version != PROTOCOL_VERSION:
        if kind == REFUSE and isinstance(body, dict):
            msg = body.get("message")
            return Message(REFUSE, {"code": str(body.get("code", "version"))[:64],
                                    "message": str(msg)[:1024] if msg is not None else version_refusal_text(version),
                                    "ours": version, "theirs": PROTOCOL_VERSION}, version)
        raise VersionMismatch(version)
    if kind not in SCHEMAS:
        raise ProtocolError(f"unknown message kind {kind[:32]!r}")
    return Message(kind, validate(kind, body), version)


def refusal(theirs: Any, code: str = "version", message: str | None = None) -> bytes:
    """The REFUSE frame answering a peer of another version (or refused for ``code``)."""
    theirs_int = theirs if isinstance(theirs, int) and not isinstance(theirs, bool) else None
    return encode(REFUSE, {"code": code, "message": (message or version_refusal_text(theirs))[:1024],
                           "ours": PROTOCOL_VERSION, "theirs": theirs_int})


def frame_body(spec, scene_hash: str) -> dict:
    """FRAME body of a :class:`common.frame.FrameSpec`."""
    return {"frame": spec.frame, "hash": scene_hash, "scene_version": spec.scene_version,
            "seed": spec.seed, "camera": [float(x) for x in spec.camera_to_world],
            "fov_x": float(spec.fov_x), "width": spec.width, "height": spec.height,
            "params": dict(spec.params), "jitter": [float(spec.jitter[0]), float(spec.jitter[1])]}


def spec_from_body(body: dict):
    """FrameSpec of a (validated) FRAME body."""
    from .frame import FrameSpec

    return FrameSpec(frame=body["frame"], seed=body["seed"], camera_to_world=tuple(body["camera"]),
                     fov_x=body["fov_x"], width=body["width"], height=body["height"],
                     params=body["params"], scene_version=body["scene_version"],
                     jitter=tuple(body["jitter"]))


# --------------------------------------------------------------------------- CURVE (issue 8)
# Optional authentication + encryption between master and workers (ZeroMQ CURVE, pyzmq's
# zmq.auth). Key directory layout, as written by generate_keys():
#
#   DIR/master.key, DIR/master.key_secret   the master's keypair (the secret stays on the master)
#   DIR/workers/NAME.key                    public keys of the workers the master accepts
#   DIR/NAME.key_secret (+ DIR/NAME.key)    a worker's keypair (copied to that worker only)
#
# The master needs master.key_secret and workers/; a worker needs its NAME.key_secret and
# master.key. curve_server()/curve_client() return the ``configure_socket`` hooks of
# master.broker.Broker and worker.node.WorkerNode. A peer whose public key is not in
# workers/ (or that speaks plain NULL security, or expects another master key) fails the
# handshake: it never gets a message through, the scene included.

CURVE_MASTER = "master"
CURVE_WORKERS_DIR = "workers"


def generate_keys(directory, workers=("worker",)) -> dict:
    """Create the master keypair and one keypair per worker name in ``directory`` (see the
    layout above; existing keys are kept). Returns {"master": path, "workers": {name: secret path}}."""
    import shutil
    from pathlib import Path

    import zmq.auth

    d = Path(directory)
    pub = d / CURVE_WORKERS_DIR
    pub.mkdir(parents=True, exist_ok=True)
    if not (d / f"{CURVE_MASTER}.key_secret").exists():
        zmq.auth.create_certificates(str(d), CURVE_MASTER)
    out = {"master": str(d / f"{CURVE_MASTER}.key_secret"), "workers": {}}
    for name in workers:
        if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", name) or name == CURVE_MASTER:
            raise ValueError(f"bad worker key name {name!r} (letters, digits, '_', '.', '-')")
        if not (d / f"{name}.key_secret").exists():
            zmq.auth.create_certificates(str(d), name)
        shutil.copyfile(d / f"{name}.key", pub / f"{name}.key")
        out["workers"][name] = str(d / f"{name}.key_secret")
    for p in d.glob("*.key_secret"):
        p.chmod(0o600)
    return out


def _load_cert(path, secret: bool):
    from pathlib import Path

    import zmq.auth

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"CURVE key file {p} not found (igi keys creates it)")
    public, sec = zmq.auth.load_certificate(str(p))
    if secret and not sec:
        raise ValueError(f"{p} holds no secret key")
    return public, sec


class CurveServer:
    """``configure_socket`` hook for the master's ROUTER: CURVE server with the master's keypair;
    a ZAP authenticator (one per ZeroMQ context, started on first use) accepts only the public
    keys in DIR/workers/. Call :meth:`stop` when the broker is stopped."""

    def __init__(self, directory):
        from pathlib import Path

        d = Path(directory)
        self.public, self.secret = _load_cert(d / f"{CURVE_MASTER}.key_secret", secret=True)
        self.allowed = d / CURVE_WORKERS_DIR
        if not self.allowed.is_dir():
            raise FileNotFoundError(f"{self.allowed}: no directory of accepted worker keys")
        self._auths: list = []

    def __call__(self, sock) -> None:
        from .curve_log import LoggingAuthenticator

        if not any(a.context is sock.context for a in self._auths):
            auth = LoggingAuthenticator(sock.context, log=logging.getLogger("igi.auth"))  # denials: INFO
            auth.start()
            auth.configure_curve(domain="*", location=str(self.allowed))
            self._auths.append(auth)
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_server = True

    def stop(self) -> None:
        for a in self._auths:
            a.stop()
        self._auths.clear()


class CurveClient:
    """``configure_socket`` hook for a worker's DEALER: its keypair DIR/NAME.key_secret and the
    master's public key DIR/master.key."""

    def __init__(self, directory, name: str = "worker"):
        from pathlib import Path

        d = Path(directory)
        self.public, self.secret = _load_cert(d / f"{name}.key_secret", secret=True)
        self.server_public, _ = _load_cert(d / f"{CURVE_MASTER}.key", secret=False)

    def __call__(self, sock) -> None:
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_serverkey = self.server_public
