"""bench.accuracy: what its command line takes."""
from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from igi.bench.accuracy import unit_fraction


def test_scale_takes_one_over_a_whole_number_only():
    """--scale is 1/n of the film size (the reference is averaged in n × n blocks): 1, 0.5,
    0.25 pass; 4 (the block size, not the fraction), 0, a negative, 0.3 and text are refused."""
    assert [unit_fraction(t) for t in ("1", "0.5", "0.25", "0.125")] == [1.0, 0.5, 0.25, 0.125]
    for bad in ("4", "0", "-0.5", "0.3", "nan", "inf", "half"):
        with pytest.raises(argparse.ArgumentTypeError, match="not"):
            unit_fraction(bad)


def test_a_bad_scale_is_a_usage_error_naming_it():
    """`igi bench accuracy SCENE --scale 4` stops at the command line with a message naming the
    value (it was a ZeroDivisionError from the reference's block average)."""
    r = subprocess.run([sys.executable, "-m", "igi.master.cli", "bench", "accuracy", "cornell-box", "--scale", "4"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "--scale" in r.stderr and "'4'" in r.stderr and "Traceback" not in r.stderr
