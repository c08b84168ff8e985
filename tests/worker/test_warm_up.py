"""A worker loads every compiled kernel before it says HELLO (worker.kernels.warm): after
warm_up, every kernel dispatcher of common.kernels and worker.kernels has a compiled
signature, so no first call inside a frame compiles or loads anything."""
from __future__ import annotations

from igi.worker.kernels.warm import kernel_dispatchers, warm_up


def test_after_warm_up_every_kernel_has_a_compiled_signature():
    res = warm_up()
    kernels = kernel_dispatchers()
    assert res["kernels"] == len(kernels) > 0
    assert res["cold"] == []
    for name, disp in kernels.items():
        assert disp.signatures, name


def test_the_worker_warms_up_before_it_connects():
    import inspect

    from igi.worker import node

    src = inspect.getsource(node.run_from_args)
    assert src.index("warm_up_before_hello(log)") < src.index("node.run()")


def test_a_failing_warm_up_is_logged_not_fatal(monkeypatch, caplog):
    import logging

    from igi.worker.kernels import warm

    def boom(*a, **k):
        raise RuntimeError("no scene today")

    monkeypatch.setattr(warm, "warm_up", boom)
    with caplog.at_level(logging.INFO):
        warm.warm_up_before_hello(logging.getLogger("igi.worker"))
    assert "warm-up failed" in caplog.text


def test_warm_up_logs_its_duration(caplog):
    import logging

    from igi.worker.kernels import warm

    with caplog.at_level(logging.INFO):
        warm.warm_up_before_hello(logging.getLogger("igi.worker"))
    assert "kernels ready in" in caplog.text


def test_compiled_before_tells_a_warm_cache_from_a_cold_one(monkeypatch, tmp_path):
    from igi.worker.kernels import parallel_compile
    from igi.worker.kernels.warm import compiled_before

    warm_up()
    assert compiled_before() is True  # every listed kernel was just compiled/loaded beside its source
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert compiled_before() is False  # an empty cache
    monkeypatch.setattr(parallel_compile, "MANIFEST", tmp_path / "no-list.json")
    assert compiled_before() is None  # without the list of kernels it cannot be told


def test_workers_started_together_compile_one_at_a_time(tmp_path):
    """one_compiler: while one process holds the kernels' lock, another that asks for it waits
    until it is released (the first compiles into numba's cache, the second then loads)."""
    import subprocess
    import sys

    from igi.worker.kernels.warm import one_compiler

    flag = tmp_path / "entered"
    child = ("import pathlib, sys\nfrom igi.worker.kernels.warm import one_compiler\n"
             "with one_compiler():\n    pathlib.Path(sys.argv[1]).write_text('in')\n")
    with one_compiler():
        p = subprocess.Popen([sys.executable, "-c", child, str(flag)])
        try:
            p.wait(timeout=3)  # the child imports and then blocks on the lock
        except subprocess.TimeoutExpired:
            pass
        assert p.poll() is None and not flag.exists(), "the second process did not wait for the lock"
    assert p.wait(timeout=120) == 0
    assert flag.read_text() == "in"
