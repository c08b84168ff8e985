"""The broker against hand-driven fake workers (real ZeroMQ sockets on loopback, no renderer):
credit limits, stale/duplicate results, re-queue to the front, expiry, scene caching, edits,
version refusal and garbage."""
from __future__ import annotations

import os
import socket
import time

import msgpack
import numpy as np
import pytest
import zmq

from igi.bench.stress_scenes import mini_cornell
from tests.support.cluster_helpers import FakeWorker, wait_until
from igi.common import protocol as P
from igi.master.broker import Broker, FrameCancelled

W, H = 24, 18  # with a 3x3 interleave: 9 tasks of one sub-image tile each
IL3 = {"interleave": 3}


@pytest.fixture
def broker():
    b = Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=1.0).start()
    yield b
    b.stop()


def hello_ok(fw: FakeWorker, expect_blob=True):
    assert fw.recv_kind(P.WELCOME) is not None
    scene = fw.recv_kind(P.SCENE)
    assert scene is not None
    assert (scene.body["blob"] is not None) == expect_blob
    return scene


def test_credit_stale_and_duplicate_results(broker):
    a = FakeWorker(broker.endpoint, "a", credit=2)
    hello_ok(a)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    got = a.tasks(2)
    assert len(got) == 2
    assert a.tasks(1, timeout=0.5) == [], "no more than the credit in flight"
    a.result(got[0], epoch=got[0]["epoch"] + 1000)  # wrong epoch: stale
    assert wait_until(lambda: broker.stats()["results_stale"] == 1, 5)
    assert a.tasks(1, timeout=0.3) == [], "a stale result returns no credit"
    a.result(got[0])
    more = a.tasks(1)
    assert len(more) == 1, "an accepted result returns one slot"
    a.result(got[0])  # duplicate
    assert wait_until(lambda: broker.stats()["results_stale"] == 2, 5)
    pending = [got[1]] + more
    while pending:
        t = pending.pop()
        a.result(t)
        pending += a.tasks(1, timeout=0.5)
    res = fut.result(10)
    assert res.tasks == 9
    assert np.allclose(res.buffers["irradiance"], 1.0)
    assert np.allclose(res.image(), 1.0)
    a.close()


def test_frames_are_cut_finer_as_render_threads_join():
    """With task_pixels=None the task size follows the render threads connected
    (frame_assembly.task_pixels_for): one thread gets a 640x480 frame in large tasks, 64 more
    threads get it in many small ones."""
    b = Broker(mini_cornell(640, 480), bind="tcp://127.0.0.1:*", heartbeat=1.0, task_pixels=None).start()
    workers = []
    try:
        def tasks_of_a_new_frame() -> int:
            before = b.stats()["queued_tasks"]
            b.submit_frame(b.frame_spec(0, IL3))  # nobody takes tasks: they stay queued
            assert wait_until(lambda: b.stats()["queued_tasks"] > before, 5)
            return b.stats()["queued_tasks"] - before

        workers.append(FakeWorker(b.endpoint, "one", credit=1))
        hello_ok(workers[-1])
        workers[-1].tasks(1)  # its one slot: now busy
        one = tasks_of_a_new_frame()
        workers.append(FakeWorker(b.endpoint, "many", credit=1, threads=64))
        hello_ok(workers[-1])
        workers[-1].tasks(1)
        many = tasks_of_a_new_frame()
        assert many >= 3 * one
    finally:
        for w in workers:
            w.close()
        b.stop()


def test_bye_puts_tasks_back_at_the_front(broker):
    a = FakeWorker(broker.endpoint, "a", credit=2)
    hello_ok(a)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    ta = a.tasks(2)
    b = FakeWorker(broker.endpoint, "b", credit=1)
    hello_ok(b)
    tb = b.tasks(1)
    assert [t["task"] for t in ta] == [0, 1] and [t["task"] for t in tb] == [2]
    a.send(P.BYE, {"reason": "test"})
    assert wait_until(lambda: broker.stats()["tasks_requeued"] == 2, 5)
    order = []
    t = tb[0]
    while True:
        b.result(t)
        nxt = b.tasks(1, timeout=1.0)
        if not nxt:
            break
        t = nxt[0]
        order.append(t["task"])
    assert order[:2] == [0, 1], f"re-queued tasks first, got {order}"
    assert fut.result(10).tasks == 9
    a.close()
    b.close()


