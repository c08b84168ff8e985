"""igi bench contention: one core's slowdown as more are busy, written as JSON."""
import json
import subprocess
import sys


def test_contention_writes_each_workload_at_each_copy_count_relative_to_one_copy(tmp_path):
    out = tmp_path / "c"
    r = subprocess.run([sys.executable, "-m", "igi.master.cli", "bench", "contention", "--copies", "1,2",
                        "--compute-reps", "200000", "--memory-reps", "1", "-o", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "c.json").read_text())
    points = {(p["kind"], p["copies"]): p for p in data["points"]}
    assert set(points) == {("compute", 1), ("compute", 2), ("memory", 1), ("memory", 2)}
    for kind in ("compute", "memory"):
        assert points[(kind, 1)]["inflation"] == 1.0
        two = points[(kind, 2)]
        assert two["inflation"] == two["mean_s"] / points[(kind, 1)]["mean_s"] > 0
    assert data["machine"]["cores"] >= 1 and data["settings"]["copies"] == [1, 2]
