"""A worker loads every compiled kernel before it says HELLO (worker.kernels.warm): after
warm_up, every kernel dispatcher of common.kernels and worker.kernels has a compiled
signature, so no first call inside a frame compiles or loads anything."""
from __future__ import annotations

from worker.kernels.warm import kernel_dispatchers, warm_up


def test_after_warm_up_every_kernel_has_a_compiled_signature():
    res = warm_up()
    kernels = kernel_dispatchers()
    assert res["kernels"] == len(kernels) > 0
    assert res["cold"] == []
    for name, disp in kernels.items():
        assert disp.signatures, name


def test_the_worker_warms_up_before_it_connects():
    import inspect

    from worker import node

    src = inspect.getsource(node.run_from_args)
    assert src.index("warm_up()") < src.index("node.run()")
