"""The reference margins (monitors/verify/robustness.py): hand-worked examples of every
operator, the sRobot's distance requirement through FRET's formalization, and the
sign property (margin > 0 => holds, < 0 => violated) on random formulas and traces.
The compiled monitor is held to these margins in tests/monitors/backends/test_margins.py.
"""

from __future__ import annotations

import math

from harness import make_trace
from hypothesis import given, settings
from hypothesis import strategies as st

from monitors.frontend.formalize import formalize
from monitors.frontend.parse import parse_requirement
from monitors.ir.formula import parse_formula, to_fret
from monitors.ir.spec import MARGIN_DELAY_TICKS, MARGIN_WINDOW_TICKS
from monitors.verify.interpret import verdicts
from monitors.verify.robustness import margins
from tests.monitors.backends.test_c99 import DEFINES, bool_f

INF = math.inf


def m(text: str, trace: list[dict], bool_margin: float = INF) -> list[float]:
    return margins(parse_formula(text), trace, bool_margin=bool_margin)


def xs(*values: float) -> list[dict]:
    return [{"x": v, "y": 1.0, "b": False, "n": 2} for v in values]


def test_relations_are_differences_in_the_inputs_units() -> None:
    trace = xs(1.0, 3.0, 4.5)
    assert m("x < 3.0", trace) == [2.0, 0.0, -1.5]  # 0: on the boundary, violated
    assert m("x <= 3.0", trace) == [2.0, 0.0, -1.5]  # 0: on the boundary, holds
    assert m("x > 3.0", trace) == [-2.0, 0.0, 1.5]
    assert m("x >= y", trace) == [0.0, 2.0, 3.5]
    assert m("x = 3.0", trace) == [-2.0, 0.0, -1.5]
    assert m("x != 3.0", trace) == [2.0, 0.0, 1.5]
    assert m("x + y < 2 * y", trace) == [0.0, -2.0, -3.5]  # both sides expressions
    # int64 against int64 and double: converted to double first
    assert m("n < 5", xs(0.0)) == [3.0]
    assert m("n >= x", xs(2.5)) == [-0.5]


def test_nan_and_infinities_never_give_a_nan_margin() -> None:
    trace = xs(math.nan, INF, -INF)
    # a NaN operand: the relation's boolean verdict as +-bool_margin
    assert m("x < 3.0", trace[:1]) == [-INF]
    assert m("x != 3.0", trace[:1], bool_margin=1.0) == [1.0]
    # two equal infinities are 0 apart; unequal ones infinitely
    assert m("x <= 1e999", trace[1:]) == [0.0, INF]
    assert m("x = (- 1e999)", trace[1:]) == [-INF, 0.0]


def test_connectives_take_min_max_and_negate() -> None:
    trace = xs(1.0, 4.0)
    assert m("(x < 3.0) & (x > 0.0)", trace) == [1.0, -1.0]
    assert m("(x < 3.0) | (x > 3.5)", trace) == [2.0, 0.5]
    assert m("! (x < 3.0)", trace) == [-2.0, 1.0]
    assert m("(x > 2.0) -> (x < 3.0)", trace) == [2.0, -1.0]
    assert m("(x > 2.0) <-> (x < 3.0)", trace) == [-1.0, -1.0]
    assert m("(x > 2.0) xor (x < 3.0)", trace) == [1.0, 1.0]


def test_boolean_atoms_are_plus_minus_bool_margin() -> None:
    trace = [{"b": True}, {"b": False}]
    assert m("b", trace) == [INF, -INF]
    assert m("b & TRUE", trace, bool_margin=1.0) == [1.0, -1.0]
    assert m("b = TRUE", trace, bool_margin=2.0) == [2.0, -2.0]  # booleans: an atom


def test_previous_tick_operators() -> None:
    trace = xs(1.0, 4.0, 2.0)
    assert m("Y (x < 3.0)", trace) == [-INF, 2.0, -1.0]  # false at tick 0, as Y is
    assert m("Z (x < 3.0)", trace, bool_margin=1.0) == [1.0, 2.0, -1.0]  # true there


def test_once_and_historically_take_running_and_window_extremes() -> None:
    trace = xs(1.0, 4.0, 2.0, 2.5, 0.0)
    assert m("H (x < 3.0)", trace) == [2.0, -1.0, -1.0, -1.0, -1.0]
    assert m("O (x > 3.0)", trace) == [-2.0, 1.0, 1.0, 1.0, 1.0]
    assert m("H[0,1] (x < 3.0)", trace) == [2.0, -1.0, -1.0, 0.5, 0.5]
    assert m("O[1,2] (x > 3.0)", trace) == [-INF, -2.0, 1.0, 1.0, -0.5]  # tick 0: empty
    assert m("H[2,inf] (x < 3.0)", trace) == [INF, INF, 2.0, -1.0, -1.0]
    assert m("O[3,2] (x > 3.0)", trace, bool_margin=1.0) == [-1.0] * 5  # empty window


