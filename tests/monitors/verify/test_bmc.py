"""The z3 encoding (monitors/bmc.py) against the reference interpreter.

Random well-typed formulas over every operator and temporal bound, random traces
with int64/double edge values (tests/support/harness.py): with the trace fixed in z3,
every tick's truth value, and every numeric subterm's value bit for bit, must be
what monitors.verify.interpret computes.  Models found by z3 must read back as traces on
which the interpreter agrees.
"""

from __future__ import annotations

import math
import struct

import pytest
import z3
from harness import BOOLS, INTS, REALS, make_trace
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.ir.formula import (
    BinOp,
    Call,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Since,
    Var,
    parse_formula,
    subterms,
)
from monitors.verify.bmc import (
    Encoder,
    Unsupported,
    evaluate_z3,
    fresh_rows,
    model_trace,
    pure_invariant,
    py_value,
    tick_encoding,
    z3_value,
)
from monitors.verify.interpret import evaluate, verdicts

TYPES = {
    **dict.fromkeys(BOOLS, "bool"),
    **dict.fromkeys(INTS, "int64"),
    **dict.fromkeys(REALS, "double"),
}
SETTINGS = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
I64_MIN, I64_MAX = -(1 << 63), (1 << 63) - 1


# ------------------------------------------------------------------ generators (well typed)


def bounds(draw: st.DrawFn) -> tuple[int | None, int | None]:
    kind = draw(st.integers(0, 5))
    if kind < 2:
        return None, None
    lo = draw(st.integers(0, 5))
    if kind == 2:
        return lo, None
    return lo, lo + draw(st.integers(0, 5))


@st.composite
def num_f(draw: st.DrawFn, depth: int, real: bool, cheap: bool = False) -> Formula:
    """An int64 term, or (real) a term that may mix in doubles."""
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        if draw(st.integers(0, 2)) == 0:
            if real and draw(st.booleans()):
                # no -0.0: Formula equality merges it with 0.0 within one formula, and
                # so does the interpreter (test_negative_zero_constant_is_its_own_double)
                return Const(
                    draw(st.sampled_from([0.0, 0.5, 3.0, -2.5, 1e300, math.inf, math.nan]))
                )
            return Const(draw(st.sampled_from([0, 1, -1, 3, 7, I64_MIN, I64_MAX])))
        if real and draw(st.booleans()):
            return Var(draw(st.sampled_from(REALS)))
        return Var(draw(st.sampled_from(INTS)))
    k = draw(st.integers(0, 6))
    if k == 0:
        return Neg(draw(num_f(depth - 1, real, cheap)))
    if k == 1 and not real and not cheap:  # integer ^: constant exponent (real pow is refused)
        return BinOp("^", draw(num_f(depth - 1, False)), Const(draw(st.integers(0, 63))))
    if k == 3:  # FRET's if-then-else value
        cond = Var(draw(st.sampled_from(BOOLS)))
        return Call(
            "ite", (cond, draw(num_f(depth - 1, real, cheap)), draw(num_f(depth - 1, real, cheap)))
        )
    if k == 2:  # the functions z3 encodes exactly (the others are refused)
        name = draw(st.sampled_from(["abs", "min", "max"] + (["sqrt", "floor", "ceil"] * real)))
        arity = 2 if name in ("min", "max") else 1
        return Call(name, tuple(draw(num_f(depth - 1, real, cheap)) for _ in range(arity)))
    op = draw(st.sampled_from(["+", "-"] if cheap else ["+", "-", "*", "/", "mod"]))
    return BinOp(op, draw(num_f(depth - 1, real, cheap)), draw(num_f(depth - 1, real, cheap)))


@st.composite
def bool_f(draw: st.DrawFn, depth: int, reals: bool = True, cheap: bool = False) -> Formula:
    if depth <= 0 or draw(st.integers(0, 4)) == 0:
        k = draw(st.integers(0, 6))
        if k == 0:
            return Const(draw(st.booleans()))
        if k < 4:
            real = reals and draw(st.booleans())
            op = draw(st.sampled_from(["=", "!=", "<", "<=", ">", ">="]))
            return BinOp(op, draw(num_f(2, real, cheap)), draw(num_f(2, real, cheap)))
        return Var(draw(st.sampled_from(BOOLS)))
    k = draw(st.integers(0, 9))
    sub = bool_f(depth - 1, reals, cheap)
    if k == 0:
        return Not(draw(sub))
    if k < 3:
        op = draw(st.sampled_from(["&", "|", "xor", "->", "<->", "=", "!="]))
        return BinOp(op, draw(sub), draw(sub))
    if k < 7:
        op = draw(st.sampled_from(["Y", "Z", "H", "O"]))
        lo, hi = bounds(draw) if op in "HO" else (None, None)
        return Past(op, draw(sub), lo, hi)
    lo, hi = bounds(draw)
    return Since(draw(st.sampled_from(["S", "T"])), draw(sub), draw(sub), lo, hi)


