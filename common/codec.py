"""Wire encoding of a task's TileBuffers (docs/architecture.md; bytes per frame in
docs/scaling.md; the paper's §4.3 "quantized and compressed").

Layout after a 12-byte header (magic b"IGTB", version, flags, pixel count P):
an lz4 frame (xxh32 checksum on each compressed block) holding, planar and byte-shuffled,
  reflectance, irradiance, unfiltered  3 x float16 each  (clamped to +-65504, NaN -> 0)
  lobe (only with flag FLAG_LOBE)      3 x float16       (negative: no lobe at the pixel)
  depth                                float32            (NaN -> inf = miss)
  normal                               2 x int16           octahedral, snorm16
= 26 bytes per pixel before compression, 32 with the lobe. Within a section the items run
channel by channel (all P red values, then all green, ...; for normals all x codes, then all
y), pixels in tile order, and the section is byte-shuffled (all first bytes of its items,
then all second bytes, ...): the slowly varying exponent bytes lie together, which is what
lz4 can exploit, and the decode reads every channel's bytes at unit stride.

Version 3 added the optional lobe section (a split glossy coat's radiance, filtered apart from
the irradiance); a task without lobes sends version 2's section layout. Version 2 (channels
apart) replaced version 1 (channels interleaved per pixel): the decode's stride-3 gathers took
~60% of the master's decode.
"""
from __future__ import annotations

import struct

import lz4.frame
import numpy as np

from igi.common.frame import NO_LOBE, TileBuffers

MAGIC = b"IGTB"
VERSION = 3
_HEADER = struct.Struct("<4sBBHI")  # magic, version, flags, reserved (0), pixel count
HEADER_SIZE = _HEADER.size
FLAG_LOBE = 0x01  # the payload holds the lobe section
BYTES_PER_PIXEL = 3 * 3 * 2 + 4 + 2 * 2
LOBE_BYTES_PER_PIXEL = 3 * 2
MAX_PIXELS = 1 << 26  # refuse headers that would make decode allocate absurd amounts

_F16_MAX = float(np.finfo(np.float16).max)  # 65504
_F16_MIN_NORMAL = np.float32(2.0 ** -14)
# float16 -> float32 by table: numpy's cast is slow for subnormal inputs, a gather is not.
_F16_TO_F32 = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16).view(np.float16).astype(np.float32)
_SNORM = 32767
_ZERO_NORMAL = -32768  # outside the snorm16 range: marks a zero (undefined) normal


# -- octahedral normals -----------------------------------------------------------------
def oct_encode(n: np.ndarray) -> np.ndarray:
    """(P, 3) normals -> (P, 2) int16 octahedral snorm16. Zero or non-finite normals get the
    reserved code (-32768, -32768) so they decode to zero rather than a made-up direction.
    float32 suffices: rounding to 1/32767 steps dwarfs its 6e-8 relative error (compiled:
    common.kernels.wire_encode)."""
    from igi.common.kernels.wire_encode import oct_encode_into

    n = np.ascontiguousarray(np.asarray(n, dtype=np.float32).reshape(-1, 3))
    q = np.empty((len(n), 2), np.int16)
    oct_encode_into(n, q)
    return q


def oct_decode(q: np.ndarray) -> np.ndarray:
    """(P, 2) int16 octahedral snorm16 -> (P, 3) float32 unit normals (zero for the reserved code)."""
    from igi.common.kernels.wire_decode import oct_decode_into

    q = np.asarray(q).reshape(-1, 2)
    out = np.empty((3, len(q)), np.float32)
    oct_decode_into(np.ascontiguousarray(q[:, 0], np.int16), np.ascontiguousarray(q[:, 1], np.int16), out)
    return np.ascontiguousarray(out.T)


# -- scalars ----------------------------------------------------------------------------
def to_f16(a: np.ndarray) -> np.ndarray:
    """float16 with NaN -> 0 and overflow clamped to +-65504 (never inf on the wire)."""
    a = np.clip(np.nan_to_num(np.asarray(a, dtype=np.float32), nan=0.0), -_F16_MAX, _F16_MAX)
    # numpy's float32 -> float16 cast takes a ~40x slower path for results in the float16
    # subnormal range (|x| < 2^-14; dark pixels hit it often): cast those as 0 and write
    # their bits directly (round-to-nearest-even of |x| * 2^24 is the subnormal mantissa).
    small = np.abs(a) < _F16_MIN_NORMAL
    h = np.where(small, np.float32(0.0), a).astype(np.float16)
    if small.any():
        v = a[small]
        bits = np.rint(np.abs(v) * np.float32(2.0 ** 24)).astype(np.uint16)
        bits |= np.where(np.signbit(v), np.uint16(0x8000), np.uint16(0))
        h.view(np.uint16)[small] = bits
    return h


