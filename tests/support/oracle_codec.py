"""The numpy wire decode that common.kernels.wire_decode replaced (as written before issue 16,
on codec version 2's layout: channels apart; version 3's optional lobe section added) and the
numpy octahedral encode that common.kernels.wire_encode replaced: test oracles, bit for bit the
references of the compiled codec."""
from __future__ import annotations

import numpy as np

from igi.common.codec import _SNORM, _ZERO_NORMAL, _sections, payload_has_lobe
from igi.common.frame import TileBuffers

# float16 -> float32 by table: numpy's cast is slow for subnormal inputs, a gather is not.
_F16_TO_F32 = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16).view(np.float16).astype(np.float32)


def _sign_nz(v: np.ndarray) -> np.ndarray:
    """sign with sign(0) = +1, so the octahedral fold is defined on the axes."""
    return np.where(v >= 0, np.float32(1.0), np.float32(-1.0))


def oct_encode(n: np.ndarray) -> np.ndarray:
    """(P, 3) normals -> (P, 2) int16 octahedral snorm16; the reserved code for zero or
    non-finite normals (common.codec.oct_encode's numpy form)."""
    n = np.asarray(n, dtype=np.float32).reshape(-1, 3)
    a = np.abs(n)
    l1 = a[:, 0] + a[:, 1] + a[:, 2]
    bad = ~(np.isfinite(l1) & (l1 > 0))
    p = n[:, :2] * (1.0 / np.where(bad, np.float32(1.0), l1))[:, None]
    p[bad] = 0.0
    lower = ~bad & (n[:, 2] < 0)
    # Lower hemisphere: fold the triangles outward across the diamond's edges.
    folded = (1.0 - np.abs(p[:, ::-1])) * _sign_nz(p)
    p = np.where(lower[:, None], folded, p)
    q = np.rint(np.clip(p, -1.0, 1.0) * np.float32(_SNORM)).astype(np.int16)
    q[bad] = _ZERO_NORMAL
    return q


def oct_decode(q: np.ndarray) -> np.ndarray:
    """(P, 2) int16 octahedral snorm16 -> (P, 3) float32 unit normals (zero for the reserved code)."""
    q = np.asarray(q).reshape(-1, 2)
    out = np.empty((3, len(q)), np.float32)
    oct_decode_planes(q[:, 0], q[:, 1], out)
    return np.ascontiguousarray(out.T)


