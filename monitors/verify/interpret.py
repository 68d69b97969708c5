"""Reference interpreter: the judge of every compiled monitor.

Written from the textbook semantics of past-time metric LTL over a finite
trace, evaluated at every tick i (the formula "holds at i" looks only at ticks
0..i).  It is deliberately direct (quantifiers over windows, no incremental
state) so that it shares no algorithm with the generated C.

Value semantics shared with the C backend (documented in the README):
- int is int64 with wrap-around on overflow;
- integer ``/`` truncates toward zero and ``mod`` takes the sign of the
  dividend (C99); division or mod by zero gives 0;
- real is IEEE double (x / 0.0 is inf or nan, comparisons with nan are false);
- ``^`` on ints needs a constant exponent 0..63; on reals it is C's pow();
- ``ite(c, a, b)``: a where c holds, else b (double if either branch is);
- ``preInt(init, x)`` / ``preReal(init, x)`` (FRET's ``init -> pre x``): init's
  value at tick 0, x's value at tick i - 1 afterwards, as an int64 / a double (an
  int64 converted as C converts it); counted from the trace's start, so a fresh
  trace (a reset) is at tick 0 again;
- functions: abs, min, max on int64s stay int64 (abs wraps INT64_MIN to itself),
  otherwise the arguments are converted to double; ``min(a, b)`` is
  ``b < a ? b : a`` and ``max(a, b)`` is ``b > a ? b : a`` (so NaN handling is
  C's ternary, not fmin); the others are C's <math.h> functions, with C's results
  where Python's math raises (NaN for a domain error, +-inf for a pole or overflow).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
from collections.abc import Mapping, Sequence
from typing import Any

from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_FUNCTIONS,
    INT_FUNCTIONS,
    BinOp,
    Call,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Pre,
    Since,
    Var,
    subterms,
)

Value = bool | int | float
Trace = Sequence[Mapping[str, Value]]

_I64 = 1 << 64


def wrap64(x: int) -> int:
    """Two's-complement wrap to int64."""
    x &= _I64 - 1
    return x - _I64 if x >= 1 << 63 else x


def _int_div(a: int, b: int) -> int:
    if b == 0:
        return 0
    q = abs(a) // abs(b)
    return wrap64(q if (a >= 0) == (b >= 0) else -q)


def _int_mod(a: int, b: int) -> int:
    if b == 0:
        return 0
    return wrap64(a - _int_div(a, b) * b)


def _real_div(a: float, b: float) -> float:
    if b == 0:
        if a == 0 or math.isnan(a):
            return math.nan
        return math.copysign(math.inf, a) * math.copysign(1.0, b)
    return a / b


def _arith(op: str, a: Value, b: Value) -> Value:
    real = isinstance(a, float) or isinstance(b, float)
    if real:
        a, b = float(a), float(b)
        match op:
            case "+":
                return a + b
            case "-":
                return a - b
            case "*":
                return a * b
            case "/":
                return _real_div(a, b)
            case "mod":
                # C's fmod: NaN for an infinite dividend or a zero divisor
                return math.fmod(a, b) if b != 0 and math.isfinite(a) else math.nan
            case "^":
                try:
                    return math.pow(a, b)
                except (OverflowError, ValueError):
                    return math.inf if a > 0 else math.nan
    a, b = int(a), int(b)
    match op:
        case "+":
            return wrap64(a + b)
        case "-":
            return wrap64(a - b)
        case "*":
            return wrap64(a * b)
        case "/":
            return _int_div(a, b)
        case "mod":
            return _int_mod(a, b)
        case "^":
            if not 0 <= b <= 63:
                raise ValueError("integer ^ needs an exponent from 0 to 63")
            return wrap64(a**b)
    raise ValueError(f"unknown operator {op}")


_MATH = {
    "sqrt": math.sqrt, "exp": math.exp, "log": math.log, "sin": math.sin, "cos": math.cos,
    "tan": math.tan, "asin": math.asin, "acos": math.acos, "atan": math.atan,
    # C's floor/ceil keep x's sign on a zero result (ceil(-0.5) is -0.0); Python's int does not
    "floor": lambda x: math.copysign(math.floor(x), x),
    "ceil": lambda x: math.copysign(math.ceil(x), x),
}  # fmt: skip


def _libm_hypot(x: float, y: float) -> float:
    """C's hypot itself: Python's math.hypot has an algorithm of its own, which may
    differ from libm's in the last bit, and the C monitor calls libm's."""
    global _HYPOT
    if _HYPOT is None:
        libm = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")
        _HYPOT = libm.hypot
        _HYPOT.restype, _HYPOT.argtypes = ctypes.c_double, [ctypes.c_double, ctypes.c_double]
    return float(_HYPOT(x, y))


_HYPOT: Any = None


def _c_math(name: str, x: float) -> float:
    """C's double function ``name`` at ``x``: Python's math calls the same libm but
    raises where C returns a special value."""
    if math.isnan(x):
        return x
    if name in ("floor", "ceil") and math.isinf(x):
        return x
    try:
        return _MATH[name](x)
    except OverflowError:
        return math.inf  # exp overflows to +inf
    except ValueError:
        if name == "log" and x == 0:
            return -math.inf  # pole
        return math.nan  # domain error: sqrt(-1), log(-1), asin(2), sin(inf)


