"""The cluster with real worker processes on loopback (tcp://127.0.0.1, ports chosen by the OS).

Equality bound: every tile's buffers cross the wire as float16 (octahedral int16 normals), and
``render_local`` applies the same codec round trip, so identical tasks give identical bytes and
the distributed image is expected to be bit-identical whatever the number of workers. The
tests assert the wire-quantization bound |a - b| <= 2^-10 |b| + 1e-6 (one float16 ulp,
relative), and that this is the size of the difference between unquantized and quantized
renders.
"""
from __future__ import annotations

import random
import signal
import sys
import time

import msgpack
import numpy as np
import pytest
import zmq

from igi.bench.stress_scenes import mini_cornell
from tests.support.cluster_helpers import start_worker, stop_procs, wait_until
from igi.common import protocol as P
from igi.common.params import make_params, params_to_dict
from igi.master.accumulation import sequence_spec
from igi.master.broker import Broker
from igi.master.frame_assembly import FrameAssembler, task_tiles
from igi.master.inprocess import render_local, roundtrip

W, H = 64, 48
REL = 2.0 ** -10


def within_wire_bound(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.abs(a - b) <= REL * np.abs(b) + 1e-6))


@pytest.fixture(scope="module")
def scene():
    return mini_cornell(W, H)


@pytest.fixture
def procs():
    ps = []
    yield ps
    stop_procs(ps)


def per_worker(broker) -> dict[str, int]:
    return {w["name"]: w["tasks_done"] for w in broker.workers()}


def test_two_workers_equal_one_worker_and_local(scene, procs):
    """Bit-identical images whoever renders the tasks, over enough frames that the last ones are
    filtered with the edge-stopping guide (the broker and render_local feed it in frame order)."""
    from igi.master.edge_stopping import MIN_FRAMES

    FRAMES = MIN_FRAMES + 2
    params = {"photons": 0}
    ref = render_local(scene, params, frames=FRAMES)
    # (unguided frames: the guide's yes/no tests may flip on quantized values, beyond the bound)
    unquantized = render_local(scene, params, frames=2, quantize=False)
    quantized = render_local(scene, params, frames=2)
    assert within_wire_bound(unquantized, quantized), "the bound covers the wire quantization"
    with Broker(scene, bind="tcp://127.0.0.1:*") as broker:
        procs.append(start_worker(broker.endpoint, "one"))
        assert broker.wait_for_workers(1, 60)
        one = broker.render_sequence(params, frames=FRAMES)
        procs.append(start_worker(broker.endpoint, "two", threads=2))  # also exercises the render pool
        assert broker.wait_for_workers(2, 60)
        before = per_worker(broker)
        two = broker.render_sequence(params, frames=FRAMES)
        after = per_worker(broker)
    assert after["two"] > 0 and after["one"] > before["one"], "both workers rendered"
    assert within_wire_bound(two, one)
    assert within_wire_bound(one, ref)
    assert np.array_equal(one, ref) and np.array_equal(two, one), "expected bit-identical"


def test_workers_boost_the_photons_of_a_caustic_lit_scene_as_this_process_does(procs):
    """cornell-box-water (a third of the lamp's flux ends in caustics): each worker process
    measures the caustic share from its own pilot set and boosts its photon sets 16x; two
    workers' image is this process's, bit for bit, so every process took the same count (a
    different count would move every photon of a set)."""
    from igi.common.loader import load_scene
    from igi.worker.renderer import Renderer
    from tests.support.paths import SHARED

    water = load_scene(SHARED / "scenes" / "cornell-box-water" / "scene.xml")
    params = {"indirect_vpls": 8}
    assert Renderer(water).photon_count(make_params(**params)) > make_params().photons  # boosted here
    ref = render_local(water, params, frames=2, width=W, height=H)
    with Broker(water, bind="tcp://127.0.0.1:*") as broker:
        procs.append(start_worker(broker.endpoint, "one"))
        procs.append(start_worker(broker.endpoint, "two"))
        assert broker.wait_for_workers(2, 60)
        two = broker.render_sequence(params, frames=2, width=W, height=H)
        assert all(n > 0 for n in per_worker(broker).values()), "both workers rendered"
    assert np.array_equal(two, ref), "expected bit-identical"


def local_frame_images(scene, pdict, count):
    """Reference: each frame's filtered image, rendered in this process."""
    from igi.worker.renderer import Renderer

    r = Renderer(scene)
    cam = scene.camera
    out = []
    n = pdict["interleave"]
    for i in range(count):
        spec = sequence_spec(i, i, cam.to_world, cam.fov_x, W, H, pdict)
        asm = FrameAssembler(W, H, n)
        for t in task_tiles(W, H, n):
            asm.add(t, roundtrip(r.render_tile(spec, t)))
        out.append(asm.image(pdict))
    return out


