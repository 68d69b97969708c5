"""The dataset's writers (supervisor/tools/fleet/dataset.py, ``Writers``): files
written on threads, results given back in order once written, and a write that fails
stops the run as one line, as a write in the parent did."""

from __future__ import annotations

import pytest

from tests.supervisor.tools.fleet.test_fleet_replay import BAGS, fleet, query
from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

pytest.importorskip("pyarrow")


def test_every_bag_is_written_once_and_counted_once_written(tmp_path):
    for i in range(12):
        write_bag(tmp_path / "fleet" / f"robot-{i % 3}" / f"b{i:02d}", messages(40 + i, 400))
    ds = tmp_path / "ds"
    run = fleet(config(tmp_path), tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(0,))
    assert "12 bags (12 read, 0 skipped, 0 damaged, 0 failed)" in run.stdout
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (12, 12)
    assert not list(ds.rglob(".*.tmp"))  # every file whole, no temporary left


def test_a_write_that_fails_mid_run_is_one_line(tmp_path):
    for i in range(3):
        write_bag(tmp_path / "fleet" / "robot-a" / f"b{i}", messages(50 + i, 1500))
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "violations").write_text("")  # a file where the violations' directory goes
    run = fleet(config(tmp_path), tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "cannot write the dataset" in lines[0], run.stderr
    assert "ds/violations" in lines[0] and "internal error" not in lines[0]
    assert run.stdout == ""  # no summary: the run stopped at the failed write
