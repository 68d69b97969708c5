"""``bench``'s scaling and soak parts: the generated configs, and the figures each
part writes to bench.json. Structure and sanity only, never speed."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from supervisor.tools.bench.scalegen import N_VARIABLES, TIMING_KINDS, generate

ROOT = Path(__file__).resolve().parents[4]
SKIP = ["--skip-throughput", "--skip-latency", "--skip-record", "--skip-replay", "--skip-ui"]
# bench runs the scaling and the soak by default; each test here leaves out the other.


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def _bench(*args: str, timeout: float) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "bench", *SKIP, *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_generated_set_formalizes_uses_every_variable_and_every_timing(tmp_path: Path) -> None:
    from monitors.ir.formula import variables
    from supervisor.pipeline import project_for

    gen = generate(100, seed=1)
    assert generate(100, seed=1).text == gen.text  # deterministic from the seed
    assert generate(100, seed=2).text != gen.text
    assert set(gen.timings) == set(TIMING_KINDS)
    assert {"null", "immediately", "next", "within", "for", "after", "until", "before"} <= set(
        gen.timings
    )
    assert {"always", "eventually", "never", "finally"} <= set(gen.timings)
    assert {"in", "notin", "onlyIn", "after", "before"} <= set(gen.scopes)
    assert {"upon", "when", "if"} <= set(gen.qualifiers)
    project = project_for(gen.write(tmp_path / "scale.yaml"), ros=False)
    assert project.ok, project.first_error()
    assert len(project.requirements) == 100
    assert len(project.config.inputs) == N_VARIABLES
    assert {v.type for v in project.config.inputs} == {"bool", "int64", "double"}
    used = {name for r in project.requirements for name in variables(r.formula)}
    assert used == {v.name for v in project.config.inputs}


def test_every_variable_is_used_in_a_small_set(tmp_path: Path) -> None:
    from monitors.ir.formula import variables
    from supervisor.pipeline import project_for

    project = project_for(generate(10).write(tmp_path / "scale.yaml"), ros=False)
    assert project.ok, project.first_error()
    used = {name for r in project.requirements for name in variables(r.formula)}
    assert len(used) == N_VARIABLES


@pytest.mark.slow  # check runs the analyses (their 30 s budget)
def test_check_accepts_a_generated_set(tmp_path: Path) -> None:
    from supervisor.tools.bench.scale import run_check

    c = run_check(generate(10).write(tmp_path / "scale.yaml"))
    assert c["exit"] == 0, c
    assert "10 requirements ok" in c["last"]
    assert c["analysis"] and c["analysis"][0].startswith("analysis: 10 requirements")


def test_soak_slope() -> None:
    from supervisor.tools.bench.soak import slope_per_minute

    assert slope_per_minute([(0.0, 100.0), (60.0, 160.0), (120.0, 220.0)]) == pytest.approx(60.0)
    assert slope_per_minute([(1.0, 5.0)]) is None


@pytest.mark.ros
@pytest.mark.slow  # check of 10 requirements (the analyses' budget) and a daemon run
def test_bench_scale_writes_its_figures(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    p = _bench("--quick", "--skip-soak", "--scale-sizes", "10", "--out", str(tmp_path), timeout=600)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "Scaling: generated configs" in p.stdout
    r = json.loads((tmp_path / "bench.json").read_text())
    assert "## Scaling" in (tmp_path / "bench.md").read_text()
    sc = r["scale"]
    (row,) = sc["rows"]
    assert row["requirements"] == 10 and row["formalized"] == 10
    for k in ("parse_formalize_s", "compile_s", "library_bytes", "tick_ns"):
        assert _positive(row[k]), (k, row[k])
    assert _positive(row["tick_ns_per_requirement"])
    c = row["check"]
    assert c["exit"] == 0 and _positive(c["wall_s"]) and c["analysis"], c
    for d in (row["daemon"], sc["reference"]):
        for k in ("cpu_us_per_msg", "rss_start_kb", "rss_end_kb", "hwm_end_kb", "ready_s"):
            assert _positive(d[k]), (k, d)
        assert 0 <= d["lost"] <= d["sent"]
        assert d["violations"] == 0  # every value zero: every requirement holds
    assert row["daemon"]["topics"] == N_VARIABLES


@pytest.mark.ros
@pytest.mark.slow  # a daemon run of 10 s
def test_bench_soak_samples(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    p = _bench(
        *("--skip-scale", "--soak-seconds", "10", "--soak-rate", "5000"),
        *("--out", str(tmp_path)),
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    assert "Soak: the daemon" in p.stdout
    so = json.loads((tmp_path / "bench.json").read_text())["soak"]
    assert so["n_samples"] >= 5
    for k in ("rss_first_kb", "rss_last_kb", "rss_max_kb", "fds_first", "fds_last", "fds_max"):
        assert _positive(so[k]), (k, so)
    assert so["rss_first_kb"] <= so["rss_max_kb"] and so["rss_last_kb"] <= so["rss_max_kb"]
    assert so["second_half_samples"] >= 2
    assert math.isfinite(so["rss_slope_kb_per_min_second_half"])
    assert 0 <= so["lost"] <= so["sent"] and so["sent"] > 0
    assert so["violations"] == 0
