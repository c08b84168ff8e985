"""The checkout's packages come first on sys.path (ahead of an installed igi), so the tests
always test this tree. Tests are packages (tests/common/, tests/worker/, tests/master/,
tests/bench/, tests/cluster/), imported by pytest as ``tests.<folder>.<file>``; their helpers
are in tests/support/ (``from tests.support.paths import SHARED``)."""
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import pytest  # noqa: E402

SHARED = ROOT.parent / "shared"


@pytest.fixture(scope="session", autouse=True)
def _private_table_cache(tmp_path_factory):
    """Tests keep precomputed tables (common.table_cache) in a directory of their own, shared
    by the session's processes (the variable is inherited), never the user's ~/.cache/igi: a
    table there could stand in for the computation a test means to check."""
    import os

    old = os.environ.get("IGI_CACHE_DIR")
    os.environ["IGI_CACHE_DIR"] = str(tmp_path_factory.mktemp("igi-cache"))
    yield
    if old is None:
        os.environ.pop("IGI_CACHE_DIR", None)
    else:
        os.environ["IGI_CACHE_DIR"] = old


def pytest_sessionstart(session):
    """Under pytest-xdist (``-n 2``, the README's command) the controller compiles the kernels
    once into numba's on-disk cache before its workers start, so the workers load them instead
    of each compiling all of them at once (minutes on a fresh checkout). The master's kernels
    (master.kernels.warm, ~17 s of a core) compile in a process of their own beside them: else
    the first test to start a master compiled them, and the bare-clone test (which copies the
    checkout's compiled kernels) once more."""
    config = session.config
    if getattr(config.option, "numprocesses", None) and not hasattr(config, "workerinput"):
        import subprocess

        from igi.worker.kernels.warm import one_compiler, warm_up

        t0 = time.perf_counter()
        from tests.support.paths import pythonpath_env

        master = subprocess.Popen([sys.executable, "-c", "from igi.master.kernels.warm import warm_up_master; "
                                   "warm_up_master()"], cwd=str(ROOT), env=pythonpath_env())
        with one_compiler():
            warm_up()
        master.wait()
        # CI's budget is tight: say what the compile (or the cache's load) took
        sys.stderr.write(f"kernels ready in {time.perf_counter() - t0:.0f} s\n")


# Run first: its own install and cold kernel compile take minutes in one test. xdist's loadfile
# hands out the files with the most tests first, so this one-test file ran last, alone, the
# other worker idle beside it for minutes at the end of every CI run.
_FIRST = ("test_fresh_clone.py",)


def pytest_configure(config):
    """The run's file order is the collection's (pytest_collection_modifyitems), not xdist's
    reordering by test count."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(session, config, items):
    """Files in the order xdist would take them (most tests first), the long single tests
    (_FIRST) before all; each file's tests keep their order. Every worker collects the same."""
    count = Counter(item.path for item in items)
    items.sort(key=lambda item: (item.path.name not in _FIRST, -count[item.path]))  # stable


def pytest_report_header(config):
    if not SHARED.is_dir():
        return (f"NOTE: the shared test set (scenes and Mitsuba references) is not at {SHARED}; "
                "tests that read it are reported as skipped (put ../shared beside the checkout, "
                "as .ci/run has it)")
    return None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Without ../shared beside the checkout, a test that fails only because a file of the
    shared set is missing is reported as skipped with that reason (one clear cause instead of
    a hundred tracebacks). With the folder present nothing is changed."""
    outcome = yield
    report = outcome.get_result()
    if SHARED.is_dir() or call.excinfo is None or report.passed or report.skipped:
        return
    text = str(call.excinfo.value)
    if str(SHARED) in text or "/shared/" in text:
        report.outcome = "skipped"
        report.longrepr = (str(item.path), item.location[1] or 0,
                           f"needs the shared test set at {SHARED} ({call.excinfo.typename}: {text[:200]})")