def oct_decode_planes(qx: np.ndarray, qy: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Planar octahedral decode: int16 codes ``qx``, ``qy`` (any equal shape S) -> (3, *S)
    float32 unit normals, written to ``out`` when given (zero for the reserved code).

    The same float32 operations in the same order as the original per-pixel formulation
    (p = max(q/32767, -1); z = 1 - |px| - |py|; fold when z < 0; v / sqrt(v.v)), so the
    result is bit-identical to it; planar arrays just make every step one contiguous ufunc call.
    """
    qx, qy = np.asarray(qx), np.asarray(qy)
    if out is None:
        out = np.empty((3,) + qx.shape, np.float32)
    s = np.float32(1.0 / _SNORM)
    m1 = np.float32(-1.0)
    px = np.maximum(qx.astype(np.float32) * s, m1)
    py = np.maximum(qy.astype(np.float32) * s, m1)
    ax, ay = np.abs(px), np.abs(py)
    z = np.subtract(np.float32(1.0), ax, out=out[2])
    z -= ay
    # Branch-free, bit-exact selects on the float bits (np.where and np.copysign are several
    # times slower on this data).
    sign = np.uint32(0x80000000)
    lower = np.less(z, np.float32(0.0)).view(np.uint8).astype(np.uint32)
    mask = np.negative(lower, out=lower)  # 0xffffffff where folded, 0 elsewhere
    # (1 - |p_other|) * sign(p) with sign(0) = +1: p is never -0 here (q/32767 of an int), and
    # 1 - |p| >= +0, so OR-ing p's sign bit into it is the same product, bit for bit.
    ux = np.subtract(np.float32(1.0), ay, out=ay).view(np.uint32)
    ux |= px.view(np.uint32) & sign
    uy = np.subtract(np.float32(1.0), ax, out=ax).view(np.uint32)
    uy |= py.view(np.uint32) & sign
    vx, vy = out[0], out[1]
    for v, u, p in ((vx, ux, px), (vy, uy, py)):  # v = lower ? u : p, as bits
        pb = p.view(np.uint32)
        vb = v.view(np.uint32)
        np.bitwise_xor(u, pb, out=vb)
        vb &= mask
        vb ^= pb
    ux = ux.view(np.float32)
    # |v|^2 = (vx vx + vy vy) + z z, summed in this order (as einsum does for 3 terms)
    n2 = np.multiply(vx, vx, out=px)
    n2 += np.multiply(vy, vy, out=py)
    n2 += np.multiply(z, z, out=ux)
    inv = np.divide(np.float32(1.0), np.sqrt(n2, out=n2), out=n2)
    out *= inv
    zero = np.equal(qx, _ZERO_NORMAL)
    zero &= np.equal(qy, _ZERO_NORMAL)
    if zero.any():
        out[:, zero] = 0.0
    return out


def _unshuffle(raw: memoryview, dtype: np.dtype, count: int) -> np.ndarray:
    size = np.dtype(dtype).itemsize
    planes = np.frombuffer(raw, dtype=np.uint8, count=count * size).reshape(size, count)
    out = np.empty((count, size), np.uint8)
    for i in range(size):  # one strided copy per byte plane: ~5x faster than a transpose copy
        out[:, i] = planes[i]
    return out.view(dtype).reshape(count)



def f16_to_f32(codes: np.ndarray) -> np.ndarray:
    """float16 bit patterns (uint16, any shape) -> float32, by table (exact, no slow path for
    subnormals). Indices are widened to intp first: take() with narrow indices is ~3x slower."""
    return _F16_TO_F32.take(np.asarray(codes).astype(np.intp))


def decode_raw(p: int, raw: np.ndarray) -> TileBuffers:
    """TileBuffers of a payload from :func:`decompress`."""
    out = {}
    pos = 0
    raw_mv = memoryview(raw)
    for name, dtype, n in _sections(p, payload_has_lobe(p, raw)):
        size = n * dtype.itemsize
        out[name] = _unshuffle(raw_mv[pos:pos + size], dtype, n)
        pos += size
    # items run channel by channel (codec version 2): (channels, P) -> (P, channels)
    f32 = lambda h: np.ascontiguousarray(f16_to_f32(h.view(np.uint16)).reshape(3, p).T)
    return TileBuffers(
        reflectance=f32(out["reflectance"]),
        irradiance=f32(out["irradiance"]),
        unfiltered=f32(out["unfiltered"]),
        depth=out["depth"].astype(np.float32),
        normal=oct_decode(np.ascontiguousarray(out["normal"].reshape(2, p).T)),
        lobe=f32(out["lobe"]) if "lobe" in out else None,
    )


def encode_numpy(buffers: TileBuffers, compression_level: int = 0) -> bytes:
    """common.codec.encode as numpy built its payload (before wire_encode.payload_into): each
    section through to_f16 / astype, byte-shuffled with a transpose, joined, lz4."""
    import lz4.frame

    from igi.common.codec import _HEADER, FLAG_LOBE, MAGIC, VERSION, oct_encode, to_f16

    def shuffle(a):
        b = np.ascontiguousarray(a).view(np.uint8).reshape(-1, a.dtype.itemsize)
        return b.T.tobytes()

    p = len(buffers)
    depth = np.asarray(buffers.depth, dtype=np.float32)
    depth = np.where(np.isnan(depth), np.float32(np.inf), depth)
    lobe = buffers.has_lobe
    lobes = np.where(np.asarray(buffers.lobe)[:, :1] >= 0, buffers.lobe, np.float32(-1.0))  # NaN red: no lobe
    parts = ([to_f16(buffers.reflectance), to_f16(buffers.irradiance), to_f16(buffers.unfiltered)]
             + ([to_f16(lobes)] if lobe else []) + [depth.astype("<f4"), oct_encode(buffers.normal).astype("<i2")])
    raw = b"".join(shuffle(a.T.reshape(-1)) for a in parts)  # channel by channel (version 2)
    body = lz4.frame.compress(raw, compression_level=compression_level, content_checksum=False, block_checksum=True,
                              store_size=True)
    return _HEADER.pack(MAGIC, VERSION, FLAG_LOBE if lobe else 0, 0, p) + body
