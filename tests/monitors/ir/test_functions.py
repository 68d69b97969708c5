"""Functions in expressions: the arithmetic functions FRET passes through to its
formulas, read by the one expression grammar, typed, refused where a stage cannot
compute them exactly (docs/reference/fretish.md, "Functions")."""

from __future__ import annotations

import random

import pytest

from monitors.backends.copilot import generate_haskell
from monitors.errors import UserError
from monitors.frontend.parse import parse_requirement
from monitors.ir.formula import (
    ARITH_FUNCTIONS,
    BinOp,
    Call,
    Const,
    FormulaSyntaxError,
    Pre,
    Var,
    parse_formula,
)
from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl
from monitors.ir.typecheck import type_of
from monitors.verify.interpret import verdicts

ENV = {"i": "int64", "j": "int64", "x": "double", "b": "bool"}


@pytest.mark.parametrize(
    ("text", "want"),
    [
        ("abs(i)", "int64"),
        ("min(i, j)", "int64"),
        ("max(i, x)", "double"),  # an int64 argument is converted, as C converts it
        ("abs(x)", "double"),
        ("sqrt(i)", "double"),
        ("floor(x)", "double"),  # C's floor returns a double
        ("hypot(i, x)", "double"),  # the planar speed from two components
        ("sin(x) < 0.5", "bool"),
        ("ite(b, i, j)", "int64"),
        ("ite(b, i, x)", "double"),
        ("ite(i > 2, b, FALSE)", "bool"),
    ],
)
def test_function_types(text, want):
    assert type_of(parse_formula(text), ENV) == want


def test_ite_needs_a_boolean_condition_and_like_branches():
    with pytest.raises(UserError, match="ite's condition must be boolean"):
        type_of(parse_formula("ite(i, 1, 2) > 0"), ENV)
    with pytest.raises(UserError, match="branches b .bool. and i .int64. differ"):
        type_of(parse_formula("ite(b, b, i)"), ENV)


def test_a_boolean_argument_is_a_type_error():
    with pytest.raises(UserError, match="sqrt needs numbers, but b is bool"):
        type_of(parse_formula("sqrt(b) > 1.0"), ENV)


def test_arity_is_checked_and_other_functions_are_kept_in_formula_text():
    with pytest.raises(FormulaSyntaxError, match="min takes 2 arguments, not 1"):
        parse_formula("min(i) > 1")
    # FRET passes user functions through its formulas; the config defines them.
    assert parse_formula("foo(i) > 1") == BinOp(">", Call("foo", (Var("i"),)), Const(1))
    assert parse_formula("preInt(0, i)") == Pre("preInt", Const(0), Var("i"))
    with pytest.raises(FormulaSyntaxError, match="future-time predicates"):
        parse_formula("persists(3, b)")


def test_formula_text_prints_and_reads_back_every_function():
    for name, arity in ARITH_FUNCTIONS.items():
        f = Call(name, tuple(Var(f"v{k}") for k in range(arity)))
        assert parse_formula(str(f)) == f


def test_fretish_passes_functions_through_and_takes_abs_min_max_as_fret_s_typed_ones():
    req = parse_requirement("the sw shall always satisfy sqrt(x * x) <= abs_x")
    assert req.response == parse_formula("sqrt(x * x) <= abs_x")
    # FRET refuses abs, min and max in a sentence (NuSMV keywords) and takes absReal,
    # minReal, maxReal; here both are the same functions (docs/reference/fretish.md).
    for name, typed in (("abs", "absReal"), ("min", "minReal"), ("max", "maxReal")):
        args = "(x)" if name == "abs" else "(x, y)"
        ours = parse_requirement(f"the sw shall always satisfy {name}{args} < 1").response
        assert ours == parse_requirement(f"the sw shall always satisfy {typed}{args} < 1").response
        with pytest.raises(UserError, match=f"'{name}' is reserved"):
            parse_requirement(f"the sw shall always satisfy {name} < 1")


def test_copilot_backend_refuses_functions_clearly():
    spec = MonitorSpec(
        "t", (VarDecl("x", "double"),), (RequirementSpec("r", parse_formula("sqrt(x) > 1.0")),)
    )
    with pytest.raises(UserError, match="does not compile the function sqrt"):
        generate_haskell(spec)


def test_fret_typed_function_names_are_the_same_functions():
    assert parse_formula("absReal(x) < maxInt(i, j)") == parse_formula("abs(x) < max(i, j)")
    req = parse_requirement("the sw shall always satisfy minReal(x, 2.0) <= absInt(i)")
    assert req.response == parse_formula("min(x, 2.0) <= abs(i)")


# FRET's past-time expansion of preBool (fret-electron/support/xform.js).
FRET_PREBOOL = "((Z FALSE) & ({init})) | ((Y TRUE) & (Y ({p})))"


@pytest.mark.parametrize(("init", "p"), [("FALSE", "b"), ("TRUE", "b & c"), ("c", "! b")])
def test_prebool_equals_frets_formula_on_random_traces(init, p):
    mine = parse_requirement(f"the sw shall always satisfy preBool({init}, {p})").response
    fret = parse_formula(FRET_PREBOOL.format(init=init, p=p))
    rnd = random.Random(f"{init}{p}")
    for _ in range(50):
        trace = [{"b": rnd.random() < 0.5, "c": rnd.random() < 0.5} for _ in range(12)]
        assert verdicts(mine, trace) == verdicts(fret, trace)
    # and it is not the same as p now (the test can fail)
    trace = [{"b": True, "c": True}, {"b": False, "c": False}]
    assert verdicts(mine, trace) != verdicts(parse_formula(p), trace)
