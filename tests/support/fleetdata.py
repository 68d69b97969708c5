"""A small fleet's archive over several days, and its dataset made by the real
``fleet replay``: for the tests of ``fleet report`` and the DuckDB queries of
docs/reference/fleet.md (``<!-- files: fleet-dataset -->``, docs/README.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

DAY_NS = 86_400 * 10**9
START_NS = 1_780_272_000 * 10**9  # 2026-06-01T00:00:00Z
# robot, bag, day, seed, storage: two robots over three days, both storage formats
BAGS = [
    ("robot-a", "b1", 0, 1, "MCAP"),
    ("robot-a", "b2", 1, 2, "SQLITE3"),
    ("robot-a", "b3", 2, 3, "MCAP"),
    ("robot-b", "b4", 0, 4, "MCAP"),
    ("robot-b", "b5", 2, 5, "SQLITE3"),
]


def fleet_archive(root: Path, n: int = 1500) -> dict[str, Path]:
    """The bags (name -> path) under ``root/ROBOT/``, each on its day from
    ``START_NS``, and one bag whose metadata is garbage (failed)."""
    out = {}
    for robot, name, day, seed, plugin in BAGS:
        shifted = [(t + START_NS + day * DAY_NS, topic, v) for t, topic, v in messages(seed, n)]
        out[name] = write_bag(root / robot / name, shifted, plugin=plugin)
    broken = root / "robot-b" / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    return out


def fleet_configs(where: Path) -> tuple[Path, Path]:
    """(before, after): the speed limit raised from 2.0 to 2.3 (a known difference:
    only ``limit`` loses violations)."""
    return config(where, "before.yaml", limit=2.0), config(where, "after.yaml", limit=2.3)


def fleet_replay(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """The real command; a failed bag makes its exit status 1, anything else is wrong."""
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
    )
    if run.returncode not in (0, 1) or "Traceback" in run.stderr:
        raise AssertionError(f"fleet replay exit {run.returncode}: {run.stderr}")
    return run


def make(out: Path, env: dict[str, str]) -> None:
    """The docs' files: ``archive/``, ``before.yaml``, ``after.yaml``, and the
    datasets ``before/`` and ``after/`` of each config over the archive."""
    fleet_archive(out / "archive", 600)
    before, after = fleet_configs(out)
    for cfg, ds in ((before, "before"), (after, "after")):
        fleet_replay(cfg.name, "archive", "-o", ds, "--jobs", "1", cwd=out)
