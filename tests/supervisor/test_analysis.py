"""The formal analyses (monitors/analysis.py) on the thesis's requirements and on
realistic broken sets (tests/data/analysis/*.yaml), all with real z3.

Every trace a finding carries is evaluated again here with the reference
interpreter: the verdicts printed next to it must be the interpreter's.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from monitors.ir.formula import parse_formula
from monitors.verify.analysis import Analysis, Req, VarInfo, analyse
from monitors.verify.interpret import verdicts
from supervisor.analysis_report import format_analysis
from supervisor.pipeline import project_for
from supervisor.tools.bench.analysis import generated
from supervisor.validation import analyse_project

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "analysis"
SROBOT = ROOT / "config" / "srobot.yaml"


def run(path: Path, k: int | None = None) -> Analysis:
    a = analyse_project(project_for(path, ros=False), k)
    assert a is not None
    assert_traces_agree(a)
    return a


def assert_traces_agree(a: Analysis) -> None:
    """Each finding's verdict table is what the interpreter says on its trace."""
    formulas = {r.id: r.formula for r in a.requirements}
    for f in a.findings:
        if f.trace is None:
            continue
        assert f.verdicts, f
        for rid, shown in f.verdicts.items():
            assert verdicts(formulas[rid], f.trace) == shown, (f.kind, rid, f.trace)


def only(a: Analysis, kind: str) -> list:
    return [f for f in a.findings if f.kind == kind]


def cli(*args: object) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=300,
    )


# ------------------------------------------------------------------ the thesis


def test_srobot_is_consistent_and_realizable_under_its_assumptions_in_seconds():
    t = time.perf_counter()
    a = run(SROBOT)
    assert time.perf_counter() - t < 5
    assert sum(r.assumption for r in a.requirements) == 2 and len(a.requirements) == 13
    assert a.consistent is True
    assert a.realizability.startswith("realizable, proved for all time")
    assert a.findings == []


def test_an_input_constraint_is_fine_as_an_assumption():
    # keep_distance as a guarantee is unrealizable (below); as an assumption it is what
    # the environment promises, and the set is realizable
    project = project_for(DATA / "input_guarantee.yaml", ros=False)
    for r in project.requirements:
        r.entry.assumption = r.entry.assumption or r.id == "keep_distance"
    a = analyse_project(project)
    assert a is not None and not a.errors
    assert a.realizability.startswith("realizable, proved for all time")


def test_explain_examples_satisfy_and_violate_each_srobot_requirement():
    a = run(SROBOT)
    for r in a.requirements:
        sat, viol = a.examples(r.id)
        assert sat is not None and viol is not None, r.id
        assert verdicts(r.formula, sat.trace) == sat.verdicts[r.id] and all(sat.verdicts[r.id])
        assert verdicts(r.formula, viol.trace) == viol.verdicts[r.id]
        assert not all(viol.verdicts[r.id])
        if not r.assumption:
            assert "every other requirement holds" in viol.note, (r.id, viol.note)


# ------------------------------------------------------------------ broken sets


def test_two_states_demanded_in_the_same_zone_conflict():
    a = run(DATA / "conflict.yaml")
    [f] = a.errors
    assert f.kind == "unrealizable" and set(f.requirements) == {"state_req103", "red_zone_slow"}
    [tick] = f.trace
    assert tick["classifier"] == 1 and tick["distance_to_target"] <= 3  # the red zone
    assert f.verdicts["red_zone_slow"] == [False] and f.verdicts["state_req103"] == [True]


def test_requirement_on_a_class_the_classifier_never_reports_is_vacuous():
    a = run(DATA / "vacuous.yaml")
    [f] = a.findings
    assert (f.kind, f.severity, f.requirements[0]) == ("vacuous", "warning", "state_req301")
    assert "classifier = 3" in f.message and not a.errors


def test_guarantee_on_an_input_is_unrealizable_with_the_defeating_input():
    a = run(DATA / "input_guarantee.yaml")
    [f] = a.errors
    assert f.kind == "unrealizable" and f.requirements == ("keep_distance",)
    assert "read(s) no output" in f.fix
    # the input that defeats every controller: a worker within 3 m
    assert f.trace == [{"classifier": 1, "distance_to_target": 0}]
    assert f.verdicts["keep_distance"] == [False] and f.verdicts["classifier_assumption"] == [True]


def test_timed_pair_is_unrealizable_only_from_the_fourth_tick():
    a = run(DATA / "timed.yaml")
    assert a.k == 7  # largest bound 5, plus 2
    [f] = a.errors
    assert set(f.requirements) == {"halt_on_obstacle", "clear_row"}
    assert len(f.trace) == 4 and f.trace[0]["obstacle"] is True
    assert f.verdicts["clear_row"][-1] is False or f.verdicts["halt_on_obstacle"][-1] is False
    # k matters: three ticks are not enough to see it (both can still be met)
    short = run(DATA / "timed.yaml", k=3)
    assert not short.errors and "causal controller" in short.realizability
    assert only(short, "k-too-small")  # and the analysis says why it cannot tell
    assert run(DATA / "timed.yaml", k=4).errors


