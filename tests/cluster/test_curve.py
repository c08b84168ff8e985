"""CURVE authentication + encryption between master and workers (issue 8, common/protocol.py
CurveServer / CurveClient through the Broker's and WorkerNode's ``configure_socket`` hooks):
a worker with an accepted key renders; a worker without the right key — an unknown keypair,
plain (NULL) security, or a wrong master key — never completes the handshake, so it neither
registers nor receives the scene."""
from __future__ import annotations

import threading

import pytest
import zmq

from igi.bench.stress_scenes import mini_cornell
from tests.support.cluster_helpers import wait_until
from igi.common import protocol as P
from igi.master.broker import Broker
from igi.worker.node import WorkerNode

W, H = 24, 18


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    d = tmp_path_factory.mktemp("keys")
    P.generate_keys(d, ["good"])
    rogue = tmp_path_factory.mktemp("rogue")  # a keypair the master never accepted, another master key
    P.generate_keys(rogue, ["good", "other"])
    return d, rogue


def test_generate_keys_layout_and_permissions(keys):
    d, _ = keys
    assert (d / "master.key").is_file() and (d / "master.key_secret").is_file()
    assert (d / "good.key_secret").is_file() and (d / "workers" / "good.key").is_file()
    assert not list((d / "workers").glob("*secret*")) and not (d / "workers" / "master.key").exists()
    assert (d / "good.key_secret").stat().st_mode & 0o077 == 0
    before = (d / "master.key_secret").read_bytes()
    P.generate_keys(d, ["good"])  # idempotent: existing keys are kept
    assert (d / "master.key_secret").read_bytes() == before
    with pytest.raises(ValueError):
        P.generate_keys(d, ["../evil"])


@pytest.fixture
def curve_broker(keys):
    d, _ = keys
    ctx = zmq.Context()
    server = P.CurveServer(d)
    b = Broker(mini_cornell(W, H), bind="tcp://127.0.0.1:*", heartbeat=0.5, context=ctx,
               configure_socket=server).start()
    yield b
    b.stop()
    server.stop()
    ctx.term()


def _start_worker(endpoint, configure_socket):
    ctx = zmq.Context()
    node = WorkerNode(endpoint, threads=1, heartbeat=0.5, max_backoff=1.0, context=ctx,
                      configure_socket=configure_socket)
    t = threading.Thread(target=node.run, daemon=True)
    t.start()
    return node, t, ctx


def _stop_worker(node, t, ctx):
    node.stop()
    t.join(15)
    assert not t.is_alive()
    ctx.term()


def test_worker_with_an_accepted_key_renders(curve_broker, keys):
    d, _ = keys
    node, t, ctx = _start_worker(curve_broker.endpoint, P.CurveClient(d, "good"))
    try:
        assert wait_until(lambda: curve_broker.stats()["workers"] == 1, 20)
        res = curve_broker.render_frame(curve_broker.frame_spec(0, {}), timeout=120)
        assert res.tasks > 0 and node.tasks_done == res.tasks
    finally:
        _stop_worker(node, t, ctx)


@pytest.mark.parametrize("who", ["unknown-key", "plain", "wrong-master-key"])
def test_worker_without_the_right_key_cannot_connect_or_receive_the_scene(curve_broker, keys, who):
    d, rogue = keys
    hook = {"unknown-key": _unknown_key_client(d, rogue), "plain": None,
            "wrong-master-key": P.CurveClient(rogue, "good")}[who]
    node, t, ctx = _start_worker(curve_broker.endpoint, hook)
    try:
        # Several handshake attempts (reconnect backoff <= 1 s) within the wait.
        assert not wait_until(lambda: curve_broker.stats()["workers"] > 0, 4.0)
        assert node._state is None and not node._blobs, "the scene reached an unauthenticated worker"
        assert node.tasks_done == 0
    finally:
        _stop_worker(node, t, ctx)
    # ... while the master keeps serving authenticated workers
    good, t2, ctx2 = _start_worker(curve_broker.endpoint, P.CurveClient(d, "good"))
    try:
        assert wait_until(lambda: curve_broker.stats()["workers"] == 1, 20)
    finally:
        _stop_worker(good, t2, ctx2)


def _unknown_key_client(d, rogue):
    """The right master public key, but a client keypair the master never accepted."""
    c = P.CurveClient(rogue, "other")
    c.server_public = P.CurveClient(d, "good").server_public
    return c


def test_plain_dealer_gets_no_answer_from_a_curve_master(curve_broker):
    ctx = zmq.Context()
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(curve_broker.endpoint)
    s.send(P.encode(P.HELLO, {"name": "plain", "host": "h", "pid": 1, "threads": 1, "credit": 3, "scenes": []}))
    assert not s.poll(2000)
    assert curve_broker.stats()["workers"] == 0
    s.close(0)
    ctx.term()


def test_plain_worker_against_a_curve_master_leaves_one_info_line(curve_broker, caplog):
    """Issue 20: a denial is logged at INFO (default level), once per interval however often
    the worker retries."""
    import logging

    caplog.set_level(logging.INFO, logger="igi.master")
    node, t, ctx = _start_worker(curve_broker.endpoint, None)
    try:
        # several handshake attempts (reconnect backoff <= 1 s) within the wait
        assert not wait_until(lambda: curve_broker.stats()["workers"] > 0, 4.0)
    finally:
        _stop_worker(node, t, ctx)
    lines = [r for r in caplog.records if r.name == "igi.master" and "denied" in r.getMessage()]
    assert len(lines) == 1, [r.getMessage() for r in lines]
    assert lines[0].levelno == logging.INFO and "CURVE" in lines[0].getMessage()
    assert curve_broker.endpoint in lines[0].getMessage()


def test_unknown_key_denial_is_logged_with_the_peer_address(curve_broker, keys, caplog):
    import logging

    d, rogue = keys
    caplog.set_level(logging.INFO, logger="igi.master")
    node, t, ctx = _start_worker(curve_broker.endpoint, _unknown_key_client(d, rogue))
    try:
        assert not wait_until(lambda: curve_broker.stats()["workers"] > 0, 3.0)
    finally:
        _stop_worker(node, t, ctx)
    lines = [r.getMessage() for r in caplog.records if r.name == "igi.master" and "denied" in r.getMessage()]
    assert len(lines) == 1 and "127.0.0.1" in lines[0], lines
