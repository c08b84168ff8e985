"""The scaling model (bench/scaling_model.py) and the master's parallel wire path (issue 12).

The model: deterministic, monotone in the worker count up to the bottleneck, exact on a
hand-computed case, and it names the right bottleneck in constructed cases. The master: the
wire path (FrameAssembler.add_wire + parallel image) gives bit-identical buffers and images to
the per-tile decode path, whatever the thread count; the new codec and filter kernels equal
the originals bit for bit. No wall-clock thresholds here.
"""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.codec import decode, encode, oct_decode
from tests.support.oracle_codec import oct_decode_planes
from igi.common.frame import TileBuffers
from igi.common.interleave import extract
from igi.common.params import make_params, params_to_dict
from igi.master import parallel
from igi.master.discontinuity_buffer import filter_irradiance, window_offsets
from igi.master.frame_assembly import FrameAssembler, task_tiles, tile_pixel_count
from igi.bench.scaling_model import LOOPBACK, NETWORKS, Config, Costs, Network, simulate

ZERO_NET = Network("zero", float("inf"), 0.0)


def _costs(**kw) -> Costs:
    base = dict(render_s_per_px=40e-3 / 2844, set_build_s=0.0, encode_s_per_px=0.0, bytes_per_px=7.0,
                result_overhead_bytes=0.0, task_bytes=0.0, master_msg_s=0.0, master_recv_s_per_px=0.0,
                finish_s_per_px=0.0, accumulate_s_per_px=0.0)
    base.update(kw)
    return Costs(**base)


# ------------------------------------------------------------------------------ the model
def test_simulation_is_deterministic():
    c = _costs(set_build_s=0.03, master_msg_s=80e-6, master_recv_s_per_px=30e-9, finish_s_per_px=150e-9,
               tile_weights=(0.5, 1.5, 1.0, 1.0), tile_grid=(2, 2))
    for cfg in (Config(workers=7), Config(workers=2, shared_host_cores=2, background=0.7, network=LOOPBACK)):
        a, b = simulate(c, cfg), simulate(c, cfg)
        assert a.frame_done == b.frame_done and a.utilization == b.utilization
        assert a.bottleneck == b.bottleneck


def test_one_worker_zero_costs_frame_time_is_the_sum_of_task_times():
    """Hand-computed: 1 worker, no network, no master cost, one frame in flight: every frame
    takes exactly the sum of its task times (set builds included: 9 sets per new seed)."""
    per_px, build, enc = 1e-5, 0.02, 1e-7
    c = _costs(render_s_per_px=per_px, set_build_s=build, encode_s_per_px=enc)
    cfg = Config(workers=1, width=64, height=48, interleave=3, task_pixels=100, pipeline=1, frames=4,
                 warmup=1, network=ZERO_NET)
    tiles = task_tiles(64, 48, 3, 100)
    px = sum(tile_pixel_count(t, 3, 64, 48) for t in tiles)
    expected = px * (per_px + enc) + 9 * build
    r = simulate(c, cfg)
    assert r.frame_s == pytest.approx(expected, rel=1e-12)
    assert np.allclose(np.diff(r.frame_done), expected, rtol=1e-12)
    assert r.set_builds_per_frame == 9
    assert r.bottleneck.startswith("workers")


def test_frames_per_second_grow_with_workers_until_the_bottleneck():
    c = _costs(master_msg_s=50e-6, master_recv_s_per_px=20e-9, finish_s_per_px=100e-9)
    # small tasks: the engine's linearity, not the task-size policy's balance
    fps = [simulate(c, Config(workers=w, accumulate=False, task_pixels=4096)).fps for w in (1, 2, 4, 8, 16, 32, 64)]
    assert all(b >= a * (1 - 1e-9) for a, b in zip(fps, fps[1:]))
    assert fps[3] == pytest.approx(8 * fps[0], rel=0.05)  # near-linear while the workers bind
    # a master that costs more than the workers can deliver caps the rate
    slow = _costs(finish_s_per_px=2e-6)
    capped = [simulate(slow, Config(workers=w, master_threads=1, accumulate=False)).fps for w in (8, 16, 32, 64)]
    assert max(capped) <= 1 / (640 * 480 * 2e-6) * 1.0001
    assert capped[-1] == pytest.approx(capped[-2], rel=0.02)


