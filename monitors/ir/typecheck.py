"""Type checking of formulas against declared variable types.

Catches what a C compiler would accept silently or what FRET never checks:
``classifier & halt`` (int used as a condition), ``halt + 1`` (bool in
arithmetic), an integer power with a non-constant exponent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_FUNCTIONS,
    ARITH_OPS,
    BOOL_OPS,
    INT_FUNCTIONS,
    REL_OPS,
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
    to_fret,
)


def _const_type(v: object) -> str:
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "int64"
    return "double"


def type_of(f: Formula, env: Mapping[str, str]) -> str:
    """The type of ``f`` ('bool', 'int64' or 'double'); raises UserError (no location:
    callers anchor it with ``.at``) naming the offending subterm."""
    match f:
        case Const(v):
            # Every backend and the analyses hold constants as int64 or IEEE double.
            if type(v) is int and not -(2**63) <= v < 2**63:
                raise UserError(f"integer constant {v} does not fit in int64")
            if isinstance(v, float) and not math.isfinite(v):
                raise UserError(f"number {v} is not finite (too large for a double)")
            return _const_type(v)
        case Var(name):
            if name not in env:
                raise UserError(f"unknown variable '{name}'")
            return env[name]
        case Not(a):
            _expect(a, env, "bool", "'!' needs a boolean")
            return "bool"
        case Neg(a):
            t = type_of(a, env)
            if t == "bool":
                raise UserError(f"unary '-' needs a number, but {to_fret(a)} is bool")
            return t
        case Past(op, a, _, _):
            _expect(a, env, "bool", f"temporal operator {op} needs a boolean")
            return "bool"
        case Since(op, a, b, _, _):
            _expect(a, env, "bool", f"temporal operator {op} needs booleans")
            _expect(b, env, "bool", f"temporal operator {op} needs booleans")
            return "bool"
        case BinOp(op, a, b) if op in BOOL_OPS:
            _expect(a, env, "bool", f"'{op}' needs booleans")
            _expect(b, env, "bool", f"'{op}' needs booleans")
            return "bool"
        case BinOp(op, a, b) if op in REL_OPS:
            ta, tb = type_of(a, env), type_of(b, env)
            if (ta == "bool") != (tb == "bool"):
                raise UserError(f"cannot compare {to_fret(a)} ({ta}) with {to_fret(b)} ({tb})")
            if ta == "bool" and op not in ("=", "!="):
                raise UserError(f"'{op}' needs numbers, but {to_fret(a)} is bool")
            return "bool"
        case BinOp(op, a, b) if op in ARITH_OPS:
            ta, tb = type_of(a, env), type_of(b, env)
            for side, t in ((a, ta), (b, tb)):
                if t == "bool":
                    raise UserError(f"'{op}' needs numbers, but {to_fret(side)} is bool")
            result = "double" if "double" in (ta, tb) else "int64"
            if op == "^" and result == "int64":
                if not (isinstance(b, Const) and isinstance(b.value, int) and 0 <= b.value <= 63):
                    raise UserError(
                        f"integer power needs a constant exponent from 0 to 63, got {to_fret(b)}",
                        hint="use a real base (e.g. 2.0 ^ n) for a variable exponent",
                    )
            return result
        case Call("ite", (c, a, b)):
            _expect(c, env, "bool", "ite's condition must be boolean")
            ta, tb = type_of(a, env), type_of(b, env)
            if (ta == "bool") != (tb == "bool"):
                raise UserError(
                    f"ite's branches {to_fret(a)} ({ta}) and {to_fret(b)} ({tb}) differ"
                )
            return "bool" if ta == "bool" else "double" if "double" in (ta, tb) else "int64"
        case Pre(name, init, a):
            return _pre_type(name, init, a, env)
        case Call(name, args) if name not in ARITH_FUNCTIONS:
            # The parsers keep calls of any name, as FRET passes them on; the config
            # stage expands the user's functions before typing, so one that is
            # left here was never declared (docs/reference/config.md, "functions").
            raise UserError(
                f"function {name}/{len(args)} is not defined",
                hint="declare it under 'functions:' in the config (docs/reference/config.md)",
            )
        case Call(name, args):
            types = [type_of(a, env) for a in args]
            for a, t in zip(args, types, strict=True):
                if t == "bool":
                    raise UserError(f"{name} needs numbers, but {to_fret(a)} is bool")
            if name in INT_FUNCTIONS and all(t == "int64" for t in types):
                return "int64"
            return "double"
    raise UserError(f"cannot type {f!r}")


def _pre_type(name: str, init: Formula, a: Formula, env: Mapping[str, str]) -> str:
    """FRET's preInt/preReal (docs/reference/fretish.md, "Functions"): the previous
    value has the function's type; preReal converts an int64, as arithmetic does,
    while preInt takes int64 only (a double would need a rounding nobody asked for)."""
    for x in (init, a):
        t = type_of(x, env)
        if t == "bool":
            raise UserError(
                f"{name} needs a number, but {to_fret(x)} is bool",
                hint="use preBool(init, p) for a condition's previous value",
            )
        if name == "preInt" and t != "int64":
            raise UserError(
                f"preInt needs int64 values, but {to_fret(x)} is {t}",
                hint="use preReal(init, x) for a real value",
            )
    return "int64" if name == "preInt" else "double"


def _expect(f: Formula, env: Mapping[str, str], want: str, why: str) -> None:
    t = type_of(f, env)
    if t != want:
        raise UserError(f"{why}, but {to_fret(f)} is {t}")


def check_bool(f: Formula, env: Mapping[str, str], what: str = "requirement") -> None:
    t = type_of(f, env)
    if t != "bool":
        raise UserError(f"{what} must be a boolean condition, but {to_fret(f)} is {t}")
