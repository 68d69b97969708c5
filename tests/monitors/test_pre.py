"""FRET's ``preInt(init, x)`` and ``preReal(init, x)`` (Lustre's ``init -> pre x``):
x's value at the previous tick, init's value at the first tick, through every stage:
parsing and printing, typing, the reference interpreter, the native C monitor (judged
against the interpreter on random traces), z3 and Copilot
(docs/reference/fretish.md, "Functions")."""

from __future__ import annotations

import math

import pytest
from harness import INPUTS, make_trace, oracle, run  # noqa: E402
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.backends.c99 import generate, state_bytes
from monitors.backends.copilot import build_copilot_monitor, generate_haskell, require_copilot
from monitors.backends.load import compile_spec
from monitors.errors import UserError
from monitors.frontend.formalize import formalize
from monitors.frontend.parse import parse_requirement
from monitors.ir.formula import (
    BinOp,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Pre,
    Since,
    Var,
    parse_formula,
    subterms,
    to_fret,
)
from monitors.ir.simplify import simplify
from monitors.ir.spec import Define, MonitorSpec, RequirementSpec, VarDecl
from monitors.ir.typecheck import type_of
from monitors.verify.analysis import Req, VarInfo, analyse
from monitors.verify.bmc import evaluate_z3, is_propositional
from monitors.verify.interpret import evaluate, verdicts

ENV = {"i": "int64", "j": "int64", "x": "double", "b": "bool"}
TYPES = {v.name: v.type for v in INPUTS}
# a define with a previous value: each requirement using it gets its own state
DEFINES = (Define("last", "int64", parse_formula("preInt(0, i0)")),)


def spec_of(formulas: list[Formula], defines: tuple[Define, ...] = DEFINES) -> MonitorSpec:
    reqs = tuple(RequirementSpec(f"R{k}", f) for k, f in enumerate(formulas))
    return MonitorSpec("pre", INPUTS, reqs, defines)


# ------------------------------------------------------------------ parse and print


@pytest.mark.parametrize(
    "text",
    [
        "preInt(0, i) < i",
        "preReal(0.0, x) >= x - 1.5",
        "preReal(i + 1, preReal(-2.5, x)) = x",
        "(preInt(j, i * 2) != 3) & preInt(1, preInt(2, j)) > -4",
    ],
)
def test_sentence_to_formula_text_and_back(text):
    response = parse_requirement(f"the sw shall always satisfy {text}").response
    assert any(isinstance(g, Pre) for g in subterms(response))
    assert parse_formula(to_fret(response)) == response
    assert parse_formula(text) == response


# ------------------------------------------------------------------ typing


def test_types():
    assert type_of(parse_formula("preInt(0, i)"), ENV) == "int64"
    assert type_of(parse_formula("preReal(0, i)"), ENV) == "double"  # int64 converted
    assert type_of(parse_formula("preReal(i, x)"), ENV) == "double"
    assert type_of(parse_formula("preReal(0.0, x) < preInt(j, i)"), ENV) == "bool"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("preInt(0, b) > 1", "preInt needs a number, but b is bool"),
        ("preReal(b, x) > 1.0", "preReal needs a number, but b is bool"),
        ("preInt(0.0, i) > 1", r"preInt needs int64 values, but 0\.0 is double"),
        ("preInt(0, x) > 1", "preInt needs int64 values, but x is double"),
        ("preInt(0, i)", "requirement must be a boolean condition"),
    ],
)
def test_type_errors_are_clear(text, message):
    from monitors.ir.typecheck import check_bool

    with pytest.raises(UserError, match=message):
        check_bool(parse_formula(text), ENV)


def test_an_undefined_function_is_a_user_error_with_a_hint():
    with pytest.raises(UserError, match=r"function foo/2 is not defined") as e:
        type_of(parse_formula("foo(i, x) > 1"), ENV)
    assert "functions:" in (e.value.hint or "")


# ------------------------------------------------------------------ interpreter


