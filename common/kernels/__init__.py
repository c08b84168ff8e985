"""Compiled kernels (numba, ``nogil``) shared by worker and master: the math defined once."""

from igi.common.kernel_cache import keep_true as _keep_true

_keep_true()  # drop cached kernels compiled from other sources before any runs
