"""``safety-supervisor bench``'s replay throughput, recording overhead and ``--quick
--out DIR`` (supervisor/tools/bench/replay.py, recording.py, command.py).

Only structure and sanity are asserted (every figure present and positive, counts
that add up), never speed: speed goals are printed by the bench, not tested.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from supervisor import data
from supervisor.tools.bench.plan import Plan

ROOT = Path(__file__).resolve().parents[4]
SROBOT = data.example("srobot.yaml")


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def test_written_rounds_read_back_as_nominal_ticks(tmp_path: Path) -> None:
    """The bag holds whole rounds, the trigger last, and decodes to the nominal state
    (and the violating one every VIOLATE_EVERY rounds)."""
    from supervisor.config import load_config
    from supervisor.tools.bench.replay import violating_state, write_rounds
    from supervisor.tools.replay.sources import open_recordings

    plan = Plan(SROBOT)
    bad = violating_state(plan)
    assert bad is not None
    n = write_rounds(tmp_path / "bag", plan, 70, "sqlite3", violating=bad, every=4)
    assert n == 70  # 10 rounds of 7 topics
    events = list(open_recordings([tmp_path / "bag"], load_config(SROBOT)).events())
    assert len(events) == n
    values = [dict(ev[2]) for ev in events]
    names = [next(iter(v)) for v in values]
    assert names[6::7] == ["turnoffUVC"] * 10  # the trigger ends each round
    rounds = [{k: v for d in values[i : i + 7] for k, v in d.items()} for i in range(0, n, 7)]
    assert rounds[0] == {k: pytest.approx(v) for k, v in plan.nominal.items()}
    assert rounds[3] == {**plan.nominal, **bad}  # every 4th round violates


@pytest.mark.slow  # builds three monitors
def test_replay_bench_small_bags(tmp_path: Path) -> None:
    from supervisor.tools.bench.replay import replay_bench
    from supervisor.tools.bench.report import _format_replay, format_markdown

    said: list[str] = []
    rep = replay_bench(Plan(SROBOT), 7_000, said.append, where=tmp_path, min_seconds=0.05)
    assert list(tmp_path.iterdir()) == []  # the bags are gone
    cases = {c["case"]: c for c in rep["cases"]}
    assert len(cases) == 6, list(cases)
    for label, c in cases.items():
        assert c["messages"] == 7_000, label
        assert _positive(c["rate"]) and _positive(c["seconds"]) and _positive(c["bag_mb"]), c
    exact = next(c for c in rep["cases"] if not c["fast"])
    assert exact["ticks"] == 1_000 and exact["violations"] == 0
    violating = [c for c in rep["cases"] if c["case"].startswith("violations")]
    assert [c["violations"] for c in violating] == [1, 1]  # one round in 1000 ticks
    scan = next(c for c in rep["cases"] if "LaserScan" in c["case"])
    assert scan["ticks"] == 7_000  # on_message: one tick per message
    # sqlite3 and MCAP apart: each storage's bulk cases, lowest and highest msg/s
    for storage, n in (("mcap", 3), ("sqlite3", 2)):
        mine = [c["rate"] for c in rep["cases"] if c["storage"] == storage and c["fast"]]
        assert len(mine) == n and rep["by_storage"][storage] == {
            "min": min(mine),
            "max": max(mine),
            "cases": n,
        }
    assert set(rep["monitor"]) >= {"tick", "batch 10000"}
    assert all(_positive(v) for v in rep["monitor"].values())

    text = "\n".join(_format_replay(rep))
    for c in rep["cases"]:
        assert c["case"] in text and f"{c['rate']:.0f}" in text
    for storage, label in (("mcap", "MCAP"), ("sqlite3", "sqlite3")):
        low = rep["by_storage"][storage]["min"] / 1e6
        assert f"  {label}, bulk stepping: {low:.2f}" in text
    md = format_markdown(_results(replay=rep))
    assert "## Replay throughput" in md
    for c in rep["cases"]:
        assert f"| {c['case']} |" in md and f"{c['rate']:.0f}" in md
    assert "| MCAP, bulk stepping |" in md and "| sqlite3, bulk stepping |" in md
    assert said and all(isinstance(s, str) for s in said)


def test_quick_defaults_and_explicit_options() -> None:
    """--quick shortens what was not given; what was given stays."""
    import argparse

    from supervisor.tools.bench.command import _add_arguments, resolve

    p = argparse.ArgumentParser()
    _add_arguments(p)
    full = resolve(p.parse_args([]))
    assert full.rates == [5000, 10000, 12500, 15000, 17500, 20000]
    assert (full.seconds, full.latency_trials, full.replay_messages) == (5.0, 1000, 1_000_000)
    assert full.record_rates == [20000]
    quick = resolve(p.parse_args(["--quick", "--seconds", "1"]))
    assert quick.rates == [5000, 20000] and quick.seconds == 1.0
    assert (quick.latency_trials, quick.replay_messages) == (100, 200_000)
    assert (full.latency_rounds, quick.latency_rounds) == (3, 1)


def _results(**parts: Any) -> dict[str, Any]:
    return {
        "config": str(SROBOT),
        "topics": ["/a"],
        "trigger": "turnoffUVC",
        "cpus": 2,
        "loadavg_before": "0 0 0",
        "loadavg_after": "0 0 0",
        "python": "3.11",
        "rmw": "x",
        "domain_id": 220,
        **parts,
    }


@pytest.mark.ros
@pytest.mark.slow
def test_bench_quick_out(tmp_path: Path) -> None:
    """Every experiment, short; bench.json and bench.md with all their figures."""
    pytest.importorskip("rclpy")
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    args = ["--quick", "--rates", "3000", "--seconds", "1", "--latency-trials", "20"]
    args += ["--latency-rounds", "2"]
    args += ["--replay-messages", "21000", "--record-rates", "5000", "--out", str(out)]
    # the UI and scale figures: test_bench_ui.py and test_bench_scale.py beside this file
    args += ["--skip-ui", "--skip-scale", "--skip-soak"]
    p = subprocess.run(
        [sys.executable, "-m", "supervisor", "bench", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "Replay throughput" in p.stdout and "Recording overhead" in p.stdout
    r = json.loads((out / "bench.json").read_text())
    assert r["cpus"] == os.cpu_count() and r["python"] and r["loadavg_before"]

    (row,) = r["throughput"]
    assert row["offered"] == 3000 and row["sent"] > 0
    (rec,) = r["recording"]
    assert rec["offered"] == 5000 and rec["goal_pct"] == 10.0
    for label in ("off", "on"):
        side = rec[label]
        assert 0 <= side["received"] <= side["sent"]
        assert side["lost"] == side["sent"] - side["received"]
        assert _positive(side["cpu_us_per_msg"]), side
    assert rec["off"]["record"] is None
    closed = rec["on"]["record"]
    assert closed["written"] >= rec["on"]["received"]  # inputs and the log's records
    # a message dropped is one the daemon received; the report's table says the same
    assert isinstance(closed["dropped"], int) and 0 <= closed["dropped"] <= rec["on"]["received"]
    assert closed["bags"] >= 1
    on_row = f"{closed['written']:>8} {closed['dropped']:>7} {closed['mb_on_disk']:>6.1f}"
    assert on_row in p.stdout, p.stdout
    assert isinstance(rec["cpu_diff_pct"], float)
    lat = r["latency"]
    # the trials in two rounds of echo then daemons, pooled; each round's p50s said
    assert len(lat["rounds"]) == 2
    for key in ("echo", "daemon", "daemon_before_action"):
        assert lat[key]["n"] + lat[key]["missed"] == 20, key
        assert all(rnd[f"{key}_p50"] > 0 for rnd in lat["rounds"]), key
    assert lat["daemon"]["n"] > 0
    assert "p50 ms of each of the 2 rounds pooled above: echo " in p.stdout
    rep = r["replay"]
    assert rep["messages"] == 21000 and len(rep["cases"]) == 6
    assert all(_positive(c["rate"]) for c in rep["cases"])

    md = (out / "bench.md").read_text()
    for section in ("Throughput and overhead", "Recording overhead", "Latency", "Replay"):
        assert f"## {section}" in md, section
    assert f"| {row['receivers']['daemon']['received']} |" in md
    assert f"| {rec['on']['received']} |" in md
    for c in rep["cases"]:
        assert f"{c['rate']:.0f}" in md
    # the daemon's stages, as the text report has them
    stages = r["latency"]["breakdown"]["stages_us"]
    # every stage of both durabilities, in order, and the part after the halt
    from supervisor.tools.bench.breakdown import STAGES, STAGES_AFTER_PUBLISH

    assert list(stages) == [name for name, _ in STAGES]
    after = r["latency"]["breakdown_after_publish"]
    assert list(after["stages_us"]) == [name for name, _ in STAGES_AFTER_PUBLISH]
    assert (
        after["after_halt_us"]["p50"] is not None
        and "after_halt_us" not in r["latency"]["breakdown"]
    )
    assert "| stage | p50 µs |" in md and "x the floor (goal: at most 1.3x)" in md
    assert "after_publish: halt p50" in md and "| safety-supervisor (before_action) |" in md
    for name, st in stages.items():
        assert f"| {name} | {st['p50']:.1f} |" in md, name
