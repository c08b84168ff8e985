"""The browser viewer: HTTP + WebSocket (aiohttp) in a background thread, plus a ZeroMQ PUB feed.

    handle = start(broker, host="127.0.0.1", port=8000, args=None)   # the ``igi serve`` hook
    handle.url, handle.token, handle.pub_endpoint; handle.stop()

Routes
------
``GET /``                 the page (``master/viewer_static/index.html``)
``GET /static/<file>``    its script and style sheet
``GET /ws``               the WebSocket (protocol below)
``GET /save.png``         the current accumulated image, 8-bit sRGB PNG, as a download
``GET /save.exr``         the same image, linear float OpenEXR, as a download
``GET /api/state``        JSON: view, parameter schema, scene objects, last stats (for scripts)

Access
------
Bound to a loopback address, nothing is asked. Bound to anything else (``--http 0.0.0.0:8000``)
every request needs the token printed at start: ``?token=…`` in the URL (the page passes it on
to its WebSocket and downloads; a successful request also sets a ``igi_token`` cookie), or the
``X-IGI-Token`` header. Wrong or missing token: 403. WebSocket upgrades whose ``Origin`` is not
this server are refused (403) in both cases, so another web site open in the same browser
cannot drive a loopback viewer. On loopback the ``Host`` header must also name this server
(``127.0.0.1``, ``localhost`` or ``[::1]`` with the port): anything else is 403 unless the token
is given, so a web page cannot reach a local viewer through a DNS-rebinding name.

Every size, camera and parameter set a client sends goes through :mod:`common.limits` (the
same checks as the CLI and the scene loader: memory budget, finite non-degenerate cameras);
a refused one gets ``{"type": "error", ...}`` and the stream goes on. Each client may apply at
most ``EDIT_RATE`` scene edits per second (burst ``EDIT_BURST``). A message that is not JSON,
or is nested too deeply, is answered with an error message.

WebSocket protocol
------------------
Server → client, text (JSON): ``{"type": "init", ...}`` (parameter schema from
``common.params.viewer_schema``, current params and view, scene objects, render plan),
``{"type": "stats", ...}`` twice a second (fps, accumulated, rays/s, workers, per-worker load,
``noise_estimate`` (= ``relative_error``: the relMSE of the mean estimated from its even/odd
frame halves; it cannot see bias), ``true_rel_mse`` against a reference image when one lies
beside the scene (``reference.exr`` in its folder, or ``../references/<name>.exr``) and the
view is the scene's own, ``workers_left`` (recent departures and why), input-to-frame latency,
render plan), ``{"type": "selected"|"moved"|"params"|
"view"|"error", ...}`` answers.

Server → client, binary: one frame = 4-byte big-endian header length, JSON header (seq,
generation, accumulated, width, height, mime, camera, scene_version, relative_error, latency),
then the JPEG or PNG bytes of the tone-mapped accumulated image. At most ``MAX_INFLIGHT`` frames
are unacknowledged per client; the client sends ``{"type": "ack", "seq": n}`` once it has drawn
frame n, and the server always sends the newest frame (older ones are dropped, never queued).

Client → server (JSON): ``ack``; ``camera`` {to_world: 16 floats row-major, fov_x?};
``params`` {values: {name: value}}; ``resolution`` {width, height}; ``reset``;
``settings`` {format: "jpeg"|"png", quality, exposure}; ``select`` {x, y} in image pixels
(float, origin top-left) or {mesh: i} / {emitter: i}; ``deselect``; ``move`` {delta: [dx, dy, dz]}
world-space translation of the selection (a ``transform_mesh`` edit, or ``set_emitter
position`` for a point/spot light).

ZeroMQ PUB feed (for programmatic clients; see docs/viewer.md and ``igi record``)
-------------------------------------------------------------------------------
An XPUB socket (default ``tcp://127.0.0.1:5556``) publishes every stream frame as three parts:
topic (``frame.f16`` or ``frame.png``), a msgpack header {frame, accumulated, width, height,
dtype, channels, generation, scene_version, relative_error, time}, and the payload: raw
little-endian float16 (H, W, 3) linear radiance, row 0 at the top, or PNG bytes (8-bit sRGB).
Each encoding is produced only while some subscriber's prefix matches its topic; slow
subscribers lose frames (SNDHWM) instead of queueing them.
"""
from __future__ import annotations

import asyncio
import concurrent.futures as cf
import hmac
import io
import ipaddress
import json
import logging
import math
import re
import secrets
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

log = logging.getLogger("igi.viewer")

STATIC = Path(__file__).resolve().parent / "viewer_static"
DEFAULT_PUB = "tcp://127.0.0.1:5556"
MAX_INFLIGHT = 2  # unacknowledged frames per WebSocket client
STATS_INTERVAL = 0.5  # seconds
TOKEN_COOKIE = "igi_token"
TOKEN_HEADER = "X-IGI-Token"
PUB_TOPICS = (b"frame.f16", b"frame.png")
LIGHT_PICK_RADIUS = 0.03  # point/spot lights are picked within this fraction of the scene diagonal
EDIT_RATE = 30.0  # scene edits (moves) per second and client ...
EDIT_BURST = 60  # ... with bursts up to this many
MAX_JSON_DEPTH = 32  # WebSocket messages nested deeper are refused before parsing