@pytest.mark.parametrize("case,expected", [
    ("workers", "workers"),
    ("filter", "master finish"),
    ("receive", "master loop"),
    ("network", "master link"),
    ("tasks", "task supply"),
])
def test_bottleneck_attribution(case, expected):
    c, cfg = _costs(), Config(workers=4, accumulate=False)
    if case == "filter":
        c, cfg = _costs(finish_s_per_px=3e-6), Config(workers=64, master_threads=1, accumulate=False)
    elif case == "receive":
        c, cfg = _costs(master_recv_s_per_px=3e-6), Config(workers=64, accumulate=False)
    elif case == "network":
        cfg = Config(workers=64, network=Network("slow", 0.1e9, 50e-6), accumulate=False)
    elif case == "tasks":
        cfg = Config(workers=256, width=320, height=240, accumulate=False)
    r = simulate(c, cfg)
    assert r.bottleneck == expected, r.utilization


def test_bytes_per_frame_and_shared_host_contention():
    c = _costs(bytes_per_px=6.5, result_overhead_bytes=100.0)
    r = simulate(c, Config(workers=3, width=320, height=240))
    tiles = task_tiles(320, 240, Config(workers=3).interleave)
    assert r.bytes_per_frame == pytest.approx(320 * 240 * 6.5 + 100.0 * len(tiles))
    # two workers on one 2-core host with a busy background run slower than on their own hosts
    alone = simulate(c, Config(workers=2, network=LOOPBACK))
    shared = simulate(c, Config(workers=2, network=LOOPBACK, shared_host_cores=2, background=1.0))
    assert shared.fps == pytest.approx(alone.fps * 2 / 3, rel=0.05)
    assert 0 < shared.utilization["shared CPU"] <= 1.0 + 1e-9


def test_networks_order_and_set_reuse():
    c = _costs(set_build_s=0.03)
    fast, mid, slow = (simulate(c, Config(workers=64, width=1920, height=1080, network=n, frames=4, warmup=2,
                                                     task_pixels=4096)).fps
                       for n in reversed(NETWORKS))
    assert fast >= mid >= slow
    acc = simulate(c, Config(workers=16))
    moving = simulate(c, Config(workers=16, accumulate=False))
    assert moving.set_builds_per_frame == 0 and acc.set_builds_per_frame >= 9
    assert moving.fps > acc.fps