def test_timed_pair_with_a_forced_trigger_is_inconsistent_from_tick_three():
    a = run(DATA / "timed_conflict.yaml")
    [f] = a.errors
    assert f.kind == "conflict" and a.consistent is False
    assert {"halt_on_obstacle", "clear_row"} <= set(f.requirements)
    assert "tick 3" in f.message and len(f.trace) == 4
    assert run(DATA / "timed_conflict.yaml", k=3).consistent is True


def test_obligation_that_must_anticipate_inputs_is_not_causally_realizable():
    a = run(DATA / "anticipate.yaml")
    [f] = a.errors
    assert set(f.requirements) == {"warn_ahead", "no_false_warning"}
    assert "only knows past and present inputs" in f.message


def test_redundant_guarantee_is_named_with_what_implies_it():
    a = run(DATA / "redundant.yaml")
    [f] = a.warnings
    assert f.kind == "redundant" and f.requirements[0] == "red_zone_halt"
    assert {"state_req103", "operationalstate_3"} <= set(f.requirements)
    assert "for all time" in f.message and not a.errors


# ------------------------------------------------------------------ smaller cases


BOOLS = [VarInfo("p", "bool", "input"), VarInfo("q", "bool", "output")]


def req(rid: str, text: str, **kw: object) -> Req:
    return Req(rid, parse_formula(text), **kw)  # type: ignore[arg-type]


def test_non_monotone_requirement_is_a_warning_judged_at_the_end():
    a = analyse([req("ev", "O q", monotone=False, note="non-monotone: eventually")], BOOLS)
    [f] = a.findings
    assert (f.kind, f.severity) == ("non-monotone", "warning") and a.consistent


def test_assumption_reading_outputs_is_treated_as_a_guarantee():
    a = analyse([req("a", "H (p -> q)", assumption=True)], BOOLS)
    assert [f.kind for f in a.findings] == ["assumption-reads-outputs"]


def test_real_power_is_left_out_not_approximated():
    vars_ = [VarInfo("d", "double", "input"), VarInfo("q", "bool", "output")]
    a = analyse([req("pw", "H (d ^ 2.0 > 1.0 -> q)"), req("ok", "H q")], vars_)
    assert [f.kind for f in a.findings] == ["not-analysed"] and a.consistent


def test_without_outputs_realizability_is_not_claimed():
    a = analyse([req("r", "H p")], [VarInfo("p", "bool", "input")])
    assert [f.kind for f in a.findings] == ["no-outputs"]
    assert a.realizability.startswith("not checked")


def test_mixed_comparisons_use_the_concrete_game():
    # y must exceed x: no Boolean abstraction (the comparison mixes input and output),
    # and x = INT64_MAX defeats every controller
    vars_ = [VarInfo("x", "int64", "input"), VarInfo("y", "int64", "output")]
    a = analyse([req("gt", "H (Y TRUE -> y > x)")], vars_)
    [f] = a.errors
    assert f.trace[-1]["x"] == 2**63 - 1
    assert_traces_agree(a)


def test_generated_channels_are_realizable_by_a_causal_controller():
    reqs, vars_ = generated(n_channels=3)
    a = analyse(reqs, vars_)
    assert a.k == 22 and a.consistent and not a.errors, format_analysis(a)
    assert "causal controller" in a.realizability and "3 independent groups" in a.realizability


# ------------------------------------------------------------------ command line


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_check_exit_codes_and_tables():
    r = cli("check", SROBOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "realizable, proved for all time" in r.stdout and "0 errors, 0 warnings" in r.stdout
    r = cli("check", DATA / "conflict.yaml")
    assert r.returncode == 1 and "Traceback" not in r.stdout + r.stderr
    assert "ERROR unrealizable: state_req103, red_zone_slow" in r.stdout
    assert "tick  classifier  distance_to_target  OpState | state_req103" in r.stdout
    assert "what to change:" in r.stdout
    r = cli("check", DATA / "vacuous.yaml")
    assert r.returncode == 0 and "warning vacuous: state_req301" in r.stdout
    r = cli("check", DATA / "timed.yaml", "--k", "3")
    assert r.returncode == 0, r.stdout
    assert cli("check", DATA / "timed.yaml", "--k", "0").returncode == 2


def test_explain_shows_role_findings_and_examples():
    r = cli("explain", DATA / "vacuous.yaml", "state_req301")
    assert r.returncode == 0, r.stderr
    assert "role:      guarantee" in r.stdout
    assert "analysis:  warning vacuous" in r.stdout
    assert "satisfied by:" in r.stdout and "violated by:" in r.stdout


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_analysis_section_of_the_config(tmp_path):
    text = (DATA / "timed.yaml").read_text()
    cfg = tmp_path / "timed.yaml"
    cfg.write_text(text + "analysis: {k: 3}\n")
    assert cli("check", cfg).returncode == 0
    cfg.write_text(text + "analysis: {enabled: false}\n")
    r = cli("check", cfg)
    assert r.returncode == 0 and "analysis:" not in r.stdout
    cfg.write_text(
        text
        + textwrap.dedent("""\
        analysis:
          k: 3
          depth: 4
        """)
    )
    r = cli("check", cfg)
    assert r.returncode == 1
    assert f"{cfg}:{text.count(chr(10)) + 3}: unknown key 'depth' in analysis" in r.stderr