def same_value(a: object, b: object) -> bool:
    """Equal as the C monitor would store them: doubles bit for bit (any NaN is NaN)."""
    if isinstance(a, float) or isinstance(b, float):
        if math.isnan(a) and math.isnan(b):
            return True
        return struct.pack("<d", a) == struct.pack("<d", b)
    return a == b and type(a) is type(b)


def z3_values(f: Formula, trace: list[dict], encoder: Encoder) -> list[object]:
    t = encoder.type_of(f)
    out = []
    for x in encoder.values(f):
        v = z3.simplify(x)
        out.append(py_value(t, v))
    return out


# ------------------------------------------------------------------ properties


@pytest.mark.slow
@SETTINGS
@given(f=bool_f(4), seed=st.integers(0, 2**32), n=st.integers(1, 14))
def test_encoding_agrees_with_interpreter_at_every_tick(f, seed, n):
    trace = make_trace(seed, n)
    assert evaluate_z3(f, trace, TYPES) == verdicts(f, trace), (str(f), trace)


@pytest.mark.slow
@SETTINGS
@given(f=bool_f(3), seed=st.integers(0, 2**32), n=st.integers(1, 6))
def test_every_subterm_value_agrees_bit_for_bit(f, seed, n):
    trace = make_trace(seed, n)
    rows = [{k: z3_value(TYPES[k], v) for k, v in row.items()} for row in trace]
    enc = Encoder(TYPES, rows)
    for g in subterms(f):
        want = evaluate(g, trace)
        want = [bool(w) if enc.type_of(g) == "bool" else w for w in want]
        got = z3_values(g, trace, enc)
        assert all(same_value(a, b) for a, b in zip(got, want, strict=True)), (str(g), got, want)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(f=bool_f(3, reals=False, cheap=True), n=st.integers(1, 6))
def test_models_read_back_as_traces_the_interpreter_agrees_with(f, n):
    # int64 + and - only: solving random double arithmetic or 64-bit products can
    # take z3 minutes (their values are checked above); doubles read back from
    # models are tested below on chosen formulas
    rows = fresh_rows(TYPES, TYPES, n)
    holds = Encoder(TYPES, rows).holds(f)
    s = z3.Solver()
    s.set(timeout=2000)
    for want in (True, False):  # a trace where f holds at the last tick, and one where not
        r = s.check(holds[-1] == z3.BoolVal(want))
        if r != z3.sat:
            continue
        trace = model_trace(s.model(), rows, TYPES)
        assert verdicts(f, trace)[-1] is want, (str(f), trace)


@pytest.mark.parametrize(
    "text",
    [
        "d0 mod 2.0 = -1.0 & d1 < d0",
        "d0 > 0.0 & d0 < 1e-310",  # a subnormal
        "d0 != d0 & d1 = -0.0 & 1.0 / d1 < 0.0",  # NaN and a negative zero
        "i0 = d0 & d0 > 9e18",  # exact int64/double equality near 2^63
        "d0 + 1.0 = d0 & d0 < 1e300",  # absorbed by rounding
    ],
)
def test_double_models_read_back_exactly(text):
    f = parse_formula(text)
    rows = fresh_rows(TYPES, TYPES, 1)
    s = z3.Solver()
    s.add(Encoder(TYPES, rows).holds(f)[0])
    assert s.check() == z3.sat
    trace = model_trace(s.model(), rows, TYPES)
    assert verdicts(f, trace) == [True], trace


# ------------------------------------------------------------------ edge cases by hand


