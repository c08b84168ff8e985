"""The checkout's packages come first on sys.path (ahead of an installed igi), so the tests
always test this tree. Tests are packages (tests/common/, tests/worker/, tests/master/,
tests/bench/, tests/cluster/), imported by pytest as ``tests.<folder>.<file>``; their helpers
are in tests/support/ (``from tests.support.paths import SHARED``)."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
