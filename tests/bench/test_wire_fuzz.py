"""Wire fuzzing (issue 8): random and mutated messages to the master's ROUTER and to a worker's
DEALER are dropped with one log line each, nothing crashes, and oversize messages are refused
before anything is allocated. Engine: bench/stress.py (fuzz_decode / fuzz_master /
fuzz_worker; ``igi bench stress`` runs more)."""
from __future__ import annotations

import json

from bench import stress as bs


def test_decoder_gives_a_message_or_a_protocol_error_for_every_mutant():
    res = bs.fuzz_decode(20_000, seed=3)
    print(json.dumps(res))
    assert res["crashes"] == 0, res["crash_examples"]
    out = res["outcomes"]
    # the mutants exercise every path: valid, malformed and other-version messages
    assert out.get("message", 0) > 500 and out.get("protocol_error", 0) > 10_000 and out.get("version_mismatch", 0) > 50


def test_master_drops_bad_messages_with_one_log_line_each_and_keeps_serving():
    res = bs.fuzz_master(400, seed=1)
    print(json.dumps(res))
    exp = res["expected"]
    assert res["messages_tried"] == 400
    assert res["refused"] == exp.get("refuse", 0) == res["refusal_log_lines"]  # other versions: REFUSE + 1 line
    assert res["dropped"] >= exp["drop"]  # every malformed one (+ valid ones from unregistered peers)
    assert res["drop_log_lines"] == res["dropped"]  # one line per dropped message
    assert res["warning_log_lines"] <= res["messages_tried"] + 10  # ... and no more
    assert res["oversize_delivered"] is False  # > MAX_MESSAGE_SIZE: ZeroMQ drops the peer, never delivered
    assert res["oversize_header_refused"] is True  # a 1 TiB frame header closes the connection at once
    assert res["serves_after"] is True and res["crashes"] == 0, res.get("serves_after_error")


def test_worker_drops_bad_messages_with_one_log_line_each_and_keeps_rendering():
    res = bs.fuzz_worker(400, seed=1)
    print(json.dumps(res))
    exp = res["expected"]
    assert res["messages_tried"] > 300
    assert res["alive"] is True and res["reconnects"] == 0
    # every malformed message is one "dropped" line; a two-frame message is read as two frames
    assert exp["drop"] <= res["drop_log_lines"] <= exp["drop"] + 2 * exp.get("multipart", 0) + exp.get("valid", 0)
    assert res["oversize_header_refused"] is True and res["reconnected_after_oversize"] is True
    assert res["serves_after"] is True and res["crashes"] == 0, res.get("serves_after_error")