def test_silent_worker_expires_and_its_tasks_move():
    with Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.2, liveness=3) as broker:
        a = FakeWorker(broker.endpoint, "silent", credit=3)
        hello_ok(a)
        fut = broker.submit_frame(broker.frame_spec(0, IL3))
        lost = a.tasks(3, timeout=1.0)
        assert len(lost) == 2, "a new worker's credit starts small, whatever it advertises"
        b = FakeWorker(broker.endpoint, "b", credit=2)
        hello_ok(b)
        done = 0
        deadline = time.monotonic() + 15
        while not fut.done() and time.monotonic() < deadline:
            for t in b.tasks(1, timeout=0.15):
                b.result(t)
                done += 1
            b.send(P.HEARTBEAT, {})
        res = fut.result(1)
        assert done == 9 and res.tasks == 9
        s = broker.stats()
        assert s["workers"] == 1 and s["tasks_requeued"] >= 2
        a.result(lost[0])  # the expired worker comes back with an old result
        assert a.recv_kind(P.ERROR, timeout=3).body["code"] == "unregistered"
        a.close()
        b.close()


def test_a_worker_building_a_set_keeps_its_task_for_the_measured_set_build_time():
    """A task's timeout allows for a set build when its worker did not hold the task's set
    (the time the workers report building sets), so a working worker's first task of a set is
    not taken from it; a task of a set it holds still expires at the tasks' own timeout."""
    from igi.master.scheduler import TIMEOUT_FLOOR

    with Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.2, liveness=100) as broker:
        a = FakeWorker(broker.endpoint, "a", credit=1)
        hello_ok(a)

        def frame(seed):
            return broker.submit_frame(broker.frame_spec(0, {"interleave": 3, "seed": seed}))

        def answer_all(fut, first=None, **kw):
            pending = [first] if first else []
            while not fut.done():
                pending += a.tasks(1, timeout=0.5)
                if pending:
                    a.result(pending.pop(), **kw)
            return fut.result(5)

        # fast tasks (the floor is their timeout), each reporting a 2 s set build
        answer_all(frame(1), timings={"render": 0.001, "sets": 2.0})
        assert broker.current_task_timeout() == TIMEOUT_FLOOR
        # a new seed: new sets, none held, so each task's timeout adds the set build
        fut = frame(2)
        t = a.tasks(1)[0]
        time.sleep(TIMEOUT_FLOOR + 1.0)
        assert broker.stats()["tasks_requeued"] == 0, "a worker building a set lost its task"
        assert answer_all(fut, t).tasks == 9
        # the same seed again: the worker holds every set, so a silent task expires at the floor
        fut = frame(2)
        t = a.tasks(1)[0]
        t0 = time.monotonic()
        assert wait_until(lambda: broker.stats()["tasks_requeued"] == 1, 10)
        assert time.monotonic() - t0 < TIMEOUT_FLOOR + 1.0
        a.result(t)  # late: stale, the re-queued copy counts
        assert answer_all(fut).tasks == 9
        a.close()


def test_a_result_that_crosses_the_masters_bye_is_neither_dropped_nor_answered(broker):
    """Shutting down, the master says BYE and forgets its workers; a result already on its way
    is expected, not a stranger's message: no warning, no ERROR asking for HELLO (a stranger
    still gets one: test_silent_worker_expires_and_its_tasks_move)."""
    a = FakeWorker(broker.endpoint, "a", credit=2)
    hello_ok(a)
    broker.submit_frame(broker.frame_spec(0, IL3))
    got = a.tasks(1)
    broker._call(broker._links.say_bye)  # the first half of stop(), its socket still open
    assert a.recv_kind(P.BYE, timeout=3) is not None
    a.result(got[0])
    assert wait_until(lambda: broker._call(lambda: broker._links.counters["after_bye"]) == 1, 5)
    assert a.recv_kind(P.ERROR, timeout=0.5) is None
    assert broker.stats()["messages_dropped"] == 0
    a.close()


def test_scene_blob_sent_once_and_edits_broadcast(broker):
    a = FakeWorker(broker.endpoint, "a")
    first = hello_ok(a, expect_blob=True)
    h = first.body["hash"]
    assert h == broker.scene_hash and first.body["edits"] == []
    b = FakeWorker(broker.endpoint, "b", scenes=[h])
    hello_ok(b, expect_blob=False)  # cached: the master does not resend the blob
    v = broker.apply_edit({"op": "set_emitter", "emitter": 0, "param": "radiance", "value": [1, 2, 3]})
    assert v == 1 == broker.scene_version
    for fw in (a, b):
        e = fw.recv_kind(P.EDIT)
        assert e.body["version"] == 1 and e.body["hash"] == h
    assert np.allclose(broker.scene.emitters[0].radiance, [1, 2, 3])
    c = FakeWorker(broker.endpoint, "late", scenes=[h])
    late = hello_ok(c, expect_blob=False)
    assert len(late.body["edits"]) == 1 and late.body["base_version"] == 0, "a late joiner gets the edits"
    with pytest.raises(ValueError):
        broker.apply_edit({"op": "set_emitter", "emitter": 5, "param": "radiance", "value": [1, 2, 3]})
    spec = broker.frame_spec(0, IL3)
    assert spec.scene_version == 1
    for fw in (a, b, c):
        fw.close()


