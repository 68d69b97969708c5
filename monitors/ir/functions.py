"""User functions: names FRET passes through its formulas, defined by the config.

A function is a named expression over its parameters (``mag(x, y) =
sqrt(x * x + y * y)``).  Each call is replaced by the definition with the
arguments in place of the parameters, before typing, so a function is as hard
real-time as the expression it stands for, takes its types from its arguments,
and may use any operator a formula may, temporal ones included
(docs/reference/config.md, "functions").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_FUNCTIONS,
    FRET_FUNCTION_NAMES,
    FUTURE_FUNCTIONS,
    PRE_FUNCTIONS,
    Call,
    Formula,
    Var,
    map_children,
    subterms,
    to_fret,
    variables,
)

# Names a user function may not take: the functions every formula already has,
# and FRET's temporal ones, which the FRETISH reader expands itself.
BUILT_IN = frozenset(
    [*ARITH_FUNCTIONS, *FRET_FUNCTION_NAMES, *PRE_FUNCTIONS, *FUTURE_FUNCTIONS]
    + ["persisted", "occurred", "prevOcc", "preBool"]
)


@dataclass(frozen=True)
class Function:
    name: str
    params: tuple[str, ...]
    body: Formula

    def signature(self) -> str:
        return f"{self.name}({', '.join(self.params)})"


def user_calls(f: Formula) -> list[Call]:
    """Calls of functions that are not built in, in order of first appearance."""
    return [g for g in subterms(f) if isinstance(g, Call) and g.name not in ARITH_FUNCTIONS]


def undefined(f: Formula, functions: Mapping[str, Function]) -> list[str]:
    """``name/arity`` of each call in ``f`` that no function defines."""
    return list(
        dict.fromkeys(f"{c.name}/{len(c.args)}" for c in user_calls(f) if c.name not in functions)
    )


def check_definition(fn: Function, functions: Mapping[str, Function]) -> None:
    """The body reads only its parameters, calls only defined functions with their
    arity, and does not reach itself through other calls (expansion must end)."""
    stray = [n for n in variables(fn.body) if n not in fn.params]
    if stray:
        raise UserError(
            f"function {fn.signature()} reads '{stray[0]}', which is not one of its parameters",
            hint="a function sees only its arguments: add a parameter and pass the "
            "variable in the call",
        )
    missing = undefined(fn.body, functions)
    if missing:
        raise UserError(
            f"function {fn.signature()} calls {', '.join(missing)}, which is not defined",
            hint="in a definition, FRET's persisted, occurred, prevOcc and preBool are "
            "written as their formulas (docs/reference/fretish.md)"
            if any(m.split("/")[0] in BUILT_IN for m in missing)
            else None,
        )
    for c in user_calls(fn.body):
        _check_arity(c, functions[c.name])
    _no_cycle(fn, functions, [])


def _no_cycle(fn: Function, functions: Mapping[str, Function], path: list[str]) -> None:
    if fn.name in path:
        cycle = " -> ".join([*path[path.index(fn.name) :], fn.name])
        raise UserError(f"functions call each other in a cycle: {cycle}")
    for c in dict.fromkeys(c.name for c in user_calls(fn.body)):
        _no_cycle(functions[c], functions, [*path, fn.name])


def _check_arity(c: Call, fn: Function) -> None:
    if len(c.args) != len(fn.params):
        n = len(fn.params)
        raise UserError(
            f"{fn.signature()} takes {n} argument{'s' * (n != 1)}, but "
            f"{to_fret(c)} passes {len(c.args)}"
        )


def expand_functions(f: Formula, functions: Mapping[str, Function]) -> Formula:
    """``f`` with every user call replaced by its definition; an undefined function
    or a wrong number of arguments is a UserError naming every such call."""
    missing = undefined(f, functions)
    if missing:
        raise UserError(
            f"uses function{'s' * (len(missing) > 1)} {', '.join(missing)}, which "
            "the config does not define",
            hint="define it under 'functions:' (docs/reference/config.md)",
        )
    if not functions:
        return f

    def go(g: Formula) -> Formula:
        g = map_children(g, go)
        if isinstance(g, Call) and g.name in functions:
            fn = functions[g.name]
            _check_arity(g, fn)
            return go(_substitute(fn.body, dict(zip(fn.params, g.args, strict=True))))
        return g

    return go(f)


def _substitute(body: Formula, args: Mapping[str, Formula]) -> Formula:
    """The body with each parameter replaced at once (an argument is not substituted
    again, so a parameter named like a variable in an argument is harmless)."""

    def go(g: Formula) -> Formula:
        if isinstance(g, Var) and g.name in args:
            return args[g.name]
        return map_children(g, go)

    return go(body)