def call(name: str, args: Sequence[Value]) -> Value:
    """Value of the arithmetic function ``name`` (see the module docstring)."""
    if name not in ARITH_FUNCTIONS:
        # the config expands user functions before anything is evaluated (as typing
        # refuses them, monitors/ir/typecheck.py); say so instead of a KeyError
        raise UserError(f"function {name}/{len(args)} is not defined")
    if name == "ite":
        c, a, b = args
        x = a if c else b
        if isinstance(a, float) or isinstance(b, float):
            return float(x)
        if isinstance(a, bool) and isinstance(b, bool):
            return x
        return int(x)  # a bool beside an int64 counts as 0/1, as in the C monitor
    if name in INT_FUNCTIONS and not any(isinstance(a, float) for a in args):
        xs = [int(a) for a in args]
        if name == "abs":
            return wrap64(abs(xs[0]))
        a, b = xs
        return (b if b < a else a) if name == "min" else (b if b > a else a)
    ys = [float(a) for a in args]
    if name == "hypot":
        return _libm_hypot(ys[0], ys[1])
    if name == "abs":
        return math.fabs(ys[0])
    if name in ("min", "max"):
        a, b = ys
        return (b if b < a else a) if name == "min" else (b if b > a else a)
    return _c_math(name, ys[0])


def _rel(op: str, a: Value, b: Value) -> bool:
    match op:
        case "=":
            return a == b
        case "!=":
            return a != b
        case "<":
            return a < b
        case "<=":
            return a <= b
        case ">":
            return a > b
        case ">=":
            return a >= b
    raise ValueError(f"unknown relation {op}")


def _bool(op: str, a: bool, b: bool) -> bool:
    match op:
        case "&":
            return a and b
        case "|":
            return a or b
        case "xor":
            return a != b
        case "->":
            return (not a) or b
        case "<->":
            return a == b
    raise ValueError(f"unknown connective {op}")


def _window(i: int, lo: int | None, hi: int | None) -> range:
    """Ticks j with lo <= i - j <= hi and j >= 0 (hi None: unbounded)."""
    first = 0 if hi is None else max(0, i - hi)
    last = i - (lo or 0)
    return range(first, last + 1)


def evaluate(formula: Formula, trace: Trace) -> list[Value]:
    """Value of ``formula`` at every tick of ``trace``."""
    return evaluate_all(formula, trace)[formula]


def evaluate_all(formula: Formula, trace: Trace) -> dict[Formula, list[Value]]:
    """Value of every subformula at every tick of ``trace`` (monitors/verify/why.py
    reads the reason for a verdict from it)."""
    n = len(trace)
    table: dict[Formula, list[Value]] = {}
    for g in subterms(formula):
        table[g] = _eval_node(g, trace, table, n)
    return table


def verdicts(formula: Formula, trace: Trace) -> list[bool]:
    """True at each tick where the formula holds (the monitor is silent)."""
    return [bool(v) for v in evaluate(formula, trace)]


def _eval_node(g: Formula, trace: Trace, t: dict[Formula, list[Value]], n: int) -> list[Value]:
    match g:
        case Const(v):
            return [v] * n
        case Var(name):
            return [row[name] for row in trace]
        case Not(a):
            return [not x for x in t[a]]
        case Neg(a):
            return [(-x if isinstance(x, float) else wrap64(-x)) for x in t[a]]
        case BinOp(op, a, b):
            xs, ys = t[a], t[b]
            if op in ("&", "|", "xor", "->", "<->"):
                return [_bool(op, bool(x), bool(y)) for x, y in zip(xs, ys, strict=True)]
            if op in ("=", "!=", "<", "<=", ">", ">="):
                return [_rel(op, x, y) for x, y in zip(xs, ys, strict=True)]
            return [_arith(op, x, y) for x, y in zip(xs, ys, strict=True)]
        case Call(name, args):
            columns = [t[a] for a in args]
            return [call(name, row) for row in zip(*columns, strict=True)]
        case Pre(name, init, a):
            # init is read at tick 0 only (Lustre's init -> pre x)
            conv = int if name == "preInt" else float
            xs, first = t[a], t[init]
            return [conv(first[0] if i == 0 else xs[i - 1]) for i in range(n)]
        case Past("Y", a):
            xs = t[a]
            return [i > 0 and bool(xs[i - 1]) for i in range(n)]
        case Past("Z", a):
            xs = t[a]
            return [i == 0 or bool(xs[i - 1]) for i in range(n)]
        case Past("O", a, lo, hi):
            xs = t[a]
            return [any(xs[j] for j in _window(i, lo, hi)) for i in range(n)]
        case Past("H", a, lo, hi):
            xs = t[a]
            return [all(xs[j] for j in _window(i, lo, hi)) for i in range(n)]
        case Since(op, a, b, lo, hi):
            xs, ys = t[a], t[b]
            return [_since(op == "S", xs, ys, i, lo, hi) for i in range(n)]
    raise TypeError(f"cannot evaluate {g!r}")


def _since(
    strong: bool, xs: list[Value], ys: list[Value], i: int, lo: int | None, hi: int | None
) -> bool:
    """a S b: some j in the window has b(j) and a holds at every k in (j, i].
    a T b: every j in the window has b(j) or a holds at some k in (j, i].
    Scans j from i down, tracking whether a held (S) / occurred (T) on (j, i]."""
    window = _window(i, lo, hi)
    a_between = True if strong else False
    for j in range(i, -1, -1):
        if j in window:
            if strong and ys[j] and a_between:
                return True
            if not strong and not ys[j] and not a_between:
                return False
        if j < window.start:
            break
        a_between = (a_between and bool(xs[j])) if strong else (a_between or bool(xs[j]))
    return not strong
