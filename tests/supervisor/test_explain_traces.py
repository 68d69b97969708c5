"""``explain``'s example traces show readable values (small integers, short
decimals), asked of the solver, and still witness what they claim: the reference
interpreter re-checks each one here (monitors/verify/analysis/readable.py)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from monitors.verify.analysis import Analysis, Example, analyse
from monitors.verify.interpret import verdicts
from supervisor.pipeline import project_for
from supervisor.validation import project_requirements

EXAMPLES = Path(__file__).resolve().parents[2] / "supervisor" / "data" / "examples"
SIGNIFICANT = 6  # digits a value of an example trace has at most


def significant_digits(x: float | int) -> int:
    """Significant decimal digits of ``x`` as Python prints it (``2.7e-312``: 2)."""
    mantissa = repr(abs(x)).split("e")[0].replace(".", "").lstrip("0").rstrip("0")
    return len(mantissa) or 1


def denormal(x: float) -> bool:
    return x != 0 and abs(x) < 2.2250738585072014e-308


def readable(x: object) -> bool:
    if isinstance(x, bool) or x is None:
        return True
    assert isinstance(x, (int, float))
    if isinstance(x, float) and (denormal(x) or str(x) == "-0.0"):
        return False
    return significant_digits(x) <= SIGNIFICANT


def test_significant_digits_counts_what_a_reader_sees() -> None:
    assert significant_digits(2.7e-312) == 2 and denormal(2.7e-312)
    assert significant_digits(0.800000011920929) == 15
    assert significant_digits(8465) == 4
    assert significant_digits(10000) == 1
    assert significant_digits(0.5) == 1
    assert not readable(7.4965867303222e-310) and not readable(-0.0) and readable(0.0)


def analysis_of(name: str) -> Analysis:
    """The analyses with the config's k and z3's default resource limit, without the
    time budget: the examples are asked for however long they take here."""
    project = project_for(EXAMPLES / name, ros=False)
    reqs, roles = project_requirements(project)
    return analyse(reqs, roles, k=project.config.analysis.k)


def assert_witness(a: Analysis, rid: str, ex: Example, satisfied: bool) -> None:
    req = next(r for r in a.requirements if r.id == rid)
    got = verdicts(req.formula, ex.trace)
    assert got == ex.verdicts[rid], (rid, ex.trace)
    held = all(got) if req.monotone else got[-1]
    assert held is satisfied, (rid, satisfied, ex.trace)


@pytest.mark.parametrize(
    "name",
    [
        "template.yaml",
        "srobot.yaml",
        "srobot-from-fret.yaml",
        pytest.param("mobile-base.yaml", marks=pytest.mark.slow),  # a minute of z3
    ],
)
def test_example_traces_of_the_shipped_examples_are_readable_witnesses(name: str) -> None:
    # In a fresh process, as `explain` runs: z3's resource count, and with it what
    # a budgeted search reaches, depends on what the process asked of z3 before
    # (the suite's earlier tests here).
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=spawn) as pool:
        pool.submit(check_examples, name).result()


def check_examples(name: str) -> None:
    a = analysis_of(name)
    shown = 0
    for r in a.requirements:
        sat, viol = a.examples(r.id)
        for ex, satisfied in ((sat, True), (viol, False)):
            if ex is None:
                continue
            assert_witness(a, r.id, ex, satisfied)
            for t, row in enumerate(ex.trace):
                for var, x in row.items():
                    assert readable(x), (name, r.id, satisfied, t, var, x)
            shown += 1
    assert shown >= len(a.requirements), "most requirements have an example"
