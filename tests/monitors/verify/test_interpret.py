"""The reference interpreter against hand-computed verdicts and textbook identities."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from monitors.ir.formula import parse_formula
from monitors.verify.interpret import evaluate, verdicts, wrap64


def run(text, **cols):
    n = len(next(iter(cols.values())))
    trace = [{k: v[i] for k, v in cols.items()} for i in range(n)]
    return verdicts(parse_formula(text), trace)


def test_previous_and_weak_previous_at_tick_zero():
    assert run("Y p", p=[1, 1, 0]) == [False, True, True]
    assert run("Z p", p=[0, 0, 1]) == [True, False, False]
    assert run("Z FALSE", p=[0, 0, 0]) == [True, False, False]


def test_historically_latches_once_false():
    assert run("H p", p=[1, 0, 1, 1]) == [True, False, False, False]


def test_metric_once_window():
    # O[2,3] p: p held 2 or 3 ticks ago
    assert run("O[2,3] p", p=[1, 0, 0, 0, 0, 0]) == [False, False, True, True, False, False]


def test_since_needs_left_after_right():
    assert run("a S b", a=[0, 1, 1, 0, 1], b=[1, 0, 0, 0, 0]) == [True, True, True, False, False]


def test_bounded_since():
    # b at tick 0; a S[1,2] b holds at ticks 1,2 only
    assert run("a S[1,2] b", a=[1, 1, 1, 1], b=[1, 0, 0, 0]) == [False, True, True, False]


def test_within_formula_from_fret():
    # upon trigger within 2 ticks resp: trigger at 0, resp at 2 is fine, resp never is not
    f = "H ((O[2,2] ((trigger & (Z (! trigger))) & (! resp))) -> (O[0,1] ((Z FALSE) | resp)))"
    assert run(f, trigger=[1, 0, 0, 0], resp=[0, 0, 1, 0]) == [True] * 4
    assert run(f, trigger=[0, 1, 0, 0, 0], resp=[0, 0, 0, 0, 0]) == [True, True, True, False, False]


def test_int64_semantics():
    trace = [{"x": 2**63 - 1, "y": -7, "z": 0}]
    assert evaluate(parse_formula("x + 1"), trace) == [-(2**63)]
    assert evaluate(parse_formula("y / 2"), trace) == [-3]
    assert evaluate(parse_formula("y mod 2"), trace) == [-1]
    assert evaluate(parse_formula("y / z"), trace) == [0]
    assert wrap64(2**64 + 5) == 5


bits = st.lists(st.booleans(), min_size=1, max_size=40)


@settings(max_examples=200)
@given(st.data())
def test_textbook_identities(data):
    n = data.draw(st.integers(1, 40))
    col = lambda: data.draw(st.lists(st.booleans(), min_size=n, max_size=n))  # noqa: E731
    cols = {"a": col(), "b": col()}
    same = [
        ("a S b", "b | (a & Y (a S b))"),
        ("a T b", "! ((! a) S (! b))"),
        ("H a", "! (O (! a))"),
        ("O a", "TRUE S a"),
        ("O[1,3] a", "Y (O[0,2] a)"),
        ("H[0,2] a", "! (O[0,2] (! a))"),
        ("a S[0,2] b", "b | (a & Y b) | (a & Y (a & Y b))"),
        ("a S[1,2] b", "a & Y (b | (a & Y b))"),
        ("Z a", "! (Y (! a))"),
    ]
    for lhs, rhs in same:
        assert run(lhs, **cols) == run(rhs, **cols), (lhs, rhs, cols)


def test_int_real_and_bool_constants_stay_distinct():
    # 1, 1.0 and TRUE must not be merged as one subterm (integer vs real division)
    trace = [{"x": 1}]
    assert evaluate(parse_formula("(x / 2.0 = 0.5) & (x / 2 = 0)"), trace) == [True]


def test_functions_have_cs_results_where_python_raises():
    def at(text: str, **row: object) -> object:
        return evaluate(parse_formula(text), [row])[0]

    assert math.isnan(at("sqrt(x)", x=-1.0)) and math.isnan(at("log(x)", x=-1.0))
    assert at("log(x)", x=0.0) == -math.inf and at("exp(x)", x=1e6) == math.inf
    assert math.isnan(at("sin(x)", x=math.inf)) and math.isnan(at("asin(x)", x=2.0))
    assert at("floor(x)", x=-math.inf) == -math.inf and at("ceil(x)", x=-2.5) == -2.0
    assert at("abs(i)", i=-(2**63)) == -(2**63)  # wraps like int64 negation
    assert at("abs(x)", x=-0.0) == 0.0 and math.copysign(1, at("abs(x)", x=-0.0)) == 1
    # min(a, b) is b < a ? b : a, so a NaN in first place survives, in second it does not
    assert math.isnan(at("min(x, 1.0)", x=math.nan)) and at("min(1.0, x)", x=math.nan) == 1.0
    assert at("max(i, x)", i=3, x=1.0) == 3.0 and isinstance(at("max(i, 2)", i=3), int)
