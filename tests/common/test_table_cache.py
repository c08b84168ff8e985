"""The disk cache of precomputed tables (common.table_cache) as the rough plastic's coat tables
use it: a table read back equals the one computed, a run that finds it computes nothing, a
damaged file is recomputed and replaced, and ``IGI_CACHE_DIR=""`` writes nothing."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from igi.common import microfacet as mf
from igi.common import table_cache

COAT = (0.3125, 1.49, True)  # a coat no other test of this process computes first


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(table_cache.ENV, str(tmp_path))
    mf._TABLES.clear()  # the process-wide memory cache would hide the disk
    yield tmp_path
    mf._TABLES.clear()


def _equal(a, b):
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]
    np.testing.assert_array_equal(a[2], b[2])


def test_a_stored_coat_table_reads_back_bit_for_bit_without_integrating(cache, monkeypatch):
    computed = mf.rough_plastic_tables(*COAT)
    files = list(cache.glob("coat-*.npz"))
    assert len(files) == 1
    mf._TABLES.clear()

    def must_not_integrate(*a, **k):
        raise AssertionError("the cached table should have been read, not recomputed")

    monkeypatch.setattr(mf, "eval_transmittance", must_not_integrate)
    monkeypatch.setattr(mf, "eval_reflectance", must_not_integrate)
    _equal(mf.rough_plastic_tables(*COAT), computed)


def test_another_process_reads_the_table_this_one_stored(cache):
    computed = mf.rough_plastic_tables(*COAT)
    # the other process cannot integrate (eval_transmittance is None): it must read the file
    code = (f"import numpy as np; from igi.common import microfacet as mf; "
            f"mf.eval_transmittance = None; t = mf.rough_plastic_tables{COAT}; "
            f"np.save({str(cache / 'out.npy')!r}, t[0])")
    subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ))
    np.testing.assert_array_equal(np.load(cache / "out.npy"), computed[0])


@pytest.mark.parametrize("damage", [b"", b"not a zip file", "wrong shape"])
def test_a_damaged_table_file_is_recomputed_and_replaced(cache, damage):
    computed = mf.rough_plastic_tables(*COAT)
    (path,) = cache.glob("coat-*.npz")
    if damage == "wrong shape":
        np.savez(path, ext_t=np.ones(3), int_r=np.float64(0.5), ext_r=np.ones(3))
    else:
        path.write_bytes(damage)
    mf._TABLES.clear()
    _equal(mf.rough_plastic_tables(*COAT), computed)
    mf._TABLES.clear()
    with np.load(path) as z:  # replaced by a good one
        np.testing.assert_array_equal(z["ext_t"], computed[0])


def test_an_empty_cache_dir_setting_turns_the_cache_off(tmp_path, monkeypatch):
    monkeypatch.setenv(table_cache.ENV, "")
    monkeypatch.chdir(tmp_path)
    mf._TABLES.clear()
    try:
        assert table_cache.cache_dir() is None
        mf.rough_plastic_tables(*COAT)
        assert table_cache.load("anything.npz") is None
        assert not any(tmp_path.iterdir())
    finally:
        mf._TABLES.clear()


def test_an_unwritable_cache_dir_costs_only_the_computation(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache directory should be")
    monkeypatch.setenv(table_cache.ENV, str(blocker / "igi"))
    mf._TABLES.clear()
    try:
        t = mf.rough_plastic_tables(*COAT)
        assert t[0].shape == (mf.ROUGH_TRANSMITTANCE_RES,) and np.all(np.isfinite(t[0]))
    finally:
        mf._TABLES.clear()


def test_tables_of_another_code_version_are_kept_apart(cache, monkeypatch):
    mf.rough_plastic_tables(*COAT)
    (first,) = cache.glob("coat-*.npz")
    mf._TABLES.clear()
    monkeypatch.setattr(mf, "_VERSION", "0123456789ab")
    mf.rough_plastic_tables(*COAT)
    names = sorted(p.name for p in cache.glob("coat-*.npz"))
    assert len(names) == 2 and first.name in names
    assert any(n.startswith("coat-0123456789ab-") for n in names)


def test_the_version_changes_with_the_source(tmp_path, monkeypatch):
    import importlib.util

    def module(text):
        path = tmp_path / f"m{abs(hash(text))}.py"
        path.write_text(text)
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    a, b = module("X = 1\n"), module("X = 2\n")
    assert table_cache.source_version(a) == table_cache.source_version(module("X = 1\n"))
    assert table_cache.source_version(a) != table_cache.source_version(b)


@pytest.mark.parametrize("bad", ["npy under the npz name", "float32 arrays", "strings"])
def test_other_malformed_files_are_recomputed_too(cache, bad):
    computed = mf.rough_plastic_tables(*COAT)
    (path,) = cache.glob("coat-*.npz")
    if bad == "npy under the npz name":
        with open(path, "wb") as f:
            np.save(f, np.ones(3))
    elif bad == "float32 arrays":
        np.savez(path, ext_t=computed[0].astype(np.float32), int_r=np.float64(computed[1]),
                 ext_r=computed[2].astype(np.float32))
    else:
        np.savez(path, ext_t=np.array(["x"] * mf.ROUGH_TRANSMITTANCE_RES), int_r=np.float64(0.5),
                 ext_r=np.array(["x"] * mf.ROUGH_TRANSMITTANCE_RES))
    mf._TABLES.clear()
    _equal(mf.rough_plastic_tables(*COAT), computed)
