"""Reference margins: the quantitative (robustness) semantics of past-time MTL.

Next to the boolean interpreter (interpret.py) and as direct: every window is a
min/max over the ticks it covers, no incremental state, so that it shares no
algorithm with the generated C (monitors/backends/c99.py), which it judges.

A margin is a signed double per tick, in the units of the formula's inputs
(docs/reference/margins.md):

- ``a < b``, ``a <= b``: b - a; ``a > b``, ``a >= b``: a - b; ``a = b``: -|a - b|;
  ``a != b``: |a - b|; both sides converted to double first (an int64 rounds to
  the nearest double, as C converts it).  Where the difference is NaN: 0 if the
  sides are equal (two equal infinities), else the relation's boolean margin (a
  NaN operand).  A relation of two booleans is a boolean atom;
- a boolean atom (variable, constant, ``ite`` of booleans): +bool_margin where it
  holds, -bool_margin where not;
- ``!`` negates, ``&`` min, ``|`` max, ``a -> b`` max(-a, b), ``a <-> b``
  min(max(-a, b), max(a, -b)), ``a xor b`` max(min(a, -b), min(-a, b));
- ``Y a``: a's margin at the previous tick, -bool_margin at tick 0 (false there);
  ``Z a`` likewise with +bool_margin;
- ``O[l,h] a``: max of a's margins over the window, ``H[l,h] a`` min; an empty
  window (tick < l) is -bool_margin for O, +bool_margin for H;
- ``a S[l,h] b``: max over j in the window of min(b at j, a at every k in (j, i]);
  -bool_margin when the window is empty; ``a T b`` is -(!a S !b);
- a window longer than MARGIN_WINDOW_TICKS (monitors/ir/spec.py) falls back: its
  margin is its boolean verdict's atom margin, as the C monitor computes it.

min(x, y) is ``y < x ? y : x`` and max(x, y) ``y > x ? y : x``, as in the C.
No margin is NaN.  Sign: margin > 0 => the formula holds at that tick, margin < 0
=> it is violated; 0 says neither (a boundary, or a fallen-back atom with
bool_margin 0).
"""

from __future__ import annotations

import math

from monitors.ir.formula import BOOL_OPS, REL_OPS, BinOp, Call, Const, Formula, Not, Past, Since
from monitors.ir.spec import margin_falls_back
from monitors.verify.interpret import Trace, Value, _window, evaluate_all


def _min(x: float, y: float) -> float:
    return y if y < x else x


def _max(x: float, y: float) -> float:
    return y if y > x else x


def relation_margin(op: str, x: Value, y: Value, holds: bool, bool_margin: float) -> float:
    """The margin of ``x op y`` between two numbers (see the module docstring)."""
    dx, dy = float(x), float(y)
    if op in ("<", "<="):
        d = dy - dx
    elif op in (">", ">="):
        d = dx - dy
    else:
        t = dx - dy
        if op == "=":
            d = t if t < 0 else -t
        else:
            d = -t if t < 0 else t
    if d == d:
        return d
    if dx == dy:
        return 0.0
    return bool_margin if holds else -bool_margin


def _is_bool(g: Formula, values: list[Value]) -> bool:
    match g:
        case Const(v):
            return isinstance(v, bool)
        case Not() | Past() | Since():
            return True
        case BinOp(op) if op in BOOL_OPS or op in REL_OPS:
            return True
    return bool(values) and isinstance(values[0], bool)


def margins(formula: Formula, trace: Trace, *, bool_margin: float = math.inf) -> list[float]:
    """The margin of ``formula`` (boolean) at every tick of ``trace``."""
    return margins_all(formula, trace, bool_margin=bool_margin)[formula]


def margins_all(
    formula: Formula, trace: Trace, *, bool_margin: float = math.inf
) -> dict[Formula, list[float]]:
    """The margin of every boolean subformula of ``formula`` reached through
    boolean operators, at every tick."""
    values = evaluate_all(formula, trace)
    n = len(trace)
    out: dict[Formula, list[float]] = {}
    bm = float(bool_margin)

    def atom(g: Formula) -> list[float]:
        return [bm if v else -bm for v in values[g]]

    def go(g: Formula) -> list[float]:
        got = out.get(g)
        if got is None:
            got = out[g] = _node(g)
        return got

    def _node(g: Formula) -> list[float]:
        match g:
            case Not(a):
                return [-x for x in go(a)]
            case BinOp(op, a, b) if op in BOOL_OPS:
                xs, ys = go(a), go(b)
                pairs = zip(xs, ys, strict=True)
                match op:
                    case "&":
                        return [_min(x, y) for x, y in pairs]
                    case "|":
                        return [_max(x, y) for x, y in pairs]
                    case "->":
                        return [_max(-x, y) for x, y in pairs]
                    case "<->":
                        return [_min(_max(-x, y), _max(x, -y)) for x, y in pairs]
                return [_max(_min(x, -y), _min(-x, y)) for x, y in pairs]  # xor
            case BinOp(op, a, b) if op in REL_OPS:
                xs, ys = values[a], values[b]
                if _is_bool(a, xs) and _is_bool(b, ys):
                    return atom(g)
                return [
                    relation_margin(op, x, y, bool(h), bm)
                    for x, y, h in zip(xs, ys, values[g], strict=True)
                ]
            case Past(_) | Since(_) if margin_falls_back(g):
                return atom(g)
            case Past("Y" | "Z" as op, a):
                xs = go(a)
                first = -bm if op == "Y" else bm
                return [first if i == 0 else xs[i - 1] for i in range(n)]
            case Past(op, a, lo, hi):
                xs = go(a) if op == "O" else [-x for x in go(a)]
                got = [_window_max(xs, i, lo, hi, -bm) for i in range(n)]
                return got if op == "O" else [-x for x in got]
            case Since(op, a, b, lo, hi):
                xs, ys = go(a), go(b)
                if op == "T":
                    xs, ys = [-x for x in xs], [-y for y in ys]
                got = [_since(xs, ys, i, lo, hi, -bm) for i in range(n)]
                return got if op == "S" else [-x for x in got]
            case Const() | Call():
                return atom(g)
        return atom(g)  # a boolean variable

    go(formula)
    return out


def _window_max(xs: list[float], i: int, lo: int | None, hi: int | None, empty: float) -> float:
    best = -math.inf
    window = _window(i, lo, hi)
    if not window:
        return empty
    for j in window:
        best = _max(best, xs[j])
    return best


def _since(
    xs: list[float], ys: list[float], i: int, lo: int | None, hi: int | None, empty: float
) -> float:
    """max over j in the window of min(ys[j], min of xs over (j, i])."""
    window = _window(i, lo, hi)
    if not window:
        return empty
    best = -math.inf
    a_between = math.inf  # min of xs over (j, i]
    for j in range(i, window.start - 1, -1):
        if j in window:
            best = _max(best, _min(ys[j], a_between))
        a_between = _min(a_between, xs[j])
    return best