# ----------------------------------------------------------------------------- helpers

def is_loopback(host: str) -> bool:
    h = host.strip("[]")
    if h == "localhost":
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


_SRGB_LUT_SIZE = 4096
_SRGB_LUT = None


def tonemap8(rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB for the live stream (a 4096-entry table: ≤ 1 code from
    ``common.image_io.to_srgb8``, several times faster; downloads use the exact one)."""
    global _SRGB_LUT
    if _SRGB_LUT is None:
        from igi.common.image_io import linear_to_srgb

        x = np.arange(_SRGB_LUT_SIZE, dtype=np.float64) / (_SRGB_LUT_SIZE - 1)
        _SRGB_LUT = np.round(linear_to_srgb(x) * 255.0).astype(np.uint8)
    a = np.asarray(rgb, np.float32)
    scale = np.float32((2.0 ** exposure) * (_SRGB_LUT_SIZE - 1))
    idx = np.nan_to_num(a * scale, nan=0.0, posinf=_SRGB_LUT_SIZE - 1, neginf=0.0)
    np.clip(idx, 0, _SRGB_LUT_SIZE - 1, out=idx)
    return _SRGB_LUT[(idx + 0.5).astype(np.int32)]


def encode_image(rgb: np.ndarray, fmt: str = "jpeg", quality: int = 90, exposure: float = 0.0) -> bytes:
    """The tone-mapped image as JPEG or PNG bytes (Pillow)."""
    from PIL import Image

    im = Image.fromarray(tonemap8(rgb, exposure))
    buf = io.BytesIO()
    if fmt == "png":
        im.save(buf, format="PNG", compress_level=1)
    else:
        im.save(buf, format="JPEG", quality=int(quality))
    return buf.getvalue()


def _finite_vec(value, n: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected {n} numbers") from None
    if a.size != n or not np.isfinite(a).all():
        raise ValueError(f"{what}: expected {n} finite numbers")
    return a


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def _dumps(obj) -> str:
    return json.dumps(_jsonable(obj), separators=(",", ":"))


# ----------------------------------------------------------------------------- scene-side state

class SceneInfo:
    """Geometry (for picking) and render plan of one scene version, built lazily and cached."""

    def __init__(self):
        self._lock = threading.Lock()
        self._version = None
        self._geom = None
        self._lights = None
        self._plan = None
        self._plan_version = None

    def geometry(self, broker):
        """(scene, Geometry, LightSampler, version) of the broker's current scene."""
        from igi.common.geometry import Geometry
        from igi.common.lights import LightSampler

        with self._lock:
            version = broker.scene_version
            scene = broker.scene
            if self._version != version or self._geom is None:
                geom = Geometry(scene)
                self._geom, self._lights, self._version = geom, LightSampler(scene, geom), version
                self._scene = scene
            return self._scene, self._geom, self._lights, self._version

    def plan(self, broker) -> dict:
        """The render plan of the current scene version: {version, lines, flags}."""
        from igi.common.render_plan import analyze

        with self._lock:
            if self._plan is not None and self._plan_version == broker.scene_version:
                return self._plan
        scene, geom, lights, version = self.geometry(broker)
        try:
            p = analyze(scene, geom, lights)
            plan = {"version": version, "lines": p.lines(), "flags": p.to_dict()}
        except Exception as e:  # the plan is informational: never break the viewer
            log.exception("render plan failed")
            plan = {"version": version, "lines": [f"render plan unavailable: {e}"], "flags": {}}
        with self._lock:
            self._plan, self._plan_version = plan, version
        return plan

    def peek_plan(self) -> dict | None:
        with self._lock:
            return self._plan


def scene_objects(scene) -> dict:
    """Meshes and emitters for the page's object list."""
    meshes = [{"index": i, "name": m.name or f"mesh {i}", "emitter": int(m.emitter),
               "triangles": int(len(m.faces))} for i, m in enumerate(scene.meshes)]
    emitters = [{"index": i, "name": e.name or f"{e.kind} {i}", "kind": e.kind, "mesh": int(e.mesh),
                 "position": e.position.tolist()} for i, e in enumerate(scene.emitters)]
    lo, hi = scene.bounds()
    return {"meshes": meshes, "emitters": emitters, "bounds": [lo.tolist(), hi.tolist()],
            "center": ((lo + hi) / 2).tolist(), "diagonal": scene.diagonal()}


def pick(broker, info: SceneInfo, x: float, y: float) -> dict | None:
    """What the pixel (x, y) of the stream's view shows: a mesh (possibly an area light) or a
    point/spot light near the ray; None for the background."""
    from igi.common import scene as S
    from igi.common.camera import camera_rays

    v = broker.view()
    w, h = int(v["width"]), int(v["height"])
    if not (0 <= x <= w and 0 <= y <= h):
        raise ValueError(f"pixel ({x}, {y}) outside the {w}x{h} image")
    scene, geom, _lights, version = info.geometry(broker)
    o, d = camera_rays(np.asarray(v["camera"]), v["fov_x"], w, h, np.array([float(x)]), np.array([float(y)]),
                       jitter=(0.0, 0.0))
    hits = geom.intersect(o, d)
    best = None
    if hits.valid[0]:
        mi = int(hits.mesh[0])
        em = int(scene.meshes[mi].emitter)
        best = {"kind": "light" if em >= 0 else "mesh", "mesh": mi, "emitter": em if em >= 0 else None,
                "name": scene.meshes[mi].name or f"mesh {mi}", "point": hits.position[0].tolist(),
                "distance": float(hits.t[0])}
    r = LIGHT_PICK_RADIUS * geom.diagonal
    for ei, e in enumerate(scene.emitters):
        if e.kind not in (S.POINT, S.SPOT):
            continue
        oc = np.asarray(e.position, np.float64) - o[0]
        t = float(oc @ d[0])
        if t <= 0 or np.linalg.norm(oc - t * d[0]) > r:
            continue
        if best is None or t < best["distance"]:
            best = {"kind": "light", "mesh": None, "emitter": ei, "name": e.name or f"{e.kind} {ei}",
                    "point": np.asarray(e.position, np.float64).tolist(), "distance": t}
    if best is not None:
        best["version"] = version
    return best


def select_object(broker, mesh: int | None = None, emitter: int | None = None) -> dict:
    """Select by index (the page's object list): distance from the camera for drag scaling."""
    scene = broker.scene
    cam = np.asarray(broker.view()["camera"], np.float64).reshape(4, 4)
    if mesh is not None:
        mi = int(mesh)
        if not 0 <= mi < len(scene.meshes):
            raise ValueError(f"no mesh {mesh}")
        m = scene.meshes[mi]
        p = m.vertices.mean(axis=0) if len(m.vertices) else np.zeros(3)
        em = int(m.emitter)
        sel = {"kind": "light" if em >= 0 else "mesh", "mesh": mi, "emitter": em if em >= 0 else None,
               "name": m.name or f"mesh {mi}", "point": p.tolist()}
    elif emitter is not None:
        ei = int(emitter)
        if not 0 <= ei < len(scene.emitters):
            raise ValueError(f"no emitter {emitter}")
        e = scene.emitters[ei]
        if e.kind == "area" and 0 <= e.mesh < len(scene.meshes):
            return select_object(broker, mesh=e.mesh)
        sel = {"kind": "light", "mesh": None, "emitter": ei, "name": e.name or f"{e.kind} {ei}",
               "point": np.asarray(e.position, np.float64).tolist()}
    else:
        raise ValueError("select: give x and y, mesh or emitter")
    sel["distance"] = float(np.linalg.norm(np.asarray(sel["point"]) - cam[:3, 3]))
    sel["version"] = broker.scene_version
    return sel


def move_edit(broker, sel: dict, delta) -> dict:
    """The scene edit that translates the selection by ``delta`` (world space)."""
    from igi.common import scene as S

    dv = _finite_vec(delta, 3, "move.delta")
    if np.linalg.norm(dv) > 10 * broker.scene.diagonal():
        raise ValueError("move.delta: too large")
    if sel.get("mesh") is not None:
        m = np.eye(4)
        m[:3, 3] = dv
        return {"op": "transform_mesh", "mesh": int(sel["mesh"]), "matrix": [float(x) for x in m.reshape(16)]}
    ei = sel.get("emitter")
    if ei is None:
        raise ValueError("nothing selected")
    e = broker.scene.emitters[int(ei)]
    if e.kind not in (S.POINT, S.SPOT):
        raise ValueError(f"a {e.kind} light has no position to move")
    return {"op": "set_emitter", "emitter": int(ei), "param": "position",
            "value": [float(x) for x in np.asarray(e.position, np.float64) + dv]}


# ----------------------------------------------------------------------------- PUB feed

class FramePublisher:
    """Stream frames on a ZeroMQ XPUB socket (module docstring); a thread owns the socket."""

    def __init__(self, broker, address: str, context=None):
        import zmq

        self.broker = broker
        self._zmq = zmq
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.XPUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SNDHWM, 4)
        try:
            self._sock.bind(address)
        except zmq.ZMQError as e:
            self._sock.close(0)
            raise OSError(f"cannot bind the frame feed to {address}: {e}") from None
        self.endpoint = self._sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self._subs: dict[bytes, int] = {}
        self._latest = None
        self._sent_seq = 0
        self._running = True
        self.published = 0
        broker.add_frame_listener(self._on_frame)
        self._thread = threading.Thread(target=self._loop, name="igi-viewer-pub", daemon=True)
        self._thread.start()

    def _on_frame(self, sf) -> None:
        self._latest = sf  # the thread picks up the newest; nothing queues here

    def _wanted(self) -> list[bytes]:
        return [t for t in PUB_TOPICS if any(t.startswith(p) for p, n in self._subs.items() if n > 0)]

    def _loop(self) -> None:
        zmq = self._zmq
        while self._running:
            try:
                if self._sock.poll(10, zmq.POLLIN):
                    while True:
                        try:
                            msg = self._sock.recv(zmq.NOBLOCK)
                        except zmq.Again:
                            break
                        if msg and msg[0] in (0, 1):
                            topic = bytes(msg[1:])
                            self._subs[topic] = max(0, self._subs.get(topic, 0) + (1 if msg[0] == 1 else -1))
                sf = self._latest
                if sf is None or sf.seq <= self._sent_seq:
                    continue
                self._sent_seq = sf.seq
                for topic in self._wanted():
                    self._publish(topic, sf)
            except zmq.ZMQError:
                if not self._running:
                    return
                log.exception("frame feed")
            except Exception:  # pragma: no cover - never let the feed thread die
                log.exception("frame feed")

    def _publish(self, topic: bytes, sf) -> None:
        import msgpack

        zmq = self._zmq
        img = np.ascontiguousarray(sf.image, np.float32)
        h, w = img.shape[:2]
        if topic == b"frame.f16":
            payload = np.clip(img, -65504.0, 65504.0).astype("<f2").tobytes()  # float16's finite range
            dtype = "float16"
        else:
            payload = encode_image(img, "png")
            dtype = "png"
        header = {"frame": int(sf.seq), "accumulated": int(sf.accumulated), "width": int(w), "height": int(h),
                  "dtype": dtype, "channels": 3, "generation": int(sf.generation),
                  "scene_version": int(sf.spec.scene_version),
                  "relative_error": None if sf.relative_error is None else float(sf.relative_error),
                  "time": time.time()}
        try:
            self._sock.send_multipart([topic, msgpack.packb(header), payload], zmq.NOBLOCK)
            self.published += 1
        except zmq.Again:
            pass  # subscribers are behind: this frame is dropped for them

    def stop(self) -> None:
        self._running = False
        self.broker.remove_frame_listener(self._on_frame)
        self._thread.join(2.0)
        self._sock.close(0)