# ------------------------------------------------------------------------------ the master
def _frame(w=97, h=61, seed=0):
    """Full-frame buffers with walls, a sphere-ish patch, misses, dark (subnormal) values."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    wall = (xx * 3 // w) + 3 * (yy * 2 // h)
    normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0], [0, 0, -1]], np.float32)
    nrm = normals[wall] + 0.05 * rng.standard_normal((h, w, 3)).astype(np.float32)
    irr = (1 + 0.3 * rng.standard_normal((h, w, 3))).astype(np.float32) * (wall[..., None] + 1)
    irr[::7, ::5] = 3e-6  # float16 subnormals
    depth = (2 + 0.01 * xx + 0.05 * wall).astype(np.float32)
    depth[wall == 5] = np.inf
    unf = np.zeros((h, w, 3), np.float32)
    unf[:3, 10:20] = 17.0
    refl = rng.random((h, w, 3), dtype=np.float32)
    return {"reflectance": refl, "irradiance": irr, "unfiltered": unf, "depth": depth, "normal": nrm}


@pytest.fixture(autouse=True)
def _restore_threads():
    prev = parallel.set_threads(None)
    yield
    parallel.set_threads(prev)


@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("n,task_pixels", [(3, 200), (4, 97), (2, 5000)])
def test_wire_path_equals_per_tile_decode_path(threads, n, task_pixels):
    parallel.set_threads(threads)
    w, h = 97, 61
    full = _frame(w, h)
    wire = [(t, encode(extract(t, n, full))) for t in task_tiles(w, h, n, task_pixels)]
    ref = FrameAssembler(w, h, n)
    fast = FrameAssembler(w, h, n)
    for t, d in reversed(wire):  # any arrival order
        ref.add(t, decode(d))
        fast.add_wire(t, d)
        assert fast.add_wire(t, d) == fast.complete  # duplicates are ignored
    assert fast.complete
    p = params_to_dict(make_params(interleave=n))
    cases = [(p, 0), (dict(p, filter_window=1), 0), (dict(p, filter_window=5), 0),
             (dict(p, consistent=True, filter_frames=2, accumulate=True), 6)]
    for params, index in cases:
        a = ref.image(params, index)
        assert a.tobytes() == fast.image(params, index).tobytes(), (params, index)  # repeatable
    for name, arr in ref.buffers.items():
        assert arr.tobytes() == fast.buffers[name].tobytes(), name


def test_wire_path_incomplete_frame_and_bad_data():
    w, h, n = 40, 30, 3
    full = _frame(w, h, seed=1)
    tiles = task_tiles(w, h, n, 60)
    ref, fast = FrameAssembler(w, h, n), FrameAssembler(w, h, n)
    for t in tiles[::2]:
        d = encode(extract(t, n, full))
        ref.add(t, decode(d))
        fast.add_wire(t, d)
    assert not fast.complete
    p = params_to_dict(make_params())
    assert np.array_equal(ref.image(p), fast.image(p), equal_nan=True)
    t = tiles[1]
    good = encode(extract(t, n, full))
    with pytest.raises(ValueError):
        fast.add_wire(t, good[:-5])  # truncated: refused, nothing written
    other = next(u for u in tiles[1::2] if tile_pixel_count(u, n, w, h) != tile_pixel_count(t, n, w, h))
    with pytest.raises(ValueError):
        fast.add_wire(other, good)  # another tile's pixel count
    assert fast.received == ref.received


@pytest.mark.parametrize("threads", [1, 2, 5])
def test_parallel_filter_equals_serial(threads):
    rng = np.random.default_rng(threads)
    H, W = 53, 71
    irr = rng.random((H, W, 3)).astype(np.float32)
    irr[3, 4, 1] = np.inf
    irr[5, 5] = np.nan
    depth = rng.choice([1.0, 1.02, 1.2, 3.0, np.inf, np.nan], (H, W)).astype(np.float32)
    nrm = rng.normal(size=(H, W, 3)).astype(np.float32)
    for window in (2, 3, 4, 7):
        parallel.set_threads(1)
        a = filter_irradiance(irr, depth, nrm, window, 0.05, 0.3)
        parallel.set_threads(threads)
        b = filter_irradiance(irr, depth, nrm, window, 0.05, 0.3)
        assert a.tobytes() == b.tobytes()
        assert a.tobytes() == _filter_reference(irr, depth, nrm, window, 0.05, 0.3).tobytes()


def _filter_reference(irr, depth, normal, window, dt, nt):
    """The original serial float32 formulation (before issue 12), per offset, whole frame."""
    H, W = depth.shape
    offs = window_offsets(window)
    hit = np.isfinite(depth)
    dc = np.where(hit, depth, np.float32(np.nan))
    src = np.where(np.isfinite(irr), irr, np.float32(0.0))
    acc = irr.copy()
    cnt = np.ones((H, W), np.float32)
    t = np.float32(dt)
    lo_b, hi_b = dc * (1 - t), dc * (1 + t)
    for oy in offs:
        for ox in offs:
            if (oy, ox) == (0, 0):
                continue
            dj = np.full((H, W), np.nan, np.float32)
            nj = np.zeros((H, W, 3), np.float32)
            ij = np.zeros((H, W, 3), np.float32)
            ys, yd = slice(max(0, oy), H + min(0, oy)), slice(max(0, -oy), H + min(0, -oy))
            xs, xd = slice(max(0, ox), W + min(0, ox)), slice(max(0, -ox), W + min(0, -ox))
            dj[yd, xd] = dc[ys, xs]
            nj[yd, xd] = normal[ys, xs]
            ij[yd, xd] = src[ys, xs]
            prod = nj * normal
            dot = (prod[..., 0] + prod[..., 1]) + prod[..., 2]
            ok = (dj >= lo_b) & (dj <= hi_b) & (dot >= np.float32(nt))
            acc += ij * ok[..., None].astype(np.float32)
            cnt += ok
    out = acc / cnt[..., None]
    out[~hit] = irr[~hit]
    return out


def test_planar_octahedral_decode_is_the_per_pixel_formula_bit_for_bit():
    rng = np.random.default_rng(5)
    q = rng.integers(-32768, 32768, (200_000, 2)).astype(np.int16)
    edge = np.arange(-32768, 32768, 97, dtype=np.int32)
    q = np.concatenate([q, np.stack([edge, 32767 - np.abs(edge)], 1).clip(-32768, 32767).astype(np.int16),
                        np.array([[-32768, -32768], [0, 0], [32767, 0], [0, -32768]], np.int16)])
    # the original formulation (codec version 1 as first written)
    p = np.maximum(q.astype(np.float32) * np.float32(1.0 / 32767), np.float32(-1.0))
    ax = np.abs(p)
    z = 1.0 - ax[:, 0] - ax[:, 1]
    unfolded = (1.0 - ax[:, ::-1]) * np.where(p >= 0, np.float32(1.0), np.float32(-1.0))
    v = np.empty((len(q), 3), np.float32)
    v[:, :2] = np.where((z < 0)[:, None], unfolded, p)
    v[:, 2] = z
    v *= (1.0 / np.sqrt(np.einsum("ij,ij->i", v, v)))[:, None]
    v[(q[:, 0] == -32768) & (q[:, 1] == -32768)] = 0.0
    assert oct_decode(q).tobytes() == v.tobytes()
    assert oct_decode_planes(q[:, 0], q[:, 1]).T.tobytes() == np.ascontiguousarray(v).tobytes()


def test_decode_still_round_trips_tile_buffers():
    rng = np.random.default_rng(3)
    p = 500
    b = TileBuffers(rng.random((p, 3), dtype=np.float32), rng.random((p, 3), dtype=np.float32),
                    np.zeros((p, 3), np.float32), rng.random(p, dtype=np.float32) + 1,
                    np.tile(np.float32([0, 0, 1]), (p, 1)))
    d = decode(encode(b), p)
    assert np.array_equal(d.normal, b.normal) and np.allclose(d.irradiance, b.irradiance, rtol=1e-3)


def _calibrated_like():
    """The costs of docs/scaling.md's calibration (cornell-box-sphere, 640x480, 108 tasks)."""
    px = 640 * 480 / 108
    return _costs(render_s_per_px=33.9e-3 / px, set_build_s=51.3e-3, encode_s_per_px=0.8e-3 / px,
                  bytes_per_px=6.97, result_overhead_bytes=100.0, task_bytes=200.0, master_msg_s=194e-6,
                  master_recv_s_per_px=15.5e-3 / (640 * 480), finish_s_per_px=55.9e-3 / (640 * 480),
                  accumulate_s_per_px=10e-9)