def _sections(p: int, lobe: bool = False) -> list[tuple[str, np.dtype, int]]:
    colour = ("reflectance", "irradiance", "unfiltered") + (("lobe",) if lobe else ())
    return [(name, np.dtype("<f2"), 3 * p) for name in colour] + [("depth", np.dtype("<f4"), p),
                                                                 ("normal", np.dtype("<i2"), 2 * p)]


def payload_bytes(p: int, lobe: bool) -> int:
    """Bytes of the decompressed payload of ``p`` pixels, with or without the lobe section."""
    return p * (BYTES_PER_PIXEL + (LOBE_BYTES_PER_PIXEL if lobe else 0))


def payload_has_lobe(p: int, raw: np.ndarray) -> bool:
    """Whether a payload from :func:`decompress` holds the lobe section (its length says)."""
    return p > 0 and len(raw) == payload_bytes(p, True)


def encode(buffers: TileBuffers, compression_level: int = 0) -> bytes:
    """TileBuffers -> bytes (header + lz4 frame). compression_level 0 is lz4's fast mode."""
    p = len(buffers)
    if p > MAX_PIXELS:
        raise ValueError(f"{p} pixels exceed the codec limit of {MAX_PIXELS}")
    for name, shape in (("reflectance", (p, 3)), ("irradiance", (p, 3)), ("unfiltered", (p, 3)),
                        ("lobe", (p, 3)), ("depth", (p,)), ("normal", (p, 3))):
        if np.shape(getattr(buffers, name)) != shape:
            raise ValueError(f"buffer {name} has shape {np.shape(getattr(buffers, name))}, expected {shape}")
    from igi.common.kernels.wire_encode import payload_into

    lobe = buffers.has_lobe
    names = ("reflectance", "irradiance", "unfiltered") + (("lobe",) if lobe else ())
    colours = np.empty((len(names), p, 3), np.float32)
    for i, name in enumerate(names):
        colours[i] = getattr(buffers, name)
    if lobe:  # a red that is not >= 0 (NaN too) is no lobe: the wire would turn NaN into a lobe of 0
        colours[3][~(colours[3][:, 0] >= 0)] = NO_LOBE
    depth = np.ascontiguousarray(buffers.depth, dtype=np.float32).reshape(p)
    raw = np.empty(payload_bytes(p, lobe), np.uint8)
    # one compiled pass: float16 colours, depth, normals, each section byte-shuffled
    payload_into(colours, colours.view(np.uint32), depth, depth.view(np.uint32), oct_encode(buffers.normal), raw)
    # Checksums on the compressed blocks, not the content: a flipped byte is caught all the same
    # (lz4 checks each block's xxh32 before decompressing it), over 3x fewer bytes: the
    # content checksum took 4 of a 640x480 frame's 7 ms of decompression on the master.
    body = lz4.frame.compress(raw, compression_level=compression_level, content_checksum=False,
                              block_checksum=True, store_size=True)
    return _HEADER.pack(MAGIC, VERSION, FLAG_LOBE if lobe else 0, 0, p) + body