# ----------------------------------------------------------------------------- the server

@dataclass(eq=False)
class _Client:
    ws: Any
    wake: asyncio.Event
    inflight: int = 0
    sent_seq: int = 0
    fmt: str = "jpeg"
    quality: int = 90
    exposure: float = 0.0
    selection: dict | None = None
    edit_tokens: float = float(EDIT_BURST)
    edit_time: float = 0.0

    def take_edit(self) -> bool:
        """Token bucket: may this client apply one more scene edit now?"""
        now = time.monotonic()
        self.edit_tokens = min(float(EDIT_BURST), self.edit_tokens + (now - self.edit_time) * EDIT_RATE)
        self.edit_time = now
        if self.edit_tokens < 1.0:
            return False
        self.edit_tokens -= 1.0
        return True


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"?')


def json_depth_ok(text: str, limit: int = MAX_JSON_DEPTH) -> bool:
    """Whether brackets nest at most ``limit`` deep (strings skipped) — checked before json.loads,
    so a 100k-deep message costs a vectorised scan, not a RecursionError."""
    if text.count("[") + text.count("{") <= limit:
        return True
    b = np.frombuffer(_JSON_STRING.sub("", text).encode("utf-8", "replace"), np.uint8)
    step = ((b == 0x5B) | (b == 0x7B)).astype(np.int32) - ((b == 0x5D) | (b == 0x7D))
    return not len(step) or int(np.cumsum(step).max()) <= limit


