"""Margins in the native C99 monitor against the reference margins, with real gcc and cffi.

Random formulas over every operator (the boolean backend's strategies) and random
traces with edge values: the compiled monitor's margin of each requirement must
equal ``monitors/verify/robustness.py``'s at every tick, exactly, also after a
full reset and after resetting one requirement mid-trace; the sign must agree with
the boolean verdict (docs/reference/margins.md).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from harness import INPUTS, make_trace
from hypothesis import given, settings
from hypothesis import strategies as st

from monitors.backends.c99 import margin_state
from monitors.backends.copilot import generate_haskell
from monitors.backends.load import LoadedMonitor, compile_spec
from monitors.errors import UserError
from monitors.ir.formula import Formula, parse_formula
from monitors.ir.spec import (
    MARGIN_DELAY_TICKS,
    MARGIN_WINDOW_TICKS,
    MonitorSpec,
    RequirementSpec,
)
from monitors.verify.interpret import verdicts
from monitors.verify.robustness import margins
from tests.monitors.backends.test_c99 import (
    DEFINES,
    RICH,
    SETTINGS,
    WITHIN,
    assert_hard_real_time_c,
    bool_f,
)


def make_spec(formulas: list[Formula], bool_margin: float = math.inf) -> MonitorSpec:
    reqs = tuple(RequirementSpec(f"R{i}", f) for i, f in enumerate(formulas))
    return MonitorSpec("test", INPUTS, reqs, DEFINES, margins=True, bool_margin=bool_margin)


def run_margins(mon: LoadedMonitor, spec: MonitorSpec, trace: list[dict]) -> list[list[float]]:
    """Margins per requirement per tick from the compiled monitor."""
    names = [v.name for v in spec.inputs]
    rows = []
    for row in trace:
        mon.tick([row[n] for n in names])
        rows.append(mon.margins())
    return [[r[i] for r in rows] for i in range(len(spec.requirements))]


def reference(spec: MonitorSpec, trace: list[dict]) -> list[list[float]]:
    return [
        margins(spec.expanded(r), trace, bool_margin=spec.bool_margin) for r in spec.requirements
    ]


def assert_same(
    got: list[list[float]], want: list[list[float]], spec: MonitorSpec, trace: list, what: str
) -> None:
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        assert not any(math.isnan(x) for x in w), "a reference margin is NaN"
        if g != w:
            tick = next(t for t in range(len(g)) if g[t] != w[t])
            raise AssertionError(
                f"{what}: requirement {spec.requirements[i].id} = "
                f"{spec.expanded(spec.requirements[i])}\n  first difference at tick {tick}: "
                f"C margin {g[tick]!r}, interpreter margin {w[tick]!r}"
                f"\n  trace[{max(0, tick - 3)}:{tick + 1}] = {trace[max(0, tick - 3) : tick + 1]}"
            )


def assert_sign_matches_verdict(
    spec: MonitorSpec, trace: list[dict], got: list[list[float]]
) -> None:
    for r, ms in zip(spec.requirements, got, strict=True):
        for tick, (m, holds) in enumerate(zip(ms, verdicts(spec.expanded(r), trace), strict=True)):
            assert not (m > 0 and not holds), (r.id, tick, m, "positive margin, violated")
            assert not (m < 0 and holds), (r.id, tick, m, "negative margin, holds")


# ------------------------------------------------------------------ property tests


@pytest.mark.slow
@SETTINGS
@given(
    formulas=st.lists(bool_f(4, max_bound=40), min_size=8, max_size=14),
    seed=st.integers(0, 2**32),
    n=st.integers(1, 200),
    cut=st.floats(0, 1),
    victim=st.integers(0, 15),
    bool_margin=st.sampled_from([math.inf, 1.0, 0.25]),
)
def test_compiled_margins_match_the_interpreter(
    tmp_path_factory, formulas, seed, n, cut, victim, bool_margin
) -> None:
    formulas = [*formulas, WITHIN]
    spec = make_spec(formulas, bool_margin)
    trace = make_trace(seed, n)
    mon = compile_spec(spec, tmp_path_factory.mktemp("mon"))
    full = reference(spec, trace)

    got = run_margins(mon, spec, trace)
    assert_same(got, full, spec, trace, "fresh")
    assert_sign_matches_verdict(spec, trace, got)

    # monitor_reset mid-trace: like a fresh monitor on the rest of the trace
    k = int(cut * n)
    mon.reset()
    run_margins(mon, spec, trace[:k])
    mon.reset()
    rest = reference(spec, trace[k:])
    assert_same(run_margins(mon, spec, trace[k:]), rest, spec, trace[k:], "after reset")

    # reset one requirement mid-trace: its margin restarts, the others' do not
    v = victim % len(formulas)
    mon.reset()
    run_margins(mon, spec, trace[:k])
    mon.reset_requirement(spec.requirements[v].id)
    want = [rest[i] if i == v else w[k:] for i, w in enumerate(full)]
    assert_same(run_margins(mon, spec, trace[k:]), want, spec, trace[k:], f"reset R{v}")


@pytest.mark.slow
@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32), n=st.integers(1, 120))
def test_batch_margins_are_the_ticks_margins(tmp_path_factory, seed, n) -> None:
    spec = make_spec([*RICH, WITHIN])
    trace = make_trace(seed, n)
    mon = compile_spec(spec, tmp_path_factory.mktemp("batch"))
    by_tick = run_margins(mon, spec, trace)
    mon.reset()
    names = [v.name for v in spec.inputs]
    batch = mon.tick_batch(mon.pack_rows([[row[x] for x in names] for row in trace]))
    assert batch.margins is not None
    assert batch.margins.shape == (n, len(spec.requirements))
    assert [list(col) for col in batch.margins.T] == by_tick


# ------------------------------------------------------------------ windows and fallback

ROW = {"b0": False, "b1": False, "b2": False, "i0": 0, "i1": 0, "d0": 0.0, "d1": 0.0}


def _trace(**columns: list) -> list[dict]:
    n = len(next(iter(columns.values())))
    return [{**ROW, **{k: v[t] for k, v in columns.items()}} for t in range(n)]


def test_a_window_within_the_limit_keeps_its_margin_and_a_longer_one_falls_back(
    tmp_path: Path,
) -> None:
    w = MARGIN_WINDOW_TICKS
    kept, long = parse_formula(f"H[0,{w}] (d0 < 5.0)"), parse_formula(f"H[0,{w + 1}] (d0 < 5.0)")
    since = parse_formula(f"(d1 > 0.0) S[2,{w + 1}] b0")
    d = MARGIN_DELAY_TICKS
    delays = [parse_formula(f"O[{d},{d + w}] (d0 < 1.0)"), parse_formula(f"H[{d + 1},inf] b0")]
    spec = make_spec([kept, long, since, *delays], bool_margin=1.0)
    state = margin_state(spec)
    assert state["R0"].fallbacks == ()
    assert state["R0"].bytes == (w + 1) * 8 + 4  # w + 1 stored margins and a fill count
    assert state["R1"].fallbacks == (f"(H[0,{w + 1}] (d0 < 5.0))",)
    assert state["R2"].fallbacks == (f"((d1 > 0.0) S[2,{w + 1}] b0)",)
    assert state["R3"].fallbacks == ()  # a delay of d, then a window of w + 1
    assert state["R3"].bytes == (d + w + 1) * 8 + 3 * 4  # two rings, their positions, a count
    assert state["R4"].fallbacks == (f"(H[{d + 1},inf] b0)",)

    d0 = [1.0, 2.0, 4.5, 3.0] + [0.0] * (d + 40)
    trace = _trace(d0=d0, b0=[True] * len(d0), d1=[1.0] * len(d0))
    mon = compile_spec(spec, tmp_path)
    got = run_margins(mon, spec, trace)
    assert got == reference(spec, trace)
    # kept: the window's minimum of 5 - d0, which 4.5 decides until it leaves the window
    assert got[0][:4] == [4.0, 3.0, 0.5, 0.5]
    assert got[0][2 + w] == 0.5 and got[0][3 + w] == 2.0
    # fallen back: the boolean verdict as +-bool_margin
    assert got[1][:4] == [1.0, 1.0, 1.0, 1.0]
    assert set(got[2]) <= {1.0, -1.0}
    # delayed by d ticks: empty (-1) until tick d, then 1 - d0 from tick 0 on
    assert got[3][d - 1 : d + 4] == [-1.0, 0.0, 0.0, 0.0, 0.0]
    assert got[3][d + 4] == 1.0  # d0 is 0 from tick 4 on
    assert set(got[4]) == {1.0}  # H over an empty window, then over b0: true


def test_reset_requirement_restarts_its_margin_only(tmp_path: Path) -> None:
    spec = make_spec([parse_formula("H (d0 < 3.0)"), parse_formula("O (d0 > 1.0)")])
    mon = compile_spec(spec, tmp_path)
    for d in (1.0, 2.5, 0.5):
        mon.tick([ROW[v.name] if v.name != "d0" else d for v in spec.inputs])
    assert mon.margins() == [0.5, 1.5]
    mon.reset_requirement("R0")
    mon.tick([ROW[v.name] if v.name != "d0" else 2.0 for v in spec.inputs])
    assert mon.margins() == [1.0, 1.5]  # R0 forgot 2.5; R1 still remembers it
    mon.reset()
    mon.tick([ROW[v.name] if v.name != "d0" else 2.0 for v in spec.inputs])
    assert mon.margins() == [1.0, 1.0]


def test_generated_c_with_margins_is_loop_free_strict_c99(tmp_path: Path) -> None:
    windows = [parse_formula(f) for f in ("O[3,20] (d0 > 1.0)", "(b0 | (i0 < 2)) S[4,inf] b1")]
    assert_hard_real_time_c(make_spec([*RICH, WITHIN, *windows]), tmp_path)


def test_without_margins_the_monitor_says_so(tmp_path: Path) -> None:
    spec = MonitorSpec("test", INPUTS, (RequirementSpec("R0", parse_formula("b0")),))
    mon = compile_spec(spec, tmp_path)
    assert not mon.has_margins
    with pytest.raises(UserError, match="computes no margins"):
        mon.margins()
    assert mon.tick_batch(mon.pack_rows([[ROW[v.name] for v in INPUTS]])).margins is None
    assert margin_state(spec) == {}


def test_copilot_backend_refuses_margins_in_one_line() -> None:
    spec = make_spec([parse_formula("H (d0 < 3.0)")])
    with pytest.raises(UserError) as e:
        generate_haskell(spec)
    assert re.fullmatch(
        r"copilot: the Copilot backend computes no margins \(hint: .*\)", str(e.value)
    )