def test_sigkill_workers_during_14_frames(scene, procs):
    pdict = params_to_dict(make_params(photons=0, accumulate=True))
    frames = 14
    refs = local_frame_images(scene, pdict, frames)
    rng = random.Random(20020)
    kills = []
    with Broker(scene, bind="tcp://127.0.0.1:*", heartbeat=0.3, liveness=3) as broker:
        for i in range(2):
            procs.append(start_worker(broker.endpoint, f"w{i}"))
        assert broker.wait_for_workers(2, 60)
        n = 2

        def kill_one():  # SIGKILL a random live worker while frames are in flight; replace it
            nonlocal n
            alive = [p for p in procs if p.poll() is None]
            victim = rng.choice(alive)
            victim.send_signal(signal.SIGKILL)
            kills.append(victim.pid)
            procs.append(start_worker(broker.endpoint, f"w{n}"))
            n += 1

        # Kills tied to frame submissions (not to wall-clock waits), so they land mid-run
        # however fast frames render: 4 kills, each with 1-2 frames in flight.
        kill_at = set(rng.sample(range(2, frames - 2), 4))
        results = []
        futs = []
        for i in range(frames):
            futs.append(broker.submit_frame(broker.frame_spec(i, pdict, width=W, height=H)))
            if i in kill_at:
                kill_one()
            if len(futs) >= 2:
                results.append(futs.pop(0).result(120))
        results += [f.result(120) for f in futs]
        stats = broker.stats()
    assert len(kills) == 4
    assert len(results) == frames
    for i, res in enumerate(results):
        img = res.image()
        assert within_wire_bound(img, refs[i]), f"frame {i} differs from the undisturbed render"
    print(f"{len(kills)} SIGKILLs, {stats['tasks_requeued']} tasks re-queued, "
          f"{stats['results_stale']} stale results dropped", file=sys.stderr)


def test_worker_started_mid_run_receives_tasks(scene, procs):
    with Broker(scene, bind="tcp://127.0.0.1:*") as broker:
        procs.append(start_worker(broker.endpoint, "first"))
        assert broker.wait_for_workers(1, 60)
        broker.start_stream({"photons": 0})
        f = broker.wait_frame(0, 60)
        assert f is not None
        procs.append(start_worker(broker.endpoint, "late"))
        assert wait_until(lambda: per_worker(broker).get("late", 0) > 0, 60), "the late worker got tasks"
        late = next(w for w in broker.workers() if w["name"] == "late")
        print(f"late worker: first task {late['first_task_s'] * 1e3:.0f} ms after its HELLO", file=sys.stderr)
        f2 = broker.wait_frame(f.seq, 60)
        assert f2 is not None and f2.accumulated > f.accumulated
        broker.stop_stream()


def test_worker_reconnects_when_the_master_comes_back(scene, procs):
    broker = Broker(scene, bind="tcp://127.0.0.1:*").start()
    endpoint = broker.endpoint
    p = start_worker(endpoint, "survivor", exit_with_master=False)
    procs.append(p)
    assert broker.wait_for_workers(1, 60)
    broker.stop()  # BYE: the worker goes back to connecting with backoff
    time.sleep(0.5)
    assert p.poll() is None
    with Broker(scene, bind=endpoint) as again:
        assert again.wait_for_workers(1, 60)
        res = again.render_frame(again.frame_spec(0, {"photons": 0}), timeout=60)
        assert res.tasks == len(task_tiles(W, H, make_params().interleave))


def test_worker_process_refuses_a_master_of_another_version(procs):
    ctx = zmq.Context.instance()
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    port = router.bind_to_random_port("tcp://127.0.0.1")
    try:
        p = start_worker(f"tcp://127.0.0.1:{port}", "strict")
        procs.append(p)
        assert router.poll(60000)
        ident, hello = router.recv_multipart()
        assert P.decode(hello).kind == P.HELLO
        router.send_multipart([ident, msgpack.packb([P.PROTOCOL_VERSION + 7, P.WELCOME, {}])])
        assert router.poll(10000)
        _, answer = router.recv_multipart()
        refuse = P.decode(answer)
        assert refuse.kind == P.REFUSE and refuse.body["theirs"] == P.PROTOCOL_VERSION + 7
        assert p.wait(30) == 2
        err = p.stderr.read().decode()
        assert f"{P.PROTOCOL_VERSION + 7}" in err and "protocol" in err
    finally:
        router.close(0)


def test_stream_api_camera_params_and_edits_change_the_image(procs):
    """What the viewer drives: every change restarts accumulation and shows up in the image."""
    scene = mini_cornell(32, 24)
    with Broker(scene, bind="tcp://127.0.0.1:*") as broker:
        procs.append(start_worker(broker.endpoint, "s"))
        assert broker.wait_for_workers(1, 60)
        broker.start_stream({"photons": 0})
        f = broker.wait_frame(0, 60)
        f = broker.wait_frame(f.seq, 60)
        assert f.accumulated >= 2, "accumulates while nothing changes"
        base = f.image

        def first_frame_after_change():
            g = broker.wait_frame(f.seq, 60)
            while g.accumulated != 1 or g.generation == f.generation:
                g = broker.wait_frame(g.seq, 60)
            return g

        cam = np.asarray(scene.camera.to_world).copy()
        cam[0, 3] += 0.3
        broker.set_camera(cam)
        f = first_frame_after_change()
        assert f.spec.camera_to_world == tuple(cam.ravel()) and not np.allclose(f.image, base)
        assert f.spec.seed == 0, "a camera move keeps the seed (cached sets, no flicker)"
        broker.set_params(filter_window=1)
        f = first_frame_after_change()
        assert f.spec.params["filter_window"] == 1
        before = f.image
        v = broker.apply_edit({"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [0.0, 0.0, 0.0]})
        f = first_frame_after_change()
        assert f.spec.scene_version == v == 1
        assert f.image.mean() < 0.2 * before.mean(), "the light was switched off on the worker"
        assert broker.stats()["rays_per_s"] > 0
        broker.stop_stream()