def parse_message(text) -> dict:
    """A client's WebSocket text as a JSON object, or ValueError with one line."""
    if not isinstance(text, str):
        raise ValueError("message must be JSON text")
    if not json_depth_ok(text):
        raise ValueError(f"message nested deeper than {MAX_JSON_DEPTH} levels")
    try:
        m = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ValueError(f"message is not valid JSON ({str(e)[:80]})") from None
    if not isinstance(m, dict):
        raise ValueError("message must be a JSON object")
    return m


class Reference:
    """A converged reference image for the scene (``common.bundled.reference_of``), resampled to
    the stream's size on demand; ``rel_mse(sf, view, scene_camera)`` is None when the view is not
    the scene's own camera, the scene was edited, or there is no reference."""

    def __init__(self, path):
        self.path = Path(path) if path else None
        self._img = None
        self._sized: dict = {}
        self._lock = threading.Lock()
        self._last = None  # (frame, relMSE): stats ask twice a second, frames come slower

    def image(self, w: int, h: int):
        if self.path is None:
            return None
        with self._lock:
            if (w, h) in self._sized:
                return self._sized[(w, h)]
            try:
                if self._img is None:
                    from igi.common.image_io import read_image

                    self._img = np.asarray(read_image(self.path), np.float32)
                img = self._img
                if img.shape[:2] != (h, w):
                    from PIL import Image

                    img = np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(img[..., c]), "F")
                                               .resize((w, h), Image.BOX)) for c in range(3)], axis=-1)
            except Exception as e:  # an unreadable reference only disables the figure
                log.warning("reference %s unusable: %s", self.path, e)
                self.path, img = None, None
            if len(self._sized) > 4:
                self._sized.clear()
            self._sized[(w, h)] = img
            return img

    def rel_mse(self, sf, scene) -> float | None:
        if self.path is None or sf is None or sf.spec.scene_version != 0:
            return None
        if self._last is not None and self._last[0] is sf:
            return self._last[1]
        err = self._rel_mse(sf, scene)
        self._last = (sf, err)
        return err

    def _rel_mse(self, sf, scene) -> float | None:
        cam = scene.camera
        if not (np.allclose(np.asarray(sf.spec.camera_to_world, np.float64).reshape(16),
                            np.asarray(cam.to_world, np.float64).reshape(16), atol=1e-9)
                and abs(float(sf.spec.fov_x) - float(cam.fov_x)) < 1e-6):
            return None
        h, w = sf.image.shape[:2]
        ref = self.image(w, h)
        if ref is None:
            return None
        from igi.common.metrics import relmse

        return relmse(sf.image, ref)


