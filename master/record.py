"""``igi record``: subscribe to a master's frame feed (ZeroMQ PUB, see docs/viewer.md) and write
the frames it receives to files.

    igi record tcp://127.0.0.1:5556 -o frames/ [--count N] [--format png|exr] [--timeout S]

It subscribes to the ``frame.f16`` topic (linear float16 radiance) and writes
``frame-<seq>.exr`` (linear float) or ``frame-<seq>.png`` (8-bit sRGB, ``--exposure`` stops).
Frames arrive at the stream's rate; a slow recorder loses frames rather than queueing them
(the feed's high-water mark). Exit status 0 after ``--count`` frames, 1 when no frame came
within ``--timeout`` seconds, 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HELP = "write frames from a master's ZeroMQ frame feed to files"
TOPIC = b"frame.f16"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("endpoint", help="the feed address printed by igi serve (default feed tcp://127.0.0.1:5556)")
    p.add_argument("-o", "--output", required=True, help="output folder (created)")
    p.add_argument("--count", type=int, default=10, help="frames to write, then exit (default 10; 0 = until Ctrl-C)")
    p.add_argument("--format", choices=("png", "exr"), default="png", help="png (sRGB 8 bit) or exr (linear float)")
    p.add_argument("--exposure", type=float, default=0.0, help="exposure in stops for PNG output")
    p.add_argument("--timeout", type=float, default=30.0, help="give up after this many seconds without a frame")
    p.add_argument("--every", type=int, default=1, help="keep every N-th received frame (default 1)")
    p.add_argument("-q", "--quiet", action="store_true", help="no line per frame")


def decode_frame(header: dict, payload: bytes):
    """(H, W, 3) float32 linear image from a ``frame.f16`` message (PNG payloads are decoded to
    linear float too)."""
    import numpy as np

    w, h = int(header["width"]), int(header["height"])
    if header.get("dtype") == "float16":
        a = np.frombuffer(payload, dtype="<f2")
        if a.size != w * h * 3:
            raise ValueError(f"payload has {a.size} values, expected {w}x{h}x3")
        return a.reshape(h, w, 3).astype(np.float32)
    if header.get("dtype") == "png":
        import io

        from PIL import Image

        from igi.common.image_io import srgb_to_linear

        with Image.open(io.BytesIO(payload)) as im:
            return srgb_to_linear(np.asarray(im.convert("RGB")) / 255.0).astype(np.float32)
    raise ValueError(f"unknown dtype {header.get('dtype')!r}")


def record(endpoint: str, output: str | Path, count: int = 10, fmt: str = "png", exposure: float = 0.0,
           timeout: float = 30.0, every: int = 1, quiet: bool = True, log=None) -> list[Path]:
    """Write ``count`` frames from the feed at ``endpoint``; returns the paths. TimeoutError when no
    frame arrives for ``timeout`` seconds."""
    import msgpack
    import zmq

    from igi.common.image_io import write_exr, write_png

    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, 4)
    sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
    sock.connect(endpoint)
    written: list[Path] = []
    received = 0
    try:
        while count <= 0 or len(written) < count:
            if not sock.poll(int(timeout * 1000)):
                raise TimeoutError(f"no frame from {endpoint} in {timeout:g} s")
            parts = sock.recv_multipart()
            if len(parts) != 3 or parts[0] != TOPIC:
                continue
            header = msgpack.unpackb(parts[1], raw=False)
            received += 1
            if (received - 1) % max(1, every):
                continue
            img = decode_frame(header, parts[2])
            path = out / f"frame-{int(header['frame']):06d}.{fmt}"
            if fmt == "exr":
                write_exr(path, img)
            else:
                write_png(path, img, exposure)
            written.append(path)
            if not quiet and log is not None:
                log(f"{path} ({header['width']}x{header['height']}, {header['accumulated']} accumulated)")
    finally:
        sock.close(0)
    return written


def run(args: argparse.Namespace) -> int:
    from .errors import UsageError

    if not args.endpoint.startswith(("tcp://", "ipc://", "inproc://")):
        raise UsageError(f"endpoint must look like tcp://HOST:PORT, got {args.endpoint!r}")
    if args.timeout <= 0 or args.every < 1:
        raise UsageError("--timeout must be > 0 and --every >= 1")

    def say(line):
        print(line, file=sys.stderr, flush=True)
    t0 = time.monotonic()
    try:
        paths = record(args.endpoint, args.output, args.count, args.format, args.exposure, args.timeout,
                       args.every, args.quiet, say)
    except TimeoutError as e:
        print(f"igi: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    if not args.quiet:
        say(f"wrote {len(paths)} frame(s) to {args.output} in {time.monotonic() - t0:.1f} s")
    return 0
