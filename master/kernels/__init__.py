"""Compiled kernels (numba, ``nogil``) of the master's per-frame work: the discontinuity
buffer fused with the compose (``discontinuity``) and the accumulation sums (``accumulate``).
The wire decode they read from is ``common.kernels.wire_decode``. The numpy originals are
kept under ``tests/support`` as oracles."""

from igi.common.kernel_cache import keep_true as _keep_true

_keep_true()  # drop cached kernels compiled from other sources before any runs
