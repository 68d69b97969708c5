"""Meaning-preserving simplification of formulas, for readable output.

FRET's construction yields e.g. ``p S (p & FTP)`` for "always p"; engineers
expect ``H p``.  Every rule here is valid in the past-time semantics of
``interpret.py`` and is property-tested against it (tests/monitors/ir/test_simplify.py).
"""

from __future__ import annotations

from monitors.ir.formula import (
    FALSE,
    FTP,
    TRUE,
    BinOp,
    Const,
    Formula,
    Not,
    Past,
    Pre,
    Since,
    map_children,
)


def simplify(f: Formula) -> Formula:
    """Bottom-up rewrite to a fixpoint of the local rules below."""
    while True:
        g = _rewrite(f)
        if g == f:
            return g
        f = g


def _rewrite(f: Formula) -> Formula:
    """Simplify the children, then apply the local rule for this node."""
    g = map_children(f, _rewrite)
    match g:
        case Not(a):
            return _not(a)
        case BinOp(op, a, b):
            return _bin(op, a, b)
        case Past(op, a, lo, hi):
            return _past(op, a, lo, hi)
        case Since(op, a, b, lo, hi):
            return _since(op, a, b, lo, hi)
        case Pre():
            # A previous value is state (its argument one tick late, init at tick 0):
            # folding it into its argument would drop that tick, so only its
            # children are simplified (above).
            return g
    return g


def _is_bool_const(f: Formula) -> bool:
    return isinstance(f, Const) and isinstance(f.value, bool)


def _not(a: Formula) -> Formula:
    if _is_bool_const(a):
        return Const(not a.value)  # type: ignore[union-attr]
    if isinstance(a, Not):
        return a.arg
    return Not(a)


def _bin(op: str, a: Formula, b: Formula) -> Formula:
    if op == "&":
        if a == TRUE:
            return b
        if b == TRUE:
            return a
        if FALSE in (a, b):
            return FALSE
        if a == b:
            return a
    elif op == "|":
        if a == FALSE:
            return b
        if b == FALSE:
            return a
        if TRUE in (a, b):
            return TRUE
        if a == b:
            return a
    elif op == "->":
        if a == TRUE:
            return b
        if a == FALSE or b == TRUE:
            return TRUE
        if b == FALSE:
            return _not(a)
    return BinOp(op, a, b)


def _past(op: str, a: Formula, lo: int | None, hi: int | None) -> Formula:
    untimed = hi is None and not lo
    if op == "Y" and a == FALSE:
        return FALSE
    if op == "Z" and a == TRUE:
        return TRUE
    if op == "H" and a == TRUE:
        return TRUE
    if op == "O" and a == FALSE:
        return FALSE
    if op == "O" and untimed and a == FTP:
        return TRUE  # tick 0 is always in the past
    if op in ("H", "O") and lo == 0 and hi == 0:
        return a
    return Past(op, a, lo, hi)


def _since(op: str, a: Formula, b: Formula, lo: int | None, hi: int | None) -> Formula:
    untimed = hi is None and not lo
    if op == "S" and untimed:
        if b == FALSE:
            return FALSE
        # a S (a & FTP): a held at tick 0 and ever since, i.e. H a
        if isinstance(b, BinOp) and b.op == "&" and FTP in (b.left, b.right):
            other = b.right if b.left == FTP else b.left
            if other == a:
                return Past("H", a)
        if b == FTP:
            # a S FTP: a at every tick after 0
            return Past("H", BinOp("|", FTP, a))
        if a == TRUE:
            return Past("O", b)
    return Since(op, a, b, lo, hi)
