"""worker.kernels.parallel_compile: the recorded kernel signatures are exactly what the
warm-up compiles, their JSON form gives back the same numba types, the schedule keeps a kernel
with the kernels compiled inside it and balances the processes, and helper processes fill a
cold cache that a fresh process then loads without compiling."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from igi.worker.kernels import parallel_compile as pc
from igi.worker.kernels.warm import kernel_dispatchers, warm_up


def _cheap_entries(n: int) -> list[dict]:
    """The ``n`` quickest recorded kernels that compile nothing inside them."""
    entries = [e for e in pc.load_manifest() if not e["inside"] and e["depth"] == 0]
    return sorted(entries, key=lambda e: e["seconds"])[:n]


def test_the_list_holds_exactly_the_signatures_the_warm_up_compiles():
    """A fresh process (no other test's calls) warms up; its dispatchers' signatures, as JSON,
    are the committed list's (regenerate with ``python -m igi.worker.kernels.warm
    --record-signatures`` when a kernel's arguments change). Left out: the kernels the warm-up also calls
    directly when they have no signature of their own (on a warm cache those loaded inside
    their callers keep none, and the direct call's types need not be their callers')."""
    from igi.worker.kernels import warm

    direct = set(warm._direct_calls()) | set(warm._bsdf_calls())
    code = ("import json\nfrom igi.worker.kernels.warm import kernel_dispatchers, warm_up\n"
            "from igi.worker.kernels.parallel_compile import type_spec\nwarm_up(parallel=False)\n"
            "print(json.dumps([[n, [type_spec(t) for t in s]] for n, d in kernel_dispatchers().items() "
            "for s in d.signatures]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    compiled = {json.dumps(x) for x in json.loads(out.stdout.strip().splitlines()[-1]) if x[0] not in direct}
    listed = {json.dumps([e["kernel"], e["signature"]]) for e in pc.load_manifest() if e["kernel"] not in direct}
    assert len(listed) > 30
    assert compiled - listed == set(), "compiled by the warm-up but not listed"
    assert listed - compiled == set(), "listed but no longer compiled by the warm-up"


def test_no_kernel_is_compiled_for_a_literal_argument():
    """A constant passed to a kernel from compiled code (``True``, ``0``) made numba compile a
    second copy for its Literal type (sample_rays, _stage, specular_many: seconds each on a
    cold cache); the callers pass typed values."""
    from numba.core import types

    warm_up()
    literal = [(name, str(sig)) for name, d in kernel_dispatchers().items() for sig in d.signatures
               if any(isinstance(t, types.Literal) for t in sig)]
    assert literal == []


def test_json_form_gives_back_every_compiled_type():
    warm_up()
    for name, d in kernel_dispatchers().items():
        for sig in d.signatures:
            back = tuple(pc.spec_type(pc.type_spec(t)) for t in sig)
            assert back == tuple(sig), name
    for e in pc.load_manifest():
        assert [pc.type_spec(pc.spec_type(s)) for s in e["signature"]] == e["signature"], e["kernel"]


def test_a_type_without_a_json_form_is_refused_by_name():
    from numba.core import types

    with pytest.raises(ValueError, match="no JSON form.*Literal"):
        pc.type_spec(types.literal(3))
    with pytest.raises(ValueError, match="not a type spec"):
        pc.spec_type({"dict": 1})


def _entry(name: str, seconds: float, inside=(), depth: int = 0) -> dict:
    return {"kernel": name, "signature": [], "seconds": seconds, "depth": depth, "inside": list(inside)}


def test_schedule_keeps_callees_with_their_caller_callees_first():
    # 0 calls 1 and 2 (compiled inside it); 3 calls 2 as well; 4 stands alone
    entries = [_entry("a", 5.0, inside=[1, 2]), _entry("b", 1.0, depth=1), _entry("c", 1.0, depth=1),
               _entry("d", 2.0, inside=[2]), _entry("e", 6.0)]
    groups = pc.groups(entries)
    names = sorted(sorted(e["kernel"] for e in g) for g in groups)
    assert names == [["a", "b", "c", "d"], ["e"]]
    big = next(g for g in groups if len(g) == 4)
    order = [e["kernel"] for e in big]
    assert order.index("b") < order.index("a") and order.index("c") < order.index("a")
    assert order.index("c") < order.index("d")
    bins = pc.schedule(entries, 2)
    assert sorted(sorted(e["kernel"] for e in b) for b in bins) == [["a", "b", "c", "d"], ["e"]]


def test_schedule_balances_independent_kernels_longest_first():
    entries = [_entry(str(i), s) for i, s in enumerate([7.0, 5.0, 4.0, 3.0, 3.0, 2.0])]
    bins = pc.schedule(entries, 2)
    loads = sorted(sum(e["seconds"] for e in b) for b in bins)
    assert loads == [12.0, 12.0]
    assert len(pc.schedule(entries, 16)) == 6  # no empty process
    assert [e["kernel"] for b in pc.schedule(entries, 1) for e in b] == ["0", "1", "2", "3", "4", "5"]


def test_helpers_fill_a_cold_cache_that_a_fresh_process_loads(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    entries = _cheap_entries(3)
    assert pc.missing(entries) == entries  # an empty cache holds none of them
    res = pc.compile_in_parallel(entries, 2)
    assert res["errors"] == [] and res["processes"] == 2 and res["kernels"] == 3
    assert pc.missing(entries) == []
    # a fresh process finds each in the cache: a hit, no compile
    code = ("import json, sys\nfrom igi.worker.kernels import parallel_compile as pc\n"
            "entries = json.loads(sys.argv[1])\nassert pc.compile_entries(entries) == []\n"
            "d = [pc._dispatcher(e['kernel']) for e in entries]\n"
            "print(json.dumps([[sum(x.stats.cache_hits.values()), sum(x.stats.cache_misses.values())] for x in d]))\n")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(entries)], capture_output=True, text=True,
                         timeout=300, env=dict(os.environ))
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [[1, 0]] * 3


def test_an_index_older_than_its_source_counts_as_missing(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    entry = _cheap_entries(1)
    assert pc.compile_in_parallel(entry, 2)["errors"] == []
    assert pc.missing(entry) == []
    for p in tmp_path.rglob("*.nbi"):
        os.utime(p, (0, 0))  # written before the source was last changed
    assert pc.missing(entry) == entry


def test_a_kernel_that_cannot_compile_is_reported_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    bad = [_entry("igi.worker.kernels.no_such_module.kernel", 1.0)]
    res = pc.compile_in_parallel(bad + _cheap_entries(1), 2)
    assert len(res["errors"]) == 1 and "igi.worker.kernels.no_such_module.kernel" in res["errors"][0]


def test_a_cold_warm_up_compiles_in_parallel_only_with_cores_and_work(monkeypatch):
    from igi.worker.kernels import warm

    calls = []
    monkeypatch.setattr(pc, "compile_in_parallel", lambda todo, n: calls.append((len(todo), n)) or {"n": n})
    monkeypatch.setattr(pc, "missing", lambda entries: entries)  # as on a cold cache
    assert warm.compile_cold_kernels(1) is None  # one core: nothing to gain
    assert warm.compile_cold_kernels(2) == {"n": 2}
    assert calls == [(len(pc.load_manifest()), 2)]
    monkeypatch.setattr(pc, "missing", lambda entries: [])  # a warm cache
    assert warm.compile_cold_kernels(2) is None


def test_a_cache_numba_keeps_elsewhere_is_not_guessed(monkeypatch):
    """An install whose kernel folders cannot be written (read-only site-packages): numba caches
    in a folder of its own choosing, so whether the kernels were compiled cannot be told; the
    warm-up then starts no helpers and compiled_before() says None (the master waits the
    first run's time for its workers)."""
    from igi.worker.kernels import warm

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    entries = pc.load_manifest()
    assert pc.cache_located(entries)  # this checkout: __pycache__ beside the sources
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    assert not pc.cache_located(entries)
    assert warm.compiled_before() is None
    monkeypatch.setattr(pc, "compile_in_parallel", lambda *a: pytest.fail("helpers started on an unseen cache"))
    assert warm.compile_cold_kernels(2) is None


def test_a_partly_cold_cache_groups_the_missing_kernels_by_their_places_in_the_list():
    """missing() returns a subset of the list; ``inside`` names callees by their place in the
    whole list, so a subset's groups still join a caller with its own callees only."""
    entries = [dict(e, index=i) for i, e in enumerate([_entry("a", 5.0, inside=[2]), _entry("b", 1.0),
                                                       _entry("c", 1.0, depth=1), _entry("d", 1.0, inside=[1])])]
    subset = [entries[0], entries[2], entries[3]]  # b is cached already
    names = sorted(sorted(e["kernel"] for e in g) for g in pc.groups(subset))
    assert names == [["a", "c"], ["d"]]
    assert all(e["index"] == i for i, e in enumerate(pc.load_manifest()))

