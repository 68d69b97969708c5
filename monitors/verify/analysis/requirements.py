"""What is analysed: the requirements, their variables, and the trace length."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from monitors.frontend.formalize import interval_started
from monitors.frontend.parse import Requirement
from monitors.ir.formula import TRUE, BinOp, Const, Formula, O, Var, Y, and_, max_bound, not_
from monitors.ir.formula import H as H_

DEFAULT_TIMEOUT_S = 10.0  # seconds per solver call


@dataclass(frozen=True)
class VarInfo:
    name: str
    type: str  # bool | int64 | double
    role: str = "input"  # input | output
    range: tuple[float, float] | None = None


@dataclass(frozen=True)
class Req:
    """One requirement to analyse; its formula is over declared variables only
    (defines already expanded)."""

    id: str
    formula: Formula
    assumption: bool = False
    monotone: bool = True
    activation: Formula = TRUE  # when its scope and condition hold (vacuity)
    note: str | None = None  # the formalizer's non-monotone explanation
    text: str = ""


def activation(req: Requirement) -> Formula:
    """When ``req`` can be triggered: its scope is active and its condition holds.

    A requirement whose activation never holds constrains nothing (vacuous).
    Scopes (FRET's intervals): ``in M`` while M; ``not in M``/``only in M``
    (the constrained part is outside M) while !M; ``after M`` once M has first
    ended; ``before M`` until M first holds; ``only after M`` until M first ends
    (always from tick 0); ``only before M`` once M has held."""
    req = interval_started(req)  # persisted(...) in a condition or mode: FRET's $Left$
    act: Formula = TRUE
    if req.scope is not None:
        m = req.scope.mode
        left_m = and_(not_(m), Y(m))
        act = {
            "in": lambda: m,
            "notin": lambda: not_(m),
            "onlyIn": lambda: not_(m),
            "after": lambda: O(left_m),
            "before": lambda: H_(not_(m)),
            "onlyAfter": lambda: H_(not_(left_m)),
            "onlyBefore": lambda: O(m),
        }[req.scope.kind]()
    if req.condition is not None:
        act = and_(act, req.condition.expr)
    return act


def default_k(reqs: Iterable[Req]) -> int:
    """The largest time bound plus 2 (a window and the ticks on either side), at least 3."""
    return max([3] + [max_bound(r.formula) + 2 for r in reqs])


def range_formula(v: VarInfo) -> Formula | None:
    """``lo <= v <= hi`` (integer bounds rounded inward), None when ``v`` has no range."""
    if v.range is None or v.type == "bool":
        return None
    lo, hi = v.range
    if v.type == "int64":
        c_lo, c_hi = Const(math.ceil(lo)), Const(math.floor(hi))
    else:
        c_lo, c_hi = Const(float(lo)), Const(float(hi))
    return BinOp("&", BinOp(">=", Var(v.name), c_lo), BinOp("<=", Var(v.name), c_hi))