class Viewer:
    """The aiohttp application in its own thread and event loop (see the module docstring)."""

    def __init__(self, broker, host: str = "127.0.0.1", port: int = 8000, *, token: str | None = None,
                 require_token: bool | None = None, pub: str | None = DEFAULT_PUB, pub_required: bool = False,
                 quiet: bool = False, reference=None):
        self.broker = broker
        self.host = host.strip("[]") or "127.0.0.1"
        self.port = int(port)
        self.require_token = (not is_loopback(self.host)) if require_token is None else bool(require_token)
        self.token = token or (secrets.token_urlsafe(18) if self.require_token else None)
        self.pub_address = pub
        self.pub_required = pub_required
        self.quiet = quiet
        self.url: str | None = None
        self.pub_endpoint: str | None = None
        self.publisher: FramePublisher | None = None
        self.info = SceneInfo()
        self._pool = cf.ThreadPoolExecutor(max_workers=4, thread_name_prefix="igi-viewer")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopping: asyncio.Event | None = None
        self._clients: set[_Client] = set()
        self._latest = None
        self._enc_cache: dict = {}
        self._enc_lock = threading.Lock()
        self._last_stats: dict | None = None
        self._view_latency: float | None = None
        self._last_gen = None
        self._stopped = False
        self.reference = Reference(reference)
        self._departed: list[dict] = []  # recent workers that left (name, reason, time)
        self._known_workers: dict[str, dict] = {}

    # -------------------------------------------------------------- lifecycle
    def start(self) -> "Viewer":
        self._thread = threading.Thread(target=self._run, name="igi-viewer", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            self._thread.join(5)
            raise self._error
        if self.pub_address:
            try:
                self.publisher = FramePublisher(self.broker, self.pub_address)
                self.pub_endpoint = self.publisher.endpoint
            except OSError as e:
                if self.pub_required:
                    self.stop()
                    raise
                log.warning("%s (frame feed off)", e)
            else:
                host = urlsplit(self.pub_endpoint.replace("tcp://", "http://", 1)).hostname or ""
                if self.pub_endpoint.startswith("tcp://") and not is_loopback(host):
                    log.warning("frame feed on %s: reachable from the network, without authentication",
                                self.pub_endpoint)
        self.broker.add_frame_listener(self._on_frame)
        latest = self.broker.latest_frame()
        if latest is not None:
            self._on_frame(latest)
        return self

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        self.broker.remove_frame_listener(self._on_frame)
        if self.publisher is not None:
            self.publisher.stop()
        if self._loop is not None and self._stopping is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopping.set)
            self._thread.join(10)
        self._pool.shutdown(wait=False, cancel_futures=True)

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._main())
        except BaseException as e:  # noqa: BLE001 - reported to start()
            if not self._ready.is_set():
                self._error = e
                self._ready.set()
            else:
                log.exception("viewer loop failed")
        finally:
            try:
                loop.run_until_complete(loop.shutdown_asyncgens())
            finally:
                loop.close()

    async def _main(self) -> None:
        from aiohttp import web

        self._stopping = asyncio.Event()
        app = web.Application(middlewares=[self._middleware_factory()], client_max_size=1 << 20)
        app.router.add_get("/", self._index)
        app.router.add_get("/index.html", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/save.png", self._save_png)
        app.router.add_get("/save.exr", self._save_exr)
        app.router.add_get("/api/state", self._state)
        app.router.add_static("/static/", STATIC, show_index=False, follow_symlinks=False)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
            try:
                await site.start()
            except OSError as e:
                raise OSError(f"cannot serve the viewer on {self.host}:{self.port}: {e.strerror or e}") from None
            sock = site._server.sockets[0]  # the bound port (port 0 = any free one)
            self.port = sock.getsockname()[1]
            shown = self.host
            if shown in ("0.0.0.0", "::"):
                shown = socket.gethostname()
            if ":" in shown:
                shown = f"[{shown}]"
            self.url = f"http://{shown}:{self.port}/" + (f"?token={self.token}" if self.require_token else "")
            stats_task = asyncio.ensure_future(self._stats_loop())
            self._ready.set()
            await self._stopping.wait()
            stats_task.cancel()
            for c in list(self._clients):
                await c.ws.close()
        finally:
            await runner.cleanup()

    # -------------------------------------------------------------- access
    def _token_ok(self, request) -> bool:
        if not self.require_token:
            return True
        given = (request.query.get("token") or request.headers.get(TOKEN_HEADER)
                 or request.cookies.get(TOKEN_COOKIE) or "")
        return hmac.compare_digest(given.encode(), self.token.encode())

    def _host_ok(self, request) -> bool:
        """On loopback: the Host header names this server (DNS-rebinding defence)."""
        if self.require_token:
            return True  # off loopback the token is the defence
        host = (request.headers.get("Host") or "").strip().lower()
        names = ("127.0.0.1", "localhost", "[::1]")
        allowed = {f"{n}:{self.port}" for n in names}
        if self.port == 80:
            allowed.update(names)
        return host in allowed

    def _token_given(self, request) -> bool:
        if not self.token:
            return False
        given = (request.query.get("token") or request.headers.get(TOKEN_HEADER)
                 or request.cookies.get(TOKEN_COOKIE) or "")
        return hmac.compare_digest(given.encode(), self.token.encode())

    @staticmethod
    def _same_origin(request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:
            return True  # not a browser page (scripts, curl)
        if origin == "null":
            return False
        return urlsplit(origin).netloc.lower() == (request.host or "").lower()

    def _middleware_factory(self):
        from aiohttp import web

        @web.middleware
        async def mw(request, handler):
            if not self._token_ok(request):
                return web.Response(status=403, text="igi viewer: a token is required (?token=… from the "
                                    "URL printed at start, or the X-IGI-Token header)\n")
            if not self._host_ok(request) and not self._token_given(request):
                log.info("viewer: refused a request for Host %r from %s", request.headers.get("Host"),
                         request.remote)
                return web.Response(status=403, text="igi viewer: unknown Host (use 127.0.0.1, localhost "
                                    "or [::1] with the port)\n")
            if request.path == "/ws" and not self._same_origin(request):
                return web.Response(status=403, text="igi viewer: cross-origin WebSocket refused\n")
            resp = await handler(request)
            if self.require_token and request.query.get("token") and hasattr(resp, "set_cookie"):
                resp.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="Strict")
            return resp
        return mw

    # -------------------------------------------------------------- HTTP handlers
    async def _index(self, request):
        from aiohttp import web

        host = request.host
        resp = web.FileResponse(STATIC / "index.html")
        resp.headers["Cache-Control"] = "no-store"
        resp.headers["Content-Security-Policy"] = (
            "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; "
            f"connect-src 'self' ws://{host} wss://{host}; frame-ancestors 'none'")
        resp.headers["X-Content-Type-Options"] = "nosniff"
        return resp

    async def _save(self, request, ext: str):
        from aiohttp import web

        sf = self.broker.latest_frame()
        if sf is None:
            return web.Response(status=503, text="no frame rendered yet\n")
        data = await asyncio.get_running_loop().run_in_executor(self._pool, _image_file, sf.image, ext)
        name = f"igi-{time.strftime('%Y%m%d-%H%M%S')}-{sf.accumulated}spp.{ext}"
        return web.Response(body=data, content_type="image/png" if ext == "png" else "image/x-exr",
                            headers={"Content-Disposition": f'attachment; filename="{name}"',
                                     "Cache-Control": "no-store",
                                     "X-IGI-Accumulated": str(sf.accumulated)})

    async def _save_png(self, request):
        return await self._save(request, "png")

    async def _save_exr(self, request):
        return await self._save(request, "exr")

    async def _state(self, request):
        from aiohttp import web

        init = await asyncio.get_running_loop().run_in_executor(self._pool, self._init_message)
        init["stats"] = self._last_stats
        return web.Response(text=_dumps(init), content_type="application/json")

    # -------------------------------------------------------------- frames
    def _on_frame(self, sf) -> None:
        """Broker finisher thread: remember the newest frame, wake the clients (no encoding here)."""
        if sf.generation != self._last_gen:
            self._last_gen = sf.generation
            self._view_latency = sf.time - sf.view_time
        self._latest = sf
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._wake_all)
            except RuntimeError:
                pass

    def _wake_all(self) -> None:
        for c in self._clients:
            c.wake.set()

    def _encoded(self, sf, fmt: str, quality: int, exposure: float) -> bytes:
        key = (sf.seq, fmt, quality, exposure)
        with self._enc_lock:
            hit = self._enc_cache.get(key)
        if hit is not None:
            return hit
        img = encode_image(sf.image, fmt, quality, exposure)
        h, w = sf.image.shape[:2]
        header = {"type": "frame", "seq": sf.seq, "generation": sf.generation, "accumulated": sf.accumulated,
                  "width": w, "height": h, "mime": "image/png" if fmt == "png" else "image/jpeg",
                  "camera": list(sf.spec.camera_to_world), "fov_x": sf.spec.fov_x,
                  "scene_version": sf.spec.scene_version, "relative_error": sf.relative_error,
                  "latency_ms": (sf.time - sf.view_time) * 1e3, "age_ms": (time.monotonic() - sf.time) * 1e3}
        hb = _dumps(header).encode()
        data = struct.pack(">I", len(hb)) + hb + img
        with self._enc_lock:
            if len(self._enc_cache) > 8:
                self._enc_cache.clear()
            self._enc_cache[key] = data
        return data

    async def _sender(self, c: _Client) -> None:
        try:
            await self._send_frames(c)
        except (ConnectionError, RuntimeError) as e:  # the client went away mid-send
            log.debug("viewer client gone: %s", e)

    async def _send_frames(self, c: _Client) -> None:
        loop = asyncio.get_running_loop()
        while not c.ws.closed:
            await c.wake.wait()
            c.wake.clear()
            while not c.ws.closed and c.inflight < MAX_INFLIGHT:
                sf = self._latest
                if sf is None or sf.seq <= c.sent_seq:
                    break
                data = await loop.run_in_executor(self._pool, self._encoded, sf, c.fmt, c.quality, c.exposure)
                if c.ws.closed:
                    return
                c.sent_seq = sf.seq
                c.inflight += 1
                await c.ws.send_bytes(data)

    # -------------------------------------------------------------- stats
    def _collect_stats(self) -> dict:
        s = self.broker.stats()
        plan = self.info.plan(self.broker)
        sf = self._latest
        v = self.broker.view()
        per = [{"name": w["name"], "host": w["host"], "threads": w["threads"], "load": w["load"],
                "busy": w["busy"], "inflight": w["inflight"], "tasks_done": w["tasks_done"]}
               for w in s.get("per_worker", [])]
        self._track_workers(per)
        try:
            true_err = self.reference.rel_mse(sf, self.broker.scene)
        except Exception:  # informational: never break the stats
            log.exception("reference relMSE")
            true_err = None
        return {"type": "stats", "fps": s["fps"], "accumulated": s["accumulated"], "rays_per_s": s["rays_per_s"],
                "workers": s["workers"], "threads": s["threads"], "per_worker": per,
                "relative_error": s["relative_error"], "noise_estimate": s["relative_error"],
                "true_rel_mse": true_err,
                "reference": self.reference.path.name if self.reference.path else None,
                "workers_left": list(self._departed[-5:]), "scene_version": s["scene_version"],
                "task_latency_ms": s["task_latency_ms"], "bytes_per_frame": s["bytes_per_frame"],
                "view_latency_ms": None if self._view_latency is None else self._view_latency * 1e3,
                "frame_seq": sf.seq if sf else 0, "width": v.get("width"), "height": v.get("height"),
                "clients": len(self._clients), "plan": plan,
                "pub": self.pub_endpoint}

    def note_worker_left(self, name: str, reason: str) -> None:
        """Record a departure the overlay shows (also called by ``igi serve``'s supervisor)."""
        self._departed.append({"name": name, "reason": reason, "time": time.time()})
        del self._departed[:-20]

    def _track_workers(self, per: list[dict]) -> None:
        now = {f'{w["name"]}@{w["host"]}': w for w in per}
        t = time.time()
        for key, w in self._known_workers.items():
            if key in now:
                continue
            if any(d["name"] in (key, w["name"]) and t - d["time"] < 60 for d in self._departed[-10:]):
                continue  # already told (e.g. by igi serve's supervisor, with the reason)
            self._departed.append({"name": key, "reason": "disconnected", "time": t})
        del self._departed[:-20]
        self._known_workers = now

    async def _stats_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            try:
                if self._clients:
                    s = await loop.run_in_executor(self._pool, self._collect_stats)
                    self._last_stats = s
                    text = _dumps(s)
                    for c in list(self._clients):
                        if not c.ws.closed:
                            try:
                                await c.ws.send_str(text)
                            except (ConnectionError, RuntimeError):
                                pass  # closing: its handler removes it
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("viewer stats")
            await asyncio.sleep(STATS_INTERVAL)

    # -------------------------------------------------------------- WebSocket
    def _init_message(self) -> dict:
        from igi.common.params import viewer_schema

        v = self.broker.view()
        scene = self.broker.scene
        from igi.common.params import values_in_use

        return {"type": "init", "schema": viewer_schema(), "params": v.get("params"),
                "in_use": values_in_use(v.get("params") or {}),
                "reference": self.reference.path.name if self.reference.path else None,
                "view": {"camera": list(v["camera"]), "fov_x": v["fov_x"], "width": v["width"], "height": v["height"]},
                "scene": scene_objects(scene), "scene_version": self.broker.scene_version,
                "plan": self.info.peek_plan(), "pub": self.pub_endpoint, "max_inflight": MAX_INFLIGHT}

    async def _ws(self, request):
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=1 << 20)
        await ws.prepare(request)
        loop = asyncio.get_running_loop()
        c = _Client(ws=ws, wake=asyncio.Event())
        self._clients.add(c)
        sender = asyncio.ensure_future(self._sender(c))
        try:
            await ws.send_str(_dumps(await loop.run_in_executor(self._pool, self._init_message)))
            c.wake.set()
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                m = None
                try:
                    m = parse_message(msg.data)
                    reply = await self._handle(c, m)
                except Exception as e:  # a bad message gets an error answer, never a crash
                    if not isinstance(e, (ValueError, KeyError, TypeError, OverflowError)):
                        log.exception("viewer message failed")
                    text = " ".join(str(e).split()) or type(e).__name__
                    if isinstance(e, KeyError):
                        text = f"missing field {text}"
                    reply = {"type": "error", "message": text[:300],
                             "request": m.get("type") if isinstance(m, dict) else None}
                if reply is not None and not ws.closed:
                    await ws.send_str(_dumps(reply))
        finally:
            self._clients.discard(c)
            sender.cancel()
        return ws

    async def _handle(self, c: _Client, m: dict) -> dict | None:
        loop = asyncio.get_running_loop()
        run = lambda fn, *a: loop.run_in_executor(self._pool, fn, *a)  # noqa: E731
        kind = m.get("type")
        b = self.broker
        if kind == "ack":
            c.inflight = max(0, c.inflight - 1)
            c.wake.set()
            return None
        if kind == "camera":
            from igi.common.limits import check_camera

            cam = _finite_vec(m.get("to_world"), 16, "camera.to_world")
            fov = m.get("fov_x")
            check_camera(cam, fov, what="camera")
            await run(lambda: b.set_camera(cam, None if fov is None else float(fov)))
            return None
        if kind == "params":
            values = m.get("values")
            if not isinstance(values, dict):
                raise ValueError("params.values: expected a map")
            from igi.common.limits import check_params
            from igi.common.params import make_params, params_to_dict, values_in_use

            merged = dict(b.view().get("params") or {})
            merged.update(values)
            check_params(params_to_dict(make_params(**merged)), emitters=len(b.scene.emitters))
            params = await run(lambda: b.set_params(**values))
            return {"type": "params", "params": params, "in_use": values_in_use(params)}
        if kind == "resolution":
            from igi.common.limits import check_resolution

            w, h = check_resolution(m.get("width"), m.get("height"))
            await run(b.set_resolution, w, h)
            return {"type": "view", "view": await run(self._view_dict)}
        if kind == "reset":
            await run(b.reset_accumulation)
            return None
        if kind == "settings":
            fmt = m.get("format", c.fmt)
            if fmt not in ("jpeg", "png"):
                raise ValueError("settings.format: jpeg or png")
            c.fmt = fmt
            c.quality = int(min(100, max(10, int(m.get("quality", c.quality)))))
            c.exposure = float(_finite_vec(m.get("exposure", c.exposure), 1, "settings.exposure")[0])
            c.exposure = min(20.0, max(-20.0, c.exposure))
            c.sent_seq = 0  # resend the current frame in the new settings
            c.wake.set()
            return None
        if kind == "select":
            if "x" in m and "y" in m:
                x, y = _finite_vec([m["x"], m["y"]], 2, "select")
                sel = await run(pick, b, self.info, float(x), float(y))
            else:
                sel = await run(lambda: select_object(b, m.get("mesh"), m.get("emitter")))
            c.selection = sel
            return {"type": "selected", "selection": sel}
        if kind == "deselect":
            c.selection = None
            return {"type": "selected", "selection": None}
        if kind == "move":
            if c.selection is None:
                raise ValueError("move: nothing selected")
            if not c.take_edit():
                raise ValueError(f"move: too many edits (at most {EDIT_RATE:g} per second); try again")
            sel = c.selection
            edit = await run(move_edit, b, sel, m.get("delta"))
            version = await run(b.apply_edit, edit)
            sel = dict(sel)
            sel["point"] = (np.asarray(sel["point"]) + _finite_vec(m.get("delta"), 3, "delta")).tolist()
            sel["version"] = version
            c.selection = sel
            return {"type": "moved", "version": version, "selection": sel, "edit": edit}
        if kind == "hello":
            return await run(self._init_message)
        raise ValueError(f"unknown message type {kind!r}")

    def _view_dict(self) -> dict:
        v = self.broker.view()
        return {"camera": list(v["camera"]), "fov_x": v["fov_x"], "width": v["width"], "height": v["height"]}


