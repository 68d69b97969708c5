"""``check``'s analyses are budgeted by z3's resource limit, not by the clock: the
same config gives the same findings on an idle machine and beside CPU hogs
(docs/reference/config.md, "analysis"); and on a terminal ``check`` shows each
stage as it goes, while a pipe gets nothing new."""

from __future__ import annotations

import contextlib
import os
import pty
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MOBILE_BASE = ROOT / "supervisor" / "data" / "examples" / "mobile-base.yaml"
# Consistency of the mobile base on 4 ticks takes about 2.9 million z3 resource
# units (docs/BENCHMARKS.md, "Analyses"): this limit stops it, the other analyses
# finish; the wall-clock caps are far out of reach, so only the resource limit can
# stop anything.
ANALYSIS = "analysis: {k: 4, rlimit: 2000000, timeout_s: 600}\nlimits: {analysis_budget_s: 900}\n"


def _config(tmp_path: Path, analysis: str) -> Path:
    text = MOBILE_BASE.read_text(encoding="utf-8").replace("\nlogging:", f"\n{analysis}logging:")
    path = tmp_path / "base.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _env() -> dict[str, str]:
    # no start-up cache: each run analyses afresh
    drop = ("SAFETY_SUPERVISOR_DEBUG", "STATE_DIRECTORY")
    return {k: v for k, v in os.environ.items() if k not in drop}


def _findings(config: Path) -> str:
    """``check``'s analysis report without its seconds."""
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(config)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=900,
    )
    assert r.returncode in (0, 1), r.stderr
    report = r.stdout[r.stdout.index("analysis: ") :]
    report = report[: report.rindex(f"{config}: ")]
    return re.sub(r"\d+\.\d+ s\b", "S s", report)


@contextlib.contextmanager
def _cpu_hogs(n: int) -> Iterator[None]:
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
            h.wait()


@pytest.mark.slow  # three full checks in subprocesses: full suite only (README, quick tier)
def test_check_gives_the_same_findings_idle_and_beside_cpu_hogs(tmp_path: Path) -> None:
    config = _config(tmp_path, ANALYSIS)
    idle = _findings(config)
    with _cpu_hogs(2):
        loaded = _findings(config)
        loaded_again = _findings(config)
    assert loaded == idle
    assert loaded_again == idle
    # the resource limit did stop an analysis, and the report says it was that one
    assert "z3 gave up: resource limit 2000000" in idle
    assert "(analysis.rlimit)" in idle


def _check_on_a_terminal(config: Path) -> tuple[str, str]:
    """``check``'s stdout (a pipe) and stderr (a pseudo-terminal)."""
    leader, follower = pty.openpty()
    with subprocess.Popen(
        [sys.executable, "-m", "supervisor", "check", str(config)],
        stdout=subprocess.PIPE,
        stderr=follower,
        env=_env(),
    ) as p:
        os.close(follower)
        err = b""
        with contextlib.suppress(OSError):  # EIO once the child closed the terminal
            while chunk := os.read(leader, 4096):
                err += chunk
        out = p.stdout.read() if p.stdout else b""
        assert p.wait(timeout=900) == 0, err
    os.close(leader)
    return out.decode(), err.decode().replace("\r\n", "\n")


@pytest.mark.slow  # two full checks in subprocesses: full suite only (README, quick tier)
def test_check_shows_each_stage_on_a_terminal_and_nothing_new_in_a_pipe(tmp_path: Path) -> None:
    config = ROOT / "supervisor" / "data" / "examples" / "template.yaml"
    out, err = _check_on_a_terminal(config)
    stages = re.findall(r"^safety-supervisor: (\w+) \.\.\. (\d+\.\d\d) s$", err, re.M)
    assert [s for s, _ in stages] == [
        "parse",
        "formalize",
        "unroll",
        "consistency",
        "realizability",
        "vacuity",
        "redundancy",
        "compile",
    ], err
    assert "requirements ok, monitor compiled and loaded" in out
    assert "safety-supervisor: parse" not in out
    piped = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(config)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=900,
    )
    assert piped.returncode == 0, piped.stderr
    assert piped.stderr == ""
    assert "safety-supervisor: parse" not in piped.stdout