def test_interpreter_by_hand():
    trace = [{"i": 1, "x": 0.5}, {"i": 2, "x": -1.0}, {"i": 3, "x": math.nan}]
    assert evaluate(parse_formula("preInt(7, i)"), trace) == [7, 1, 2]
    vals = evaluate(parse_formula("preReal(0, i)"), trace)
    assert vals == [0.0, 1.0, 2.0] and all(isinstance(v, float) for v in vals)
    # init is an expression read at tick 0 only (FRET's init -> pre x)
    assert evaluate(parse_formula("preInt(i + 10, i)"), trace) == [11, 1, 2]
    # nested: two ticks late, and both inits at tick 0
    assert evaluate(parse_formula("preInt(5, preInt(6, i))"), trace) == [5, 6, 1]
    assert verdicts(parse_formula("preReal(0.0, x) < x"), trace) == [True, False, False]
    # a reset starts a fresh trace: tick 0 again, init again
    assert evaluate(parse_formula("preInt(7, i)"), trace[1:]) == [7, 2]
    assert evaluate(parse_formula("preInt(7, i)"), []) == []


def test_previous_value_is_not_the_value_now():
    # the test can fail: preReal(0.0, x) is not x
    f, g = parse_formula("preReal(0.0, x) < 1.5"), parse_formula("x < 1.5")
    trace = [{"x": 1.0}, {"x": 2.0}, {"x": 1.0}]
    assert verdicts(f, trace) == [True, True, False]
    assert verdicts(f, trace) != verdicts(g, trace)


def test_simplify_keeps_pre():
    f = parse_formula("(preInt(0, i) > 1) & TRUE")
    assert simplify(f) == parse_formula("preInt(0, i) > 1")
    assert simplify(parse_formula("preInt(0, i) = i")) == parse_formula("preInt(0, i) = i")
    inner = parse_formula("preReal(0.0, x) > 1.0 | FALSE")
    assert simplify(inner) == parse_formula("preReal(0.0, x) > 1.0")


def test_mode_scope_counts_from_the_trace_start():
    # as preBool: a previous value is the trace's previous tick in every scope (FRET)
    req = parse_requirement("in mode m sw shall always satisfy preInt(0, i) <= i")
    f = formalize(req).formula
    assert Pre("preInt", Const(0), Var("i")) in subterms(f)
    trace = [{"m": k in (2, 3), "i": [5, 4, 3, 9][k]} for k in range(4)]
    # at tick 2 (the mode's first tick) the previous value is tick 1's 4, not init 0
    assert verdicts(f, trace) == [True, True, False, False]


# ------------------------------------------------------------------ C against the interpreter

FIXED = [
    "preInt(7, i0) < i0",
    "preReal(0.0, d0) = d0",
    "preReal(i1, i0) >= d1",
    "Y (preInt(0, i0) = i1)",
    "H (preReal(d1, preReal(1.5, d0)) != d0)",
    "O[1,3] (preInt(i1 * 2, i0 + i1) > i0)",
    "(preReal(-0.0, d0 / d1) < 1.0) S b0",
    "last > 2",
    "(last = i0) | (preInt(3, last) < last)",
]


def check_c(tmp_path, formulas: list[Formula], seeds: range, n: int) -> None:
    spec = spec_of(formulas)
    mon = compile_spec(spec, tmp_path)
    for seed in seeds:
        trace = make_trace(seed, n)
        mon.reset()
        full = oracle(spec, trace)
        assert run(mon, spec, trace) == full, seed
        # reset mid-trace: tick 0 again (init), and one requirement reset alone
        k = n // 2
        mon.reset()
        run(mon, spec, trace[:k])
        mon.reset_requirement("R0")
        rest = oracle(spec, trace[k:])
        want = [rest[0]] + [w[k:] for w in full[1:]]
        assert run(mon, spec, trace[k:]) == want, seed


def test_c_matches_interpreter_on_fixed_formulas(tmp_path):
    check_c(tmp_path, [parse_formula(t) for t in FIXED], range(25), 60)


