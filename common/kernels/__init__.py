"""Compiled kernels (numba, ``nogil``) shared by worker and master: the math defined once."""