def test_set_aware_policy_builds_few_sets_and_scales_at_16_workers():
    """Issue 19: the broker's set-aware policy, accumulating at 640x480 on 10 Gbit/s: at most
    20 set builds per frame at 16 workers (105 with strict queue order) and >= 90% of linear."""
    c = _calibrated_like()
    one = simulate(c, Config(workers=1, interleave=3))
    r16 = simulate(c, Config(workers=16, interleave=3))
    assert one.set_builds_per_frame == 9
    assert r16.set_builds_per_frame <= 20
    assert r16.fps / (16 * one.fps) >= 0.90
    # the default 5x5 interleave: every set of a new seed is built once, by one worker
    assert simulate(c, Config(workers=16, interleave=5)).set_builds_per_frame <= 25 * 1.1
    # the old what-if policy still runs (and is what the set-aware policy replaced)
    old = simulate(c, Config(workers=16, interleave=3, affinity_lookahead=108))
    assert old.set_builds_per_frame >= 9


def test_a_deeper_pipeline_builds_fewer_sets():
    c = _calibrated_like()
    two = simulate(c, Config(workers=16, pipeline=2, task_pixels=4096))
    three = simulate(c, Config(workers=16, pipeline=3, task_pixels=4096))
    assert three.set_builds_per_frame <= two.set_builds_per_frame
    assert three.fps >= two.fps * (1 - 1e-9)


def test_result_cost_micro_benchmark_runs():
    """bench/result_cost.py drives the broker's own RESULT handler (no sockets); figures > 0."""
    from igi.bench.result_cost import measure

    r = measure(width=96, height=72, workers=4, results=40, reps=1)
    assert r["no_sets"]["per_result_us"] > 0 and r["sets_64"]["per_result_us"] > 0
    assert r["config"]["pipeline"] == 3
