"""limits: a time bound is paid for in monitor state and analysis size; a config that
would need too much of either is refused, or its analyses cut short, with the reason
(docs/reference/faults.md, docs/reference/config.md limits)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from monitors.backends.c99 import state_bytes
from monitors.errors import UserError
from monitors.ir.formula import parse_formula
from monitors.verify.analysis import Req, VarInfo, analyse
from supervisor.analysis_report import format_analysis, skip_text
from supervisor.config import load_config
from supervisor.pipeline import build_project, compile_project
from supervisor.validation import analyse_project

AS_LIMIT = 1 << 30  # the CLI runs under a 1 GB address-space limit


def _config(tmp_path: Path, within: str, *, period_ms: float = 10, limits: str = "") -> Path:
    p = tmp_path / "limits.yaml"
    p.write_text(
        "component: R\n"
        f"step: {{policy: periodic, period_ms: {period_ms}}}\n"
        "variables:\n"
        "  a: {type: bool, topic: /a, msg: std_msgs/msg/Bool}\n"
        "  b: {type: bool, topic: /b, msg: std_msgs/msg/Bool}\n"
        "requirements:\n"
        "  - id: ok\n"
        "    text: R shall always satisfy a | b\n"
        "    on_violation: [rec]\n"
        "  - id: slow\n"
        f"    text: when a R shall within {within} satisfy b\n"
        "    on_violation: [rec]\n"
        "mitigations:\n"
        "  rec: {log: {message: x}}\n" + limits
    )
    return p


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """The CLI under an address-space limit: running away is a MemoryError or an
    allocation failure, never a machine that swaps."""
    argv = ["prlimit", f"--as={AS_LIMIT}", sys.executable, "-m", "supervisor", *args]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
@pytest.mark.parametrize("within", ["100000 hours", "36000000000 ticks", "9999999999 seconds"])
def test_huge_bound_is_refused_at_its_line_with_the_memory_it_needs(
    tmp_path: Path, within: str
) -> None:
    cfg = _config(tmp_path, within)
    r = _cli("check", str(cfg))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    fail = [line for line in r.stdout.splitlines() if line.startswith("FAIL  slow")]
    assert len(fail) == 1, r.stdout
    assert f"{cfg}:11: requirement 'slow' needs " in fail[0]
    assert "GB of monitor state, limit 64.0 MB (limits.monitor_memory_mb)" in fail[0]
    assert "monitor not compiled" in r.stdout
    # explain, and compile (the unit's other ways in) are refused the same way
    r = _cli("explain", str(cfg))
    assert r.returncode == 1 and f"{cfg}:11: requirement 'slow' needs" in r.stdout
    r = _cli("compile", str(cfg), "-o", str(tmp_path / "out"))
    assert r.returncode == 1 and f"{cfg}:11: requirement 'slow' needs" in r.stderr


def test_bound_just_under_the_limit_compiles_and_the_analyses_say_why_they_skip(
    tmp_path: Path,
) -> None:
    # 1000 s at 1 ms: a delay line of 1e6 bytes, under a 1 MB (1048576 bytes) limit
    cfg = _config(tmp_path, "1000 seconds", period_ms=1, limits="limits: {monitor_memory_mb: 1}\n")
    r = _cli("check", str(cfg))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "monitor compiled and loaded" in r.stdout
    skipped = [line for line in r.stdout.splitlines() if "skipped:" in line]
    assert skipped and "consistency, realizability, vacuity, redundancy" in skipped[0]
    assert "k = 1000002 ticks" in skipped[0] and "limits.analysis_budget_s" in skipped[0]
    # the same bound over a smaller limit is refused
    cfg = _config(
        tmp_path, "1000 seconds", period_ms=1, limits="limits: {monitor_memory_mb: 0.9}\n"
    )
    r = _cli("check", str(cfg))
    assert r.returncode == 1 and f"{cfg}:11: requirement 'slow' needs 976.6 kB" in r.stdout


def test_many_requirements_together_over_the_limit_is_an_error_at_limits(tmp_path: Path) -> None:
    text = _config(tmp_path, "1000 seconds", period_ms=1).read_text()
    more = "".join(
        f"  - id: slow{i}\n    text: when a R shall within 100{i} seconds satisfy b\n"
        "    on_violation: [rec]\n"
        for i in range(3)
    )
    cfg = tmp_path / "many.yaml"
    text = text.replace("mitigations:", more + "mitigations:")
    cfg.write_text(text + "limits:\n  monitor_memory_mb: 2\n")
    project = build_project(load_config(cfg), ros=False)
    assert all(r.ok for r in project.requirements)
    (err,) = project.errors
    assert (err.file, err.line) == (str(cfg), text.count("\n") + 1)
    assert "the monitor needs 3.8 MB of state for its 5 requirements, limit 2.0 MB" in str(err)


def test_computed_state_is_what_the_compiler_allocates(tmp_path: Path) -> None:
    """state_bytes against the symbol sizes gcc gives each requirement's state struct."""
    cfg = _config(tmp_path, "70 ticks")
    text = cfg.read_text().replace(
        "requirements:\n",
        "  m: {type: bool, define: '(a S[3,200] b) | (O[100,100000] a) | (Y b)'}\n"
        "requirements:\n  - id: mixed\n    text: R shall always satisfy m | a\n"
        "    on_violation: [rec]\n",
    )
    cfg.write_text(text)
    project = build_project(load_config(cfg), ros=False)
    assert project.ok, [str(r.error) for r in project.requirements]
    manifest = compile_project(project, tmp_path / "out")
    nm = subprocess.run(
        ["nm", "-S", "--defined-only", str(tmp_path / "out" / manifest["library"])],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    sizes = {f"ss__r{i}": s for i, s in enumerate(state_bytes(project.spec()).values()) if s}
    found = {
        parts[3]: int(parts[1], 16)
        for parts in (line.split() for line in nm.splitlines())
        if len(parts) == 4 and parts[3].startswith("ss__r")
    }
    assert found == sizes and len(found) == 3


def test_limits_section_is_validated_with_lines(tmp_path: Path) -> None:
    for bad, msg in [
        ("limits: {monitor_memory: 3}\n", "unknown key 'monitor_memory' in limits"),
        ("limits: {analysis_budget_s: -1}\n", "limits.analysis_budget_s must be positive"),
        ("limits: {monitor_memory_mb: .inf}\n", "is not a finite number"),
        ("limits: 3\n", "limits must be a mapping"),
    ]:
        cfg = _config(tmp_path, "3 ticks", limits=bad)
        with pytest.raises(UserError) as e:
            load_config(cfg)
        assert e.value.line == 15 and msg in str(e.value), str(e.value)


def test_budget_exhausted_during_the_analyses_names_what_was_skipped() -> None:
    # cheap to unroll, slow to solve: many requirements over 64-bit values
    vars_ = [VarInfo(n, "int64", "input" if n < "m" else "output") for n in "abcxyz"]
    reqs = [
        Req(f"r{i}", parse_formula(f"H (a * x + {i} = b * y -> O[0,6] (z * c = {i} * a))"))
        for i in range(8)
    ]
    a = analyse(reqs, vars_, k=8, timeout_s=5.0, budget_s=0.5)
    assert a.skipped, "the budget did not cut anything short"
    assert all("time budget of 0.5 s ran out" in why.reason for why in a.skipped.values())
    assert a.seconds["total"] < 10.0
    # an analysis that had finished before keeps its result
    assert set(a.skipped) <= {"consistency", "realizability", "vacuity", "redundancy"}


def test_check_prints_the_skipped_analyses(tmp_path: Path) -> None:
    cfg = _config(tmp_path, "30 ticks", limits="limits: {analysis_budget_s: 0.001}\n")
    project = build_project(load_config(cfg), ros=False)
    a = analyse_project(project)
    assert a is not None and a.skipped
    text = format_analysis(a)
    assert "  skipped:       " in text and "(limits.analysis_budget_s)" in text
    for name in a.skipped:
        assert name in text


def test_a_set_too_large_to_unroll_in_the_budget_is_given_up_at_once() -> None:
    # Unrolling is measured on the first requirements and projected: a set that
    # would spend most of the budget building terms is skipped with the estimate,
    # long before the budget runs out.
    vars_ = [VarInfo(f"v{i}", "int64", "input") for i in range(20)]
    reqs = [
        Req(
            f"r{i}",
            parse_formula(f"H (O[0,90] (v{i % 20} > {i}) -> H[0,90] (v{(i + 7) % 20} < 3))"),
        )
        for i in range(400)
    ]
    budget = 20.0
    t0 = time.monotonic()
    a = analyse(reqs, vars_, k=95, timeout_s=5.0, budget_s=budget)
    spent = time.monotonic() - t0
    assert set(a.skipped) >= {"consistency", "realizability", "vacuity", "redundancy"}
    why = a.skipped["consistency"].reason
    assert "unrolling all 400 requirements would take about" in why, why
    assert "measured on the first" in why and "k = 95" in why
    assert spent < budget / 2, f"gave up after {spent:.1f} s of a {budget:g} s budget"


def test_z3_memory_limit_stops_the_analyses_with_the_reason() -> None:
    # limits.analysis_memory_mb is z3's max_memory: reached, the analysis running
    # stops, the later ones are skipped, and explain's examples are not asked for.
    vars_ = [VarInfo(n, "int64", "input" if n < "m" else "output") for n in "abxy"]
    reqs = [Req(f"r{i}", parse_formula(f"H (a + {i} = b -> O[0,4] (x = y))")) for i in range(3)]
    a = analyse(reqs, vars_, k=6, timeout_s=5.0, budget_s=30.0, memory_mb=1)
    assert skip_text(a.skipped["consistency"]) == (
        "stopped: z3 reached its memory limit of 1 MB (limits.analysis_memory_mb)"
    )
    for name in ("vacuity", "examples"):
        assert "memory limit of 1 MB" in a.skipped[name].reason, a.skipped
    assert a.find_examples is None and a.examples("r0") == (None, None)
    text = format_analysis(a)
    assert "memory limit of 1 MB (limits.analysis_memory_mb)" in text
    assert "(limits.analysis_memory_mb) (limits.analysis_budget_s)" not in text
    # the same set without the limit is analysed in full
    full = analyse(reqs, vars_, k=6, timeout_s=5.0, budget_s=30.0)
    assert not full.skipped, full.skipped


def test_check_says_when_z3_reached_the_memory_limit(tmp_path: Path) -> None:
    cfg = _config(tmp_path, "3 ticks", limits="limits: {analysis_memory_mb: 1}\n")
    p = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(cfg)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "z3 reached its memory limit of 1 MB (limits.analysis_memory_mb)" in p.stdout