def test_edit_cancels_frames_of_the_old_version(broker):
    fut = broker.submit_frame(broker.frame_spec(0, IL3))  # no worker: stays open
    broker.apply_edit({"op": "set_material", "material": 0, "param": "diffuse", "value": 0.5})
    with pytest.raises(FrameCancelled):
        fut.result(5)


def test_other_protocol_version_is_refused_and_master_stays_up(broker):
    ctx = zmq.Context.instance()
    peer = ctx.socket(zmq.DEALER)
    peer.setsockopt(zmq.LINGER, 0)
    peer.connect(broker.endpoint)
    hello = {"name": "future", "host": "h", "pid": 1, "threads": 1, "credit": 3, "scenes": []}
    peer.send(P.encode(P.HELLO, hello, version=P.PROTOCOL_VERSION + 1))
    assert peer.poll(5000)
    raw = msgpack.unpackb(peer.recv(), raw=False)
    assert raw[0] == P.PROTOCOL_VERSION and raw[1] == P.REFUSE
    body = raw[2]
    assert body["code"] == "version" and body["theirs"] == P.PROTOCOL_VERSION + 1 and body["ours"] == P.PROTOCOL_VERSION
    assert f"{P.PROTOCOL_VERSION + 1}" in body["message"] and f"{P.PROTOCOL_VERSION}" in body["message"]
    peer.close(0)
    assert broker.stats()["refused"] == 1 and broker.stats()["workers"] == 0
    _serves_a_frame(broker)


def test_garbage_is_dropped_and_master_keeps_serving(broker):
    ctx = zmq.Context.instance()
    peer = ctx.socket(zmq.DEALER)
    peer.setsockopt(zmq.LINGER, 0)
    peer.connect(broker.endpoint)
    rng = np.random.default_rng(7)
    sent = 0
    for i in range(50):
        peer.send(rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes())
        sent += 1
    peer.send_multipart([b"two", b"frames"])
    peer.send(msgpack.packb([P.PROTOCOL_VERSION, P.TASK, {"frame": -1}]))  # valid msgpack, bad schema
    peer.send(msgpack.packb([P.PROTOCOL_VERSION, P.WELCOME, {"worker": "x", "heartbeat": 1.0, "liveness": 3}]))
    sent += 3
    # raw TCP garbage: not even ZMTP
    host, port = broker.endpoint.rsplit("/", 1)[-1].rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as s:
        s.sendall(os.urandom(4096))
    assert wait_until(lambda: broker.stats()["messages_dropped"] >= sent, 10)
    peer.close(0)
    _serves_a_frame(broker)


def _serves_a_frame(broker):
    fw = FakeWorker(broker.endpoint, "ok", credit=9)
    hello_ok(fw)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    answered = 0
    while answered < 9:  # effective credit grows with the results delivered
        got = fw.tasks(1)
        assert got
        fw.result(got[0])
        answered += 1
    assert fut.result(10).tasks == 9
    fw.close()


def test_stop_cancels_open_frames_and_later_submissions():
    b = Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*").start()
    fut = b.submit_frame(b.frame_spec(0, IL3))  # no worker: stays open
    b.stop()
    with pytest.raises(FrameCancelled):
        fut.result(5)
    with pytest.raises(FrameCancelled):
        b.submit_frame(b.frame_spec(1, IL3)).result(5)
    b.stop()  # idempotent


def test_worker_lists_its_sets_only_when_they_change():
    """Issue 19: RESULT.sets goes out only when the renderer's cached-set list changed since the
    last RESULT of this connection (or the renderer changed)."""
    from igi.worker.node import WorkerNode

    class R:
        def __init__(self, sets):
            self.sets = sets

        def cached_sets(self):
            return self.sets

    node = WorkerNode("tcp://127.0.0.1:1")
    r = R({(7, 0), (7, 1)})
    assert node._sets_to_send(r, 1) == [[7, 0], [7, 1]]
    assert node._sets_to_send(r, 1) is None  # unchanged: not sent
    r.sets = {(7, 0), (7, 1), (8, 0)}
    assert node._sets_to_send(r, 1) == [[7, 0], [7, 1], [8, 0]]
    assert node._sets_to_send(r, 2) is not None  # a new connection lists again
    assert node._sets_to_send(R(set(r.sets)), 2) is not None  # so does a new renderer
    node._pool.shutdown()
    node._scene_pool.shutdown()


