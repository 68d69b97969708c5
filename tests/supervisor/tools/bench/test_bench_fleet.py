"""The fleet bench (supervisor/tools/bench/fleet.py) on a small archive, as a user runs
it: every kind of bag made, every run's figures present, and the resume after a kill
reading none of the bags finished before it.  Speed is printed by the bench, never
asserted here."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import Any

import pytest

pytest.importorskip("pyarrow")


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


@pytest.mark.slow
def test_a_small_fleet_bench_measures_each_run_and_resumes_without_reading_again(tmp_path):
    out = tmp_path / "fleet.json"
    run = subprocess.run(
        [sys.executable, "-m", "supervisor.tools.bench.fleet", "--bags", "50", "--robots", "5",
         "--messages", "3000", "--split-messages", "20000", "--skip-ray", "--tmp",
         str(tmp_path), "--json", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    got = json.loads(out.read_text())
    assert got["kinds"] == {
        "mcap": 25, "sqlite3": 25, "violating": 10, "compressed": 3, "damaged": 1,
    }  # fmt: skip
    assert [r["args"] for r in got["runs"]] == ["--jobs 1", "--jobs 2"]
    for r in got["runs"]:
        assert r["exit"] == 1  # the damaged bag
        assert "50 bags (49 read, 0 skipped, 1 damaged, 0 failed)" in r["summary"]
        assert r["workers"] == int(r["args"].split()[-1])
        assert all(_positive(r[k]) for k in ("wall_s", "rate", "cpu_s", "peak_worker_mb"))
    resume = got["resume"]
    assert resume["killed"]["killed"] and 0 < resume["finished_at_kill"] < 50
    assert resume["read_again"] == 0 and resume["all_finished"] == 50
    assert f"{resume['finished_at_kill']} done before" in resume["resumed"]["summary"]
    for part in ("split", "split_mcap", "split_sqlite3"):
        assert all(_positive(v) for v in got[part]["ns_per_message"].values()), got[part]
    assert "goal >= 1.8x" in run.stdout and "goal <= 300 MB" in run.stdout
    assert not list(tmp_path.glob("fleet-bench-*"))  # its archive removed at the end