@pytest.mark.parametrize(
    ("text", "row"),
    [
        ("i0 < d0", {"i0": I64_MAX, "d0": 2.0**63}),  # 2^63 is above every int64
        ("i0 = d0", {"i0": 2**53 + 1, "d0": 2.0**53}),  # exact, not after rounding
        ("i0 > d0", {"i0": 2**53 + 1, "d0": 2.0**53}),
        ("i0 = d0", {"i0": I64_MIN, "d0": -(2.0**63)}),
        ("i0 != d0", {"i0": 0, "d0": math.nan}),
        ("i0 <= d0", {"i0": 0, "d0": math.nan}),
        ("d0 mod 2.0 = -1.0", {"d0": -7.0}),  # fmod: sign of the dividend
        ("d0 mod -2.5 = 0.5", {"d0": 3.0}),
        ("d0 mod 2.0 != d0 mod 2.0", {"d0": math.inf}),  # NaN
        ("i0 / 0 = 0 & i0 mod 0 = 0", {"i0": 5}),
        ("i0 / -1 = i0", {"i0": I64_MIN}),  # wraps, as in C on two's complement
        ("-7 / 2 = -3 & -7 mod 2 = -1", {}),
        ("i0 ^ 63 = i0 * i0 ^ 62", {"i0": 3}),
        ("d0 / 0.0 > 1e308", {"d0": 1.0}),
        ("-0.0 = 0.0", {}),
        ("abs(i0) = i0", {"i0": I64_MIN}),  # wraps, as the C monitor's abs does
        ("min(d0, 1.0) != min(d0, 1.0)", {"d0": math.nan}),  # b < a ? b : a keeps a NaN
        ("max(1.0, d0) = 1.0", {"d0": math.nan}),
        ("sqrt(d0) != sqrt(d0)", {"d0": -1.0}),
        ("floor(d0) = -3.0 & ceil(d0) = -2.0", {"d0": -2.5}),
        ("max(i0, d0) = 3.0", {"i0": 3, "d0": 1.0}),
        ("ite(i0 > 2, i0, d0) = 3.0", {"i0": 3, "d0": 1.0}),  # the int64 branch as a double
        ("ite(i0 > 2, d0 > 0.0, FALSE)", {"i0": 3, "d0": 1.0}),
    ],
)
def test_value_semantics_edges(text, row):
    f = parse_formula(text)
    trace = [{"i0": 0, "d0": 0.0, **row}]
    assert evaluate_z3(f, trace, TYPES) == verdicts(f, trace)


def test_negative_zero_constant_is_its_own_double():
    # the encoder's cache must not hand -0.0 the encoding of an earlier 0.0
    enc = Encoder(TYPES, [{}])
    assert z3.is_true(z3.simplify(enc.holds(parse_formula("1.0 / 0.0 > 0.0"))[0]))
    assert z3.is_true(z3.simplify(enc.holds(parse_formula("1.0 / -0.0 < 0.0"))[0]))


def test_py_value_reads_subnormals_signed_zero_and_nan():
    for x in (5e-324, -5e-324, -0.0, 1.5, -math.inf, 2.0**-1070):
        assert same_value(py_value("double", z3.simplify(z3_value("double", x))), x)
    assert math.isnan(py_value("double", z3.simplify(z3_value("double", math.nan))))
    assert py_value("int64", z3.simplify(z3_value("int64", I64_MIN))) == I64_MIN


def test_real_power_is_refused_not_approximated():
    with pytest.raises(Unsupported, match="pow"):
        evaluate_z3(parse_formula("d0 ^ 2.0 > 1.0"), [{"d0": 3.0}], TYPES)
    with pytest.raises(Unsupported, match="int64"):
        evaluate_z3(parse_formula("i0 < 99999999999999999999"), [{"i0": 1}], TYPES)


@pytest.mark.parametrize("fn", ["exp", "log", "sin", "cos", "tan", "asin", "acos", "atan"])
def test_libm_functions_are_refused_not_approximated(fn):
    with pytest.raises(Unsupported, match=fn):
        evaluate_z3(parse_formula(f"{fn}(d0) > 0.5"), [{"d0": 3.0}], TYPES)


def test_pure_invariants_and_the_per_tick_encoding():
    assert pure_invariant(parse_formula("H (b0 -> i0 > 3)")) == parse_formula("b0 -> i0 > 3")
    for text in ("H (Y b0)", "H[0,3] b0", "O b0", "b0", "H[1,inf] b0"):
        assert pure_invariant(parse_formula(text)) is None, text
    row = fresh_rows(TYPES, TYPES, 1)[0]
    s = z3.Solver()
    s.add(tick_encoding(TYPES, parse_formula("b0 & i0 > 3"), row))
    assert s.check() == z3.sat and s.model().eval(row["i0"]).as_signed_long() > 3
    with pytest.raises(Unsupported, match="temporal"):
        tick_encoding(TYPES, parse_formula("Y b0"), row)