def test_c_state_and_reset(tmp_path):
    spec = spec_of([parse_formula("preInt(7, i0) = 7")], defines=())
    assert state_bytes(spec) == {"R0": 16}  # the int64 value and the first-tick flag
    c, _ = generate(spec)
    assert "int64_t f0;" in c and "bool f1;" in c
    mon = compile_spec(spec, tmp_path)
    row = {"b0": False, "b1": False, "b2": False, "i0": 1, "i1": 0, "d0": 0.0, "d1": 0.0}
    names = [v.name for v in spec.inputs]
    tick = lambda: mon.tick([row[n] for n in names])  # noqa: E731
    assert [tick(), tick()] == [b"\x00", b"\x01"]  # 7 at tick 0, then 1
    mon.reset()
    assert tick() == b"\x00"  # init again
    mon.reset_requirement("R0")
    assert tick() == b"\x00"


def test_a_define_with_pre_is_owned_by_each_requirement(tmp_path):
    # two requirements on the same define: resetting one must not reset the other's
    spec = spec_of([parse_formula("last = 0"), parse_formula("last = 0")])
    mon = compile_spec(spec, tmp_path)
    names = [v.name for v in spec.inputs]
    row = {"b0": False, "b1": False, "b2": False, "i0": 5, "i1": 0, "d0": 0.0, "d1": 0.0}
    assert mon.tick([row[n] for n in names]) == b"\x00\x00"
    mon.reset_requirement("R1")
    assert mon.tick([row[n] for n in names]) == b"\x01\x00"


# ---- random formulas with previous values, nested in relations and temporal operators

INT_CONSTS = [0, 1, -1, 3, 7, -(1 << 63), (1 << 63) - 1]
REAL_CONSTS = [0.5, -0.0, 3.0, -2.5, 1e300, math.inf, math.nan]


@st.composite
def int_f(draw: st.DrawFn, depth: int) -> Formula:
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        k = draw(st.integers(0, 3))
        if k == 0:
            return Const(draw(st.sampled_from(INT_CONSTS)))
        if k == 1:
            return Var("last")
        return Var(draw(st.sampled_from(["i0", "i1"])))
    k = draw(st.integers(0, 4))
    if k < 2:
        return Pre("preInt", draw(int_f(depth - 1)), draw(int_f(depth - 1)))
    if k == 2:
        return Neg(draw(int_f(depth - 1)))
    op = draw(st.sampled_from(["+", "-", "*", "/", "mod"]))
    return BinOp(op, draw(int_f(depth - 1)), draw(int_f(depth - 1)))


@st.composite
def real_f(draw: st.DrawFn, depth: int) -> Formula:
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        k = draw(st.integers(0, 3))
        if k == 0:
            return Const(draw(st.sampled_from(REAL_CONSTS)))
        if k == 1:
            return draw(int_f(1))  # an int64 converted to double
        return Var(draw(st.sampled_from(["d0", "d1"])))
    k = draw(st.integers(0, 3))
    if k < 2:
        return Pre("preReal", draw(real_f(depth - 1)), draw(real_f(depth - 1)))
    op = draw(st.sampled_from(["+", "-", "*", "/"]))
    return BinOp(op, draw(real_f(depth - 1)), draw(real_f(depth - 1)))


@st.composite
def bool_f(draw: st.DrawFn, depth: int) -> Formula:
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        op = draw(st.sampled_from(["=", "!=", "<", "<=", ">", ">="]))
        if draw(st.booleans()):
            return BinOp(op, draw(int_f(2)), draw(int_f(2)))
        return BinOp(op, draw(real_f(2)), draw(real_f(2)))
    k = draw(st.integers(0, 5))
    sub = bool_f(depth - 1)
    if k == 0:
        return Not(draw(sub))
    if k == 1:
        return BinOp(draw(st.sampled_from(["&", "|", "->"])), draw(sub), draw(sub))
    if k == 2:
        return Var(draw(st.sampled_from(["b0", "b1", "b2"])))
    if k < 5:
        op = draw(st.sampled_from(["Y", "Z", "H", "O"]))
        lo, hi = (None, None)
        if op in "HO" and draw(st.booleans()):
            lo = draw(st.integers(0, 3))
            hi = lo + draw(st.integers(0, 4))
        return Past(op, draw(sub), lo, hi)
    return Since(draw(st.sampled_from(["S", "T"])), draw(sub), draw(sub))


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(formulas=st.lists(bool_f(3), min_size=4, max_size=8), seed=st.integers(0, 2**32))
def test_compiled_monitor_matches_interpreter_on_random_pre_formulas(
    tmp_path_factory, formulas, seed
):
    check_c(tmp_path_factory.mktemp("pre"), formulas, range(seed, seed + 3), 80)