def _image_file(image: np.ndarray, ext: str) -> bytes:
    """EXR (linear float) or PNG (exact sRGB) bytes of ``image`` (via common.image_io)."""
    import os
    import tempfile

    from igi.common.image_io import write_exr, write_png

    fd, path = tempfile.mkstemp(suffix="." + ext)
    os.close(fd)
    try:
        (write_exr if ext == "exr" else write_png)(path, np.asarray(image, np.float32))
        return Path(path).read_bytes()
    finally:
        os.unlink(path)


# ----------------------------------------------------------------------------- the hook

def start(broker, host: str = "127.0.0.1", port: int = 8000, args=None, *, require_token: bool | None = None,
          token: str | None = None, pub: str | None = "default", quiet: bool = False) -> Viewer:
    """Start the viewer for ``broker`` (the ``igi serve`` hook); prints the URL (and the token).

    ``pub``: frame feed address; "default" takes ``args.pub`` when given, else
    :data:`DEFAULT_PUB` (a busy default port only logs a warning); None or "" turns it off.
    ``require_token``: None = only when ``host`` is not loopback."""
    pub_required = False
    if pub == "default":
        given = getattr(args, "pub", None) if args is not None else None
        if given is not None:
            pub, pub_required = (given if given.lower() not in ("", "none", "off") else None), True
        else:
            pub = DEFAULT_PUB
    elif pub:
        pub_required = True
    reference = None
    scene_path = getattr(args, "scene_path", None) if args is not None else None
    if scene_path:
        from igi.common.bundled import reference_of

        reference = reference_of(scene_path)
    v = Viewer(broker, host, port, token=token, require_token=require_token, pub=pub or None,
               pub_required=pub_required, quiet=quiet, reference=reference)
    try:
        v.start()
    except OSError as e:
        from igi.master.errors import UsageError

        raise UsageError(str(e)) from None
    if not quiet:
        print(f"igi viewer: {v.url}", file=sys.stderr, flush=True)
        if v.require_token:
            print(f"igi viewer: token {v.token} (required: bound to {v.host}, not loopback)",
                  file=sys.stderr, flush=True)
        if v.pub_endpoint:
            print(f"igi viewer: frames published on {v.pub_endpoint} (igi record {v.pub_endpoint} -o DIR)",
                  file=sys.stderr, flush=True)
    return v
