"""common.malloc_policy: tile-sized buffers freed and made again reuse the heap's pages instead
of faulting fresh ones in (the master's lz4 decompression, a worker's encode)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from igi.common.malloc_policy import reuse_freed_blocks

# A fresh process: a frame-sized block comes and goes, then 50 tiles' payloads are
# decompressed and dropped, as the broker's loop does; prints the page faults of the 50.
TILES = """
import os, resource, sys
if sys.argv[1] == "on":
    from igi.common.malloc_policy import reuse_freed_blocks
    assert reuse_freed_blocks()
import lz4.frame
comp = lz4.frame.compress(os.urandom(1000) * 320)  # a 640x480 tile's payload: 320 kB
frame = bytearray(40 << 20)
del frame
for _ in range(3):
    lz4.frame.decompress(comp)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(50):
    lz4.frame.decompress(comp)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", TILES, mode], check=True, capture_output=True, text=True)
    return int(out.stdout.strip().splitlines()[-1])


def test_freed_tile_buffers_are_reused_not_faulted_in_again():
    if not reuse_freed_blocks():
        pytest.skip("not glibc: mallopt is not there to set")
    before = _faults("off")
    if before < 50 * 10:  # this C library keeps the pages already: nothing to prove here
        pytest.skip(f"the C library kept the freed pages without the policy ({before} faults)")
    after = _faults("on")
    # 320 kB is 78 pages: without the policy every one of the 50 payloads faults its pages in
    assert after < before / 20, (before, after)


def test_reuse_is_set_once_and_reports_the_same():
    assert reuse_freed_blocks() == reuse_freed_blocks()