def test_mode_scope_sentence_compiles_to_the_interpreters_verdicts(tmp_path):
    inputs = (VarDecl("m", "bool"), VarDecl("i", "int64"), VarDecl("x", "double"))
    sentences = [
        "in mode m sw shall always satisfy preInt(0, i) <= i",
        "only in m mode sw shall always satisfy preReal(0.5, x) < x + 1.0",
        "in mode m upon preInt(0, i) > 3 sw shall within 2 ticks satisfy preReal(i, x) = x",
    ]
    formulas = [formalize(parse_requirement(s)).formula for s in sentences]
    spec = MonitorSpec(
        "m", inputs, tuple(RequirementSpec(f"R{k}", f) for k, f in enumerate(formulas))
    )
    mon = compile_spec(spec, tmp_path)
    for seed in range(10):
        rows = make_trace(seed, 60)
        trace = [{"m": r["b0"], "i": r["i0"] % 8, "x": r["d0"]} for r in rows]
        mon.reset()
        assert run(mon, spec, trace) == oracle(spec, trace), seed


# ------------------------------------------------------------------ z3 and analyses


@pytest.mark.parametrize("text", [*FIXED[:7], "preReal(1e300, d0 * d1) > preReal(0, i0)"])
def test_bmc_agrees_with_the_interpreter(text):
    f = parse_formula(text)
    assert not is_propositional(f)
    for seed in range(4):
        trace = make_trace(seed, 10)
        assert evaluate_z3(f, trace, TYPES) == verdicts(f, trace), seed


def test_analyses_run_on_previous_values():
    # every stage of check on a previous value, without a traceback; the solver
    # timeout keeps the realizability game (64-bit values, no Boolean arena: a
    # previous value is not a per-tick comparison) short
    vars_ = [VarInfo("x", "int64", "input", (0, 10)), VarInfo("y", "int64", "output", (0, 10))]
    reqs = [
        Req("up", parse_formula("H (preInt(0, y) <= y)")),
        Req("pos", parse_formula("H (y >= preInt(0, x))")),
    ]
    a = analyse(reqs, vars_, k=4, timeout_s=1)
    assert a.consistent


# ------------------------------------------------------------------ Copilot


def test_copilot_refuses_an_init_that_is_not_a_constant():
    spec = MonitorSpec(
        "t", (VarDecl("i", "int64"),), (RequirementSpec("r", parse_formula("preInt(i, i) > 1")),)
    )
    with pytest.raises(UserError, match="needs a constant initial value for preInt") as e:
        generate_haskell(spec)
    assert "--backend native" in (e.value.hint or "")
    nan = MonitorSpec(
        "t",
        (VarDecl("x", "double"),),
        (RequirementSpec("r", BinOp("<", Pre("preReal", Const(math.nan), Var("x")), Var("x"))),),
    )
    with pytest.raises(UserError, match="constant initial value"):
        generate_haskell(nan)


def test_copilot_writes_a_constant_init_as_a_typed_stream():
    spec = spec_of([parse_formula("preInt(-3, i0) < i0"), parse_formula("preReal(0, d0) > 1.0")])
    hs = generate_haskell(spec)
    assert "Stream Int64" in hs and "[(-3 :: Int64)] ++" in hs
    assert "Stream Double" in hs and "[(0.0 :: Double)] ++" in hs


@pytest.mark.ghc
def test_copilot_matches_interpreter(tmp_path):
    try:
        require_copilot()
    except UserError as e:
        pytest.skip(f"NASA Copilot is not installed ({e})")
    formulas = [
        parse_formula(t)
        for t in [*FIXED[:2], "preReal(-3, i0) >= d1", "H (preReal(2.5, preReal(1.5, d0)) != d0)"]
    ]
    spec = spec_of([*formulas, parse_formula("last > 2")])
    mon = build_copilot_monitor(spec, tmp_path)
    for seed in range(10):
        trace = make_trace(seed, 50)
        mon.reset()
        assert run(mon, spec, trace) == oracle(spec, trace), seed
