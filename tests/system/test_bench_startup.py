"""``bench --startup`` end to end, one run of each figure: structure and sanity only
(every figure present, min <= median <= max, READY reached), never speed."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]
FIGURES = (
    "import_cli",
    "help",
    "check_cold",
    "check_warm",
    "run_cold",
    "run_warm",
    "replay_cold",
    "replay_warm",
)


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "bench", "--startup", "--startup-runs", "2", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_startup_figures_as_json_and_in_a_file(tmp_path: Path) -> None:
    r = _bench("--json", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert json.loads((tmp_path / "startup.json").read_text()) == doc
    for key in FIGURES:
        fig = doc[key]
        assert fig["runs"] == 2 and len(fig["samples_s"]) == 2, (key, fig)
        assert all(math.isfinite(x) and x > 0 for x in fig["samples_s"]), (key, fig)
        assert fig["min_s"] <= fig["median_s"] <= fig["max_s"], (key, fig)
    assert set(doc["goals_s"]) == {"import_cli", "help", "run_warm", "run_cold", "replay_warm"}


def test_startup_table() -> None:
    r = _bench()
    assert r.returncode == 0, r.stderr
    rows = [line for line in r.stdout.splitlines() if line.startswith("  ")]
    labels = (
        "import supervisor.cli",
        "--help",
        "check, empty cache",
        "check, cache filled",
        "run to READY=1",
        "replay 10 ",
    )
    for label in labels:
        assert any(row.strip().startswith(label) for row in rows), r.stdout
    assert sum("<= " in row for row in rows) == 5, r.stdout  # the five goals
    assert "Traceback" not in r.stderr
