"""The Boolean abstraction of a realizability game (monitors/verify/analysis/arena.py)
with real z3: which comparisons become Booleans, on which side, what each tick may
choose, and the requirement sets it refuses (the game then runs on the values)."""

from __future__ import annotations

import re

import pytest
import z3

from monitors.ir.formula import parse_formula
from monitors.verify.analysis.arena import NoAbstraction, abstract_arena
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.requirements import Req, VarInfo

VARS = {
    "x": VarInfo("x", "int64", "input", (0, 100)),
    "b": VarInfo("b", "bool", "input"),
    "y": VarInfo("y", "int64", "output", (0, 10)),
    "q": VarInfo("q", "bool", "output"),
}


def context(*formulas: str) -> Context:
    reqs = [Req(f"r{i}", parse_formula(f)) for i, f in enumerate(formulas)]
    return Context(reqs, VARS, 2, 10.0)


def choices(arena_tick: z3.BoolRef, names: list[str], rows: dict[str, z3.ExprRef]) -> set:
    """Every combination of ``names`` the tick's constraint allows (all-SAT)."""
    s = z3.Solver()
    s.add(arena_tick)
    found = set()
    while s.check() == z3.sat:
        m = s.model()
        combo = tuple(z3.is_true(m.eval(rows[n], model_completion=True)) for n in names)
        found.add(combo)
        s.add(z3.Or([rows[n] != z3.BoolVal(v) for n, v in zip(names, combo, strict=True)]))
    return found


def test_comparisons_become_booleans_with_the_combinations_the_ranges_allow() -> None:
    ctx = context("H (x > 50 & x < 20 | b -> y = 3 | q)")
    arena = abstract_arena(ctx, ["x", "b"], ["y", "q"], ["r0"], "t_")
    assert arena.boolean
    assert arena.ins == ["b", "cmp0", "cmp1"]
    assert arena.outs == ["q", "cmp2"]
    assert set(arena.holds) == {"r0"}
    # x > 50 and x < 20 share x: never both true within 0..100
    assert choices(arena.env_tick[0], ["cmp0", "cmp1"], arena.rows[0]) == {
        (False, False),
        (True, False),
        (False, True),
    }
    assert choices(arena.out_tick[1], ["cmp2"], arena.rows[1]) == {(False,), (True,)}
    # a model of the arena gives concrete inputs that make its comparisons true
    s = z3.Solver()
    s.add(arena.env_tick[0], arena.rows[0]["cmp0"], arena.rows[0]["b"])
    assert s.check() == z3.sat
    row = arena.concretize(s.model(), 1)[0]
    assert set(row) == {"x", "b"}
    assert z3.is_true(row["b"]) and row["x"].as_long() > 50


@pytest.mark.parametrize(
    ("formula", "why"),
    [
        ("H (x > y -> q)", "(x > y) compares inputs with outputs"),
        ("H (preInt(0, x) > 3 -> q)", "compares a previous value (preInt/preReal)"),
    ],
)
def test_the_sets_it_cannot_abstract_are_refused_with_the_reason(formula: str, why: str) -> None:
    ctx = context(formula)
    with pytest.raises(NoAbstraction, match=re.escape(why)):
        abstract_arena(ctx, ["x", "b"], ["y", "q"], ["r0"], "t_")


def test_too_many_comparisons_sharing_variables_are_refused() -> None:
    many = " | ".join(f"x > {i}" for i in range(11))
    ctx = context(f"H ({many} -> q)")
    with pytest.raises(NoAbstraction, match="^11 comparisons share variables$"):
        abstract_arena(ctx, ["x", "b"], ["y", "q"], ["r0"], "t_")