def test_since_is_max_over_candidates_of_min_along_the_way() -> None:
    b = [False, True, False, False, False]
    trace = [{**row, "b": v} for row, v in zip(xs(5.0, 4.0, 3.0, 1.0, 2.5), b, strict=True)]
    # b at tick 1 is the one candidate; x > 2 must hold on every tick after it
    assert m("(x > 2.0) S b", trace) == [-INF, INF, 1.0, -1.0, -1.0]
    assert m("(x > 2.0) S[1,2] b", trace) == [-INF, -INF, 1.0, -1.0, -INF]
    assert m("(x > 2.0) S[2,inf] b", trace) == [-INF, -INF, -INF, -1.0, -1.0]
    # T is the dual, -(!a S !b): after tick 1, x > 2 once since then releases it
    assert m("(x > 2.0) T (! b)", trace) == [INF, -INF, 1.0, 1.0, 1.0]


def test_window_longer_than_the_limit_falls_back_to_its_verdict() -> None:
    w = MARGIN_WINDOW_TICKS
    trace = xs(*([1.0] * (w + 5)))
    assert set(m(f"H[0,{w + 1}] (x < 3.0)", trace, bool_margin=1.0)) == {1.0}
    assert set(m(f"H[0,{w}] (x < 3.0)", trace, bool_margin=1.0)) == {2.0}
    # only the long window falls back; the relation beside it keeps its margin
    assert m(f"(O[0,{w + 1}] (x > 5.0)) | (x < 4.0)", trace)[0] == 3.0
    # a lower bound only delays: kept up to MARGIN_DELAY_TICKS
    d = MARGIN_DELAY_TICKS
    ramp = xs(*[float(t) for t in range(d + 3)])
    assert m("O[40,41] (x > 5.0)", ramp)[38:43] == [-INF, -INF, -5.0, -4.0, -3.0]
    assert m(f"O[{d},{d}] (x > 5.0)", ramp, bool_margin=1.0)[d:] == [-5.0, -4.0, -3.0]
    # beyond it, the verdict: kept, tick d + 1 would be 0 - 0.5 and d + 2 1 - 0.5
    assert m(f"O[{d + 1},{d + 1}] (x > 0.5)", ramp, bool_margin=1.0)[d:] == [-1.0, -1.0, 1.0]


def test_srobot_uv_distance_requirement_through_freds_formalization() -> None:
    # The sRobot's red zone while the UV lamp is on (docs/reference/margins.md): FRET
    # wraps the condition in H and the scope in an implication.
    req = parse_requirement(
        "While !turnoffUVC sRobot shall always satisfy distance_to_target >= 3",
        file="<test>",
        line=1,
    )
    f = formalize(req, period_ms=10, file="<test>", line=1).formula
    assert to_fret(f) == "(H ((! turnoffUVC) -> (distance_to_target >= 3)))"
    uv_on = [True, True, True, True, True, True, False, True]
    distance = [9, 7, 5, 4, 3, 2, 2, 8]
    trace = [
        {"turnoffUVC": not on, "distance_to_target": d}
        for on, d in zip(uv_on, distance, strict=True)
    ]
    # margin = distance - 3 m while the lamp is on, the worst since the start (H):
    # 0 at exactly 3 m (still allowed), negative inside the red zone, and it stays
    # there until the requirement is reset, whatever the lamp or distance do then
    assert margins(f, trace) == [6.0, 4.0, 2.0, 1.0, 0.0, -1.0, -1.0, -1.0]
    assert verdicts(f, trace) == [True] * 5 + [False] * 3
    # lamp off from the start: no constraint, infinitely far from breaking
    assert margins(f, [{"turnoffUVC": True, "distance_to_target": 1}]) == [INF]


@settings(max_examples=300, deadline=None)
@given(
    f=bool_f(4, max_bound=40),
    seed=st.integers(0, 2**32),
    n=st.integers(1, 80),
    bool_margin=st.sampled_from([INF, 1.0, 0.5]),
)
def test_sign_of_the_margin_is_the_verdict(f, seed, n, bool_margin) -> None:
    trace = make_trace(seed, n)
    for row in trace:  # the strategies' defines, as the spec would expand them
        row["big"] = row["i0"] > 3
        row["rose"] = False
    got = margins(f, trace, bool_margin=bool_margin)
    for tick, (margin, holds) in enumerate(zip(got, verdicts(f, trace), strict=True)):
        assert margin == margin, (tick, "NaN margin")
        assert not (margin > 0 and not holds), (tick, margin, "positive margin, violated")
        assert not (margin < 0 and holds), (tick, margin, "negative margin, holds")
    assert DEFINES  # the strategies draw the defines' names as boolean variables
