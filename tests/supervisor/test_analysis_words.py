"""The analyses (``monitors/verify/analysis/``) say which of their limits they
reached as values (``Limit``, ``Skip``, ``Remedy``), never by the supervisor's
names for them; ``supervisor/analysis_report.py`` words those as ``check`` and
``explain`` have always printed them (docs/ARCHITECTURE.md, "Three packages, one
direction")."""

from __future__ import annotations

import re
from pathlib import Path

from monitors.ir.formula import parse_formula
from monitors.verify.analysis import Analysis, Finding, Limit, Remedy, Req, Skip, VarInfo, analyse
from supervisor.analysis_report import fix_text, skip_text
from supervisor.pipeline import project_for
from supervisor.validation import project_requirements

ROOT = Path(__file__).resolve().parents[2]
# How the supervisor names the analyses' limits: config keys and the option.
APPLICATION_WORDS = re.compile(r"analysis\.|limits\.|--k\b|analysis_budget_s|analysis_memory_mb")


def texts(a: Analysis) -> list[str]:
    """Everything the analyses wrote in words."""
    out = [a.consistency, a.realizability]
    for f in a.findings:
        out += [f.message, f.fix, f.trace_note]
    out += [s.reason for s in a.skipped.values()]
    return out


def too_short() -> Analysis:
    """The timed pair on traces shorter than its bounds: a k-too-small finding."""
    reqs, roles = project_requirements(
        project_for(ROOT / "tests" / "data" / "analysis" / "timed.yaml", ros=False)
    )
    return analyse(reqs, roles, k=3)


def out_of_memory() -> Analysis:
    vars_ = [VarInfo(n, "int64", "input" if n < "m" else "output") for n in "abxy"]
    reqs = [Req(f"r{i}", parse_formula(f"H (a + {i} = b -> O[0,4] (x = y))")) for i in range(3)]
    return analyse(reqs, vars_, k=6, timeout_s=5.0, budget_s=30.0, memory_mb=1)


def over_budget() -> Analysis:
    vars_ = [VarInfo("a", "bool", "input"), VarInfo("b", "bool", "output")]
    return analyse(
        [Req("r1", parse_formula("H ((H[0,5] a) -> b)"))], vars_, k=100_000, budget_s=0.01
    )


def test_the_analyses_name_no_setting_of_the_supervisor() -> None:
    for a in (too_short(), out_of_memory(), over_budget()):
        said = [t for t in texts(a) if APPLICATION_WORDS.search(t)]
        assert said == [], said


def test_the_limits_reached_are_values_the_supervisor_words_as_before() -> None:
    [short] = [f for f in too_short().findings if f.kind == "k-too-small"]
    assert short.remedy == Remedy(Limit.TRACE_LENGTH, at_least=5)
    assert fix_text(short) == "analyse longer traces: --k 5 or more"

    memout = out_of_memory().skipped
    assert memout["consistency"] == Skip(
        "stopped: z3 reached its memory limit of 1 MB", Limit.MEMORY
    )
    assert skip_text(memout["examples"]) == (
        "z3 reached its memory limit of 1 MB (limits.analysis_memory_mb)"
    )

    budget = over_budget().skipped["consistency"]
    assert budget.limit is Limit.TIME_BUDGET and budget.remedies == (Limit.TRACE_LENGTH,)
    assert skip_text(budget) == (
        "unrolling traces of k = 100000 ticks builds about 1.1e+06 solver terms, about 5.5 s "
        "against a time budget of 0.01 s; a shorter k (analysis.k, --k) analyses shorter traces "
        "(limits.analysis_budget_s)"
    )


def test_each_remedy_and_skip_is_worded_as_check_printed_it() -> None:
    undecided = Finding(
        "realizability",
        "warning",
        ("r1",),
        "not decided",
        "give the double variables ranges",
        remedy=Remedy(Limit.SOLVER_TIMEOUT),
    )
    assert fix_text(undecided) == "raise analysis.timeout_s, or give the double variables ranges"
    too_large = Skip(
        "unrolling would take long (traces of k = 9 ticks)",
        Limit.TIME_BUDGET,
        (Limit.TRACE_LENGTH, Limit.TIME_BUDGET),
    )
    assert skip_text(too_large) == (
        "unrolling would take long (traces of k = 9 ticks); a shorter k (analysis.k, --k) or a "
        "larger limits.analysis_budget_s analyses it (limits.analysis_budget_s)"
    )
    assert skip_text(Skip("the time budget ran out", Limit.TIME_BUDGET)) == (
        "the time budget ran out (limits.analysis_budget_s)"
    )