def test_worker_lists_its_sets_only_after_the_renderers_sets_version_changed():
    """A renderer with a sets_version is asked for its list only when the version moved."""
    from igi.worker.node import WorkerNode

    class R:
        sets_version = 0
        calls = 0

        def cached_sets(self):
            R.calls += 1
            return {(7, 0)} if R.sets_version == 0 else {(7, 0), (8, 1)}

    node = WorkerNode("tcp://127.0.0.1:1")
    r = R()
    assert node._sets_to_send(r, 1) == [[7, 0]]
    assert node._sets_to_send(r, 1) is None and R.calls == 1  # same version: not even asked
    R.sets_version = 1
    assert node._sets_to_send(r, 1) == [[7, 0], [8, 1]] and R.calls == 2
    node._pool.shutdown()
    node._scene_pool.shutdown()


def test_master_keeps_the_last_set_list_of_each_worker(broker):
    a = FakeWorker(broker.endpoint, "a", credit=2)
    hello_ok(a)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    seed = broker.frame_spec(0, IL3).seed

    def cached():
        return broker._call(lambda: {k for w in broker._workers.values() for k in w.cached})
    t = a.tasks(1)[0]
    a.send(P.RESULT, {"frame": t["frame"], "task": t["task"], "epoch": t["epoch"], "count": 0, "data": b"",
                      "sets": [[seed, 5]]}, check=False)  # a bad result: nothing learnt from it
    t = a.tasks(1)[0]
    a.result(t)  # no list: the master keeps what it knew and adds the task's own set
    assert wait_until(lambda: (0, seed, t["k"]) in cached(), 5)
    answered = 1
    while answered < 9:
        got = a.tasks(1)
        assert got
        a.result(got[0])
        answered += 1
    fut.result(10)
    a.close()


def test_re_registering_does_not_keep_the_front_of_the_queue(broker):
    """Issue 20: a peer that says HELLO again and again gets other tasks each time (the ones it
    held avoid it) and is quarantined after three such faults; the frame still completes."""
    good = FakeWorker(broker.endpoint, "good", credit=1)
    hello_ok(good)
    rogue = FakeWorker(broker.endpoint, "rehello", credit=4096)
    hello_ok(rogue)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    first = good.tasks(1)  # the good worker is busy meanwhile
    assert first
    held = set()
    for _ in range(3):
        got = {t["task"] for t in rogue.tasks(2, timeout=2)}
        assert got and not got & held, "the re-queued tasks avoid the peer that held them"
        held |= got
        rogue.hello()
        hello_ok(rogue, expect_blob=True)
    assert rogue.tasks(1, timeout=1.0) == [], "quarantined: no more tasks"
    assert broker.stats()["quarantined"] == ["rehello"]
    good.result(first[0])
    answered = 1
    while answered < 9:
        got = good.tasks(1)
        assert got
        good.result(got[0])
        answered += 1
    assert fut.result(10).tasks == 9
    rogue.close()
    good.close()


def test_a_peer_cycling_identities_cannot_keep_the_lost_tasks(broker):
    """Issue 20: tasks given back by a worker that never delivered (here: BYE right after taking
    them) go to a worker that has delivered, not to the next newcomer."""
    good = FakeWorker(broker.endpoint, "good", credit=2)
    hello_ok(good)
    fut = broker.submit_frame(broker.frame_spec(0, IL3))
    first = good.tasks(2)
    good.result(first[0])  # "good" has delivered: trusted
    busy = [first[1]] + good.tasks(1)  # and is full again
    lost = set()
    for i in range(2):
        r = FakeWorker(broker.endpoint, f"cycler{i}", credit=4096)
        hello_ok(r)
        got = {t["task"] for t in r.tasks(2, timeout=2)}
        assert got and not got & lost, "a newcomer never gets the tasks a newcomer gave back"
        lost |= got
        r.send(P.BYE, {"reason": "cycling"})
        r.close()
    assert wait_until(lambda: broker.stats()["workers"] == 1, 5)
    answered = 1
    pending = busy
    while answered < 9:
        t = pending.pop()
        good.result(t)
        answered += 1
        pending += good.tasks(1, timeout=2)
    assert fut.result(10).tasks == 9
    good.close()
