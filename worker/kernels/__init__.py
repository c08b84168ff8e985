"""Compiled kernels (numba, ``nogil``): the inner loops of the worker, one module per family.

Each kernel works on flat float32/float64 arrays and hands rays to Embree in large batches;
Python only orchestrates. The numpy originals are kept under ``tests/`` as oracles.
"""

from igi.common.kernel_cache import keep_true as _keep_true

_keep_true()  # drop cached kernels compiled from other sources before any runs
