"""Wire fuzzing (issue 8): random and mutated messages to the master's ROUTER and to a worker's
DEALER are dropped and counted, with rate-limited warnings (issue 20: one line per kind per
interval, the next line carries the count of those not shown), nothing crashes, and oversize
messages are refused before anything is allocated. Engine: bench/stress.py (fuzz_decode / fuzz_master /
fuzz_worker; ``igi bench stress`` runs more)."""
from __future__ import annotations

import json

from igi.bench import stress as bs


def test_decoder_gives_a_message_or_a_protocol_error_for_every_mutant():
    res = bs.fuzz_decode(20_000, seed=3)
    print(json.dumps(res))
    assert res["crashes"] == 0, res["crash_examples"]
    out = res["outcomes"]
    # the mutants exercise every path: valid, malformed and other-version messages
    assert out.get("message", 0) > 500 and out.get("protocol_error", 0) > 10_000 and out.get("version_mismatch", 0) > 50


def test_master_drops_bad_messages_with_rate_limited_log_lines_and_keeps_serving():
    res = bs.fuzz_master(400, seed=1)
    print(json.dumps(res))
    exp = res["expected"]
    assert res["messages_tried"] == 400
    assert res["refused"] == exp.get("refuse", 0)  # other versions: a REFUSE each, all counted
    assert res["refusal_log_lines"] <= 5 and (res["refusal_log_lines"] > 0) == (res["refused"] > 0)  # one line per 10 s
    assert res["dropped"] >= exp["drop"]  # every malformed one (+ valid ones from unregistered peers)
    assert 1 <= res["drop_log_lines"] <= 5  # one line per 10 s for the kind "dropped", not one each
    assert res["warning_log_lines"] <= 30  # ... and a few others (fuzz peers that registered, then expire)
    assert res["oversize_delivered"] is False  # > MAX_MESSAGE_SIZE: ZeroMQ drops the peer, never delivered
    assert res["oversize_header_refused"] is True  # a 1 TiB frame header closes the connection at once
    assert res["serves_after"] is True and res["crashes"] == 0, res.get("serves_after_error")


def test_worker_drops_bad_messages_with_rate_limited_log_lines_and_keeps_rendering():
    res = bs.fuzz_worker(400, seed=1)
    print(json.dumps(res))
    exp = res["expected"]
    assert res["messages_tried"] > 300
    assert res["alive"] is True and res["reconnects"] == 0
    # hundreds of malformed messages: one "dropped" line within the interval, not one each
    assert exp["drop"] > 100 and 1 <= res["drop_log_lines"] <= 5
    assert res["dropped_counted"] >= exp["drop"]  # every one taken, though a handful of lines written
    assert res["oversize_header_refused"] is True and res["reconnected_after_oversize"] is True
    assert res["serves_after"] is True and res["crashes"] == 0, res.get("serves_after_error")


def test_rate_limited_log_counts_and_reports_suppressed_lines():
    import logging

    from igi.common.ratelimit_log import RateLimitedLog

    lines = []

    class H(logging.Handler):
        def emit(self, record):
            lines.append(record.getMessage())
    lg = logging.getLogger("igi.test.ratelimit")
    lg.propagate = False
    lg.addHandler(H())
    lg.setLevel(logging.INFO)
    now = [0.0]
    rl = RateLimitedLog(lg, interval=10.0, clock=lambda: now[0])
    for i in range(2000):
        rl.warning("dropped", "dropped message %d", i)
    rl.warning("other", "another kind")
    assert lines == ["dropped message 0", "another kind"]
    assert rl.counts["dropped"] == 2000 and rl.written["dropped"] == 1
    now[0] = 10.5
    rl.warning("dropped", "dropped message %d", 2000)
    assert lines[-1].startswith("dropped message 2000") and "1999 more 'dropped'" in lines[-1]
    rl.warning("dropped", "x")
    rl.flush()
    assert lines[-1] == "1 more 'dropped' message(s) not shown"