def decompress(data: bytes, count: int | None = None) -> tuple[int, np.ndarray]:
    """Validate ``data`` and lz4-decompress it: (pixel count P, the raw payload as a uint8
    array of :func:`payload_bytes` bytes, still planar and byte-shuffled — see
    :func:`section_planes`; :func:`payload_has_lobe` tells whether it holds the lobe section).
    Raises ValueError exactly where :func:`decode` does."""
    mv = memoryview(data)
    if len(mv) < HEADER_SIZE:
        raise ValueError(f"tile data too short for a header ({len(mv)} < {HEADER_SIZE} bytes)")
    magic, version, flags, reserved, p = _HEADER.unpack_from(mv)
    if magic != MAGIC:
        raise ValueError(f"not tile data: magic {bytes(magic)!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise ValueError(f"tile data version {version}, this build reads version {VERSION}")
    if flags & ~FLAG_LOBE or reserved:
        raise ValueError(f"tile data header has unknown flags {flags:#x}/{reserved:#x}")
    if count is not None and p != count:
        raise ValueError(f"tile data holds {p} pixels, expected {count}")
    if p > MAX_PIXELS:
        raise ValueError(f"tile data announces {p} pixels, above the limit of {MAX_PIXELS}")
    expected = payload_bytes(p, bool(flags & FLAG_LOBE))
    dec = lz4.frame.LZ4FrameDecompressor()
    try:
        # max_length bounds the output: a payload inflating beyond the header's size is
        # refused without decompressing the rest (no decompression bombs).
        raw = dec.decompress(bytes(mv[HEADER_SIZE:]), max_length=expected + 1)
    except RuntimeError as e:  # lz4 reports corrupt frames as RuntimeError
        raise ValueError(f"tile data is corrupt: {e}") from None
    if len(raw) > expected:
        raise ValueError(f"tile data decompresses to more than the {expected} bytes its header announces")
    if len(raw) < expected:
        raise ValueError(f"tile data is truncated: {len(raw)} of {expected} bytes decompressed")
    if not dec.eof:
        raise ValueError("tile data is truncated: the lz4 frame's end mark or checksum is missing")
    if dec.unused_data:
        raise ValueError(f"tile data has {len(dec.unused_data)} trailing bytes")
    return p, np.frombuffer(raw, np.uint8)


def section_offsets(p: int, lobe: bool = False) -> dict[str, int]:
    """Byte offset of every section in a decompressed payload of ``p`` pixels (the layout in
    this module's docstring; each section is ``itemsize`` byte planes of its values)."""
    out = {}
    pos = 0
    for name, dtype, n in _sections(p, lobe):
        out[name] = pos
        pos += n * dtype.itemsize
    return out


def section_planes(raw: np.ndarray, p: int) -> dict[str, np.ndarray]:
    """Views of a decompressed payload: name -> (itemsize, channels, P) uint8 byte planes
    (plane b holds byte b of every little-endian value, channel by channel, pixels in tile
    order)."""
    out = {}
    pos = 0
    for name, dtype, n in _sections(p, payload_has_lobe(p, raw)):
        size = n * dtype.itemsize
        out[name] = raw[pos:pos + size].reshape(dtype.itemsize, n // p if p else 1, p)
        pos += size
    return out


def decode_into(raw: np.ndarray, p: int, h: int, w: int, n: int, y0: int, x0: int,
                vals: np.ndarray, nrm: np.ndarray, depth: np.ndarray) -> bool:
    """Decode a payload of an h x w tile (``p`` = h·w pixels, from :func:`decompress`) into
    planar float32 arrays: ``vals`` (12, H, W) reflectance, irradiance, unfiltered, lobe (x RGB;
    the lobe NO_LOBE where the payload has none), ``nrm`` (3, H, W), ``depth`` (H, W); tile
    pixel (r, c) lands on (y0 + r·n, x0 + c·n). Returns whether the payload held a lobe.
    Compiled (``common.kernels.wire_decode``); the layout is this module's."""
    global _decode_tile
    if _decode_tile is None:  # numba loads only when something decodes
        from igi.common.kernels.wire_decode import decode_tile as _decode_tile
    lobe = payload_has_lobe(p, raw)
    if h * w != p or len(raw) != payload_bytes(p, lobe):
        raise ValueError(f"tile {h}x{w} does not match {p} pixels / {len(raw)} bytes")
    H, W = depth.shape
    if p and not (0 <= y0 and y0 + (h - 1) * n < H and 0 <= x0 and x0 + (w - 1) * n < W
                  and vals.shape == (12, H, W) and nrm.shape == (3, H, W)):
        raise ValueError(f"tile {h}x{w} at ({y0}, {x0}) step {n} is outside the {W}x{H} planes")
    o_r, o_i, o_u, o_l, o_d, o_n = (p * o for o in _PIXEL_OFFSETS[lobe])
    _decode_tile(raw, h, w, o_r, o_i, o_u, o_l if lobe else -1, o_d, o_n, n, y0, x0, vals, nrm,
                 depth.view(np.uint32), np.float32(NO_LOBE))
    return lobe


_decode_tile = None
# Section offsets are linear in the pixel count: those of one pixel, in _sections' order
# (without, with the lobe; the lobe's offset without it is unused).
_PIXEL_OFFSETS = tuple(tuple(section_offsets(1, lobe).get(name, 0) for name in
                             ("reflectance", "irradiance", "unfiltered", "lobe", "depth", "normal"))
                       for lobe in (False, True))


def decode(data: bytes, count: int | None = None) -> TileBuffers:
    """bytes -> TileBuffers (float32 arrays). ``count``, when given, must match the header.

    Raises ValueError for anything that is not a complete, well-formed message: wrong magic
    or version, a pixel count other than expected, truncated or corrupt lz4 data, or a
    payload that decompresses to more (or less) than the header announces.
    """
    return decode_raw(*decompress(data, count))


def decode_raw(p: int, raw: np.ndarray) -> TileBuffers:
    """TileBuffers of a payload from :func:`decompress`."""
    vals = np.empty((12, 1, p), np.float32)
    nrm = np.empty((3, 1, p), np.float32)
    depth = np.empty((1, p), np.float32)
    decode_into(raw, p, 1, p, 1, 0, 0, vals, nrm, depth)
    t = lambda a: np.ascontiguousarray(a[:, 0].T)
    return TileBuffers(reflectance=t(vals[0:3]), irradiance=t(vals[3:6]), unfiltered=t(vals[6:9]),
                       depth=depth[0], normal=t(nrm), lobe=t(vals[9:12]))
