"""Requirement -> past-time metric LTL, semantically equal to FRET 3.0's ``pt``.

FRET builds every formula for an abstract interval [LEFT, RIGHT) chosen by
the scope, from a base form chosen by the timing (negated for the ``only``
scopes, which constrain the complement of the mode), and the condition's
trigger.  This module follows that construction (facts from FRET's
``formalizations_past.js``, checked against FRET's output on the examples in
``shared/data/fret-examples.jsonl``); the formulas are built with the AST, not
by string rewriting.

Differences from FRET, on purpose: durations with units are converted to ticks
with the step period (FRET ignores units), and non-integral tick counts are
refused instead of producing malformed bounds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from fractions import Fraction

from monitors.errors import UserError
from monitors.frontend.parse import BOUNDED, INTERVAL_START, Duration, Requirement
from monitors.ir.formula import (
    FALSE,
    FTP,
    TRUE,
    BinOp,
    Formula,
    H,
    Not,
    O,
    S,
    Var,
    Y,
    Z,
    and_,
    implies,
    map_children,
    not_,
    or_,
)
from monitors.ir.simplify import simplify

# Milliseconds per unit.
UNIT_MS = {
    "hour": Fraction(3_600_000),
    "minute": Fraction(60_000),
    "second": Fraction(1000),
    "millisecond": Fraction(1),
    "microsecond": Fraction(1, 1000),
}

# Timings whose base form is "false until something happens" (FRET's
# occursBy / end-of-interval forms), per polarity: (timing, negated).
_PENDING = {
    ("eventually", False),
    ("null", False),
    ("finally", False),
    ("finally", True),
    ("always", True),  # not always = eventually not
    ("never", True),  # not never = eventually
}


@dataclass(frozen=True)
class Formalization:
    formula: Formula
    monotone: bool
    note: str | None  # for non-monotone requirements: why, and how it is monitored


# ---------------------------------------------------------------- durations


def ticks(
    d: Duration, period_ms: float | None, *, file: str = "<input>", line: int | None = None
) -> int:
    """A duration in ticks; units other than ticks need the step period."""
    if d.amount < 0:
        raise UserError(f"negative duration {d}", file=file, line=line)
    if d.unit == "tick":
        if d.amount.denominator != 1:
            raise UserError(f"{d} is not a whole number of ticks", file=file, line=line)
        return int(d.amount)
    if period_ms is None:
        raise UserError(
            f"'{d}' needs the tick length to be converted to ticks",
            file=file,
            line=line,
            hint="set step.period_ms in the config, or write the duration in ticks",
        )
    period = Fraction(repr(float(period_ms)))
    if period <= 0:
        raise UserError(f"step period must be positive, not {period_ms} ms", file=file, line=line)
    total_ms = d.amount * UNIT_MS[d.unit]
    n = total_ms / period
    if n.denominator != 1:
        raise UserError(
            f"'{d}' is {float(n):g} ticks of {_ms(period)} ms, not a whole number",
            file=file,
            line=line,
            hint=f"a step period of {_suggest(total_ms, period)} would work",
        )
    return int(n)


def _ms(x: Fraction) -> str:
    return str(x.numerator) if x.denominator == 1 else f"{float(x):g}"


def _suggest(total_ms: Fraction, period: Fraction) -> str:
    """Periods that divide the duration: the closest one below the current
    period, and a round one (1-2-5 series) when it differs."""
    closest = total_ms / ((total_ms / period).__ceil__())
    out = [f"{_ms(closest)} ms"]
    for exp in range(6, -4, -1):
        for m in (5, 2, 1):
            p = Fraction(m) * Fraction(10) ** exp
            if p <= period and (total_ms / p).denominator == 1:
                if p != closest:
                    out.append(f"{_ms(p)} ms")
                return " or ".join(out)
    return out[0]


# ---------------------------------------------------------------- building blocks
# Names follow FRET's: persistsTo(f, start) is "f since (f and start)"
# (f has held since the interval/trigger start), occursBy its dual.


def _persists(f: Formula, start: Formula) -> Formula:
    return S(f, and_(f, start))


def _occurs_by(f: Formula, start: Formula) -> Formula:
    return not_(_persists(not_(f), start))


def _once(f: Formula, lo: int, hi: int) -> Formula:
    """O[lo,hi] f; an empty window (hi < lo, e.g. 'within 0 ticks') is FALSE."""
    if hi < lo:
        return FALSE
    return O(f, lo, hi)


class _Base:
    """Base forms for one interval start ``left`` and condition."""

    def __init__(self, left: Formula, cond: Formula | None, holding: bool) -> None:
        self.left = left
        self.cond = cond
        if cond is None:
            self.trig = left
        elif holding:
            self.trig = cond
        else:  # rising edge of the condition, or condition already true at the start
            self.trig = or_(and_(cond, Y(not_(cond))), and_(cond, left))

    def nci(self) -> Formula:
        """No trigger since the interval started (the obligation is vacuous)."""
        assert self.cond is not None
        return _persists(not_(self.cond), self.left)

    def immediately(self, p: Formula) -> Formula:
        return _persists(implies(self.trig, p), self.left)

    def next(self, p: Formula) -> Formula:
        if self.cond is None:
            return _persists(implies(Y(self.left), p), self.left)
        return _persists(implies(Y(self.trig), or_(p, self.left)), self.left)

    def always(self, p: Formula) -> Formula:
        if self.cond is None:
            return _persists(p, self.left)
        return _persists(or_(self.nci(), p), self.left)

    def eventually(self, p: Formula) -> Formula:
        if self.cond is None:
            return _occurs_by(p, self.left)
        return or_(self.nci(), _occurs_by(p, self.trig))

    def finally_(self, p: Formula) -> Formula:
        if self.cond is None:
            return p
        return or_(self.nci(), p)

    def until(self, p: Formula, stop: Formula) -> Formula:
        if self.cond is None:
            return _persists(implies(_persists(not_(stop), self.left), p), self.left)
        body = or_(self.nci(), implies(_persists(not_(stop), self.trig), p))
        return _persists(body, self.left)

    def before(self, p: Formula, stop: Formula) -> Formula:
        if self.cond is None:
            enforce = and_(not_(self.left), Y(_occurs_by(p, self.left)))
        else:
            enforce = or_(
                self.nci(),
                and_(not_(self.left), not_(self.trig), Y(_occurs_by(p, self.trig))),
            )
        return _persists(implies(stop, enforce), self.left)

    def throughout(self, p: Formula, n: int) -> Formula:
        near = _once(self.trig, 0, n)
        if self.cond is None:
            return _persists(implies(near, p), self.left)
        return _persists(implies(near, or_(self.nci(), p)), self.left)

    def within(self, p: Formula, n: int) -> Formula:
        if self.cond is None:
            body = implies(_persists(not_(p), self.left), _once(self.left, 0, n - 1))
        else:
            body = implies(
                _once(and_(self.trig, not_(p)), n, n), _once(or_(self.left, p), 0, n - 1)
            )
        return _persists(body, self.left)

    def after(self, p: Formula, n: int) -> Formula:
        return and_(self.throughout(not_(p), n), self.within(p, n + 1))

    def not_after(self, p: Formula, n: int) -> Formula:
        focus = _once(self.trig, n + 1, n + 1)
        if self.cond is None:
            ok = or_(_once(self.left, 0, n), not_(p), Y(_occurs_by(p, self.left)))
        else:
            ok = or_(_once(self.left, 0, n), not_(p), Y(_once(p, 0, n)))
        return _persists(implies(focus, ok), self.left)

    def form(self, timing: str, negate: bool, p: Formula, stop: Formula | None, n: int) -> Formula:
        if not negate:
            match timing:
                case "immediately":
                    return self.immediately(p)
                case "next":
                    return self.next(p)
                case "always":
                    return self.always(p)
                case "never":
                    return self.always(not_(p))
                case "eventually" | "null":
                    return self.eventually(p)
                case "finally":
                    return self.finally_(p)
                case "until":
                    assert stop is not None
                    return self.until(p, stop)
                case "before":
                    assert stop is not None
                    return self.before(p, stop)
                case "for":
                    return self.throughout(p, n)
                case "within":
                    return self.within(p, n)
                case "after":
                    return self.after(p, n)
        else:  # FRET's "not" forms, used by the only-scopes
            match timing:
                case "immediately":
                    return self.immediately(not_(p))
                case "next":
                    return self.next(not_(p))
                case "always":
                    return self.eventually(not_(p))
                case "never":
                    return self.eventually(p)
                case "eventually" | "null":
                    return self.always(not_(p))
                case "finally":
                    return self.finally_(not_(p))
                case "until":
                    assert stop is not None
                    return self.before(not_(p), stop)
                case "before":
                    assert stop is not None
                    return self.until(not_(p), stop)
                case "for":
                    return self.within(not_(p), n)
                case "within":
                    return self.throughout(not_(p), n)
                case "after":
                    return self.not_after(p, n)
        raise ValueError(f"unknown timing {timing}")


# ---------------------------------------------------------------- scopes

LAST = None  # the interval runs to the end of the trace


def _interval(kind: str, m: Formula) -> tuple[Formula, Formula | None, bool]:
    """(left, right, negate) for a scope; right None is LAST."""
    fim = and_(m, Z(not_(m)))  # first tick in mode
    lim = and_(not_(m), Y(m))  # first tick after leaving the mode
    fnim = and_(not_(m), Z(m))  # first tick out of mode
    lnim = and_(m, Y(not_(m)))  # first tick after leaving "not in mode"
    ffim = and_(fim, Z(H(not_(m))))  # first time ever in mode
    flim = and_(lim, Y(H(not_(lim))))  # first time ever leaving the mode
    match kind:
        case "in":
            return fim, lim, False
        case "notin":
            return fnim, lnim, False
        case "onlyIn":
            return fnim, lnim, True
        case "after":
            return flim, LAST, False
        case "before":
            return FTP, ffim, False
        case "onlyAfter":
            return FTP, flim, True
        case "onlyBefore":
            return ffim, LAST, True
    raise ValueError(f"unknown scope {kind}")


def _special(kind: str, timing: str, m: Formula, p: Formula) -> Formula | None:
    """FRET's simpler formulas for some scopes without a condition."""
    fim, fnim = and_(m, Z(not_(m))), and_(not_(m), Z(m))
    table = {
        ("in", "always"): lambda: H(implies(m, p)),
        ("in", "never"): lambda: H(implies(m, not_(p))),
        ("in", "immediately"): lambda: H(implies(fim, p)),
        ("notin", "always"): lambda: H(implies(not_(m), p)),
        ("notin", "never"): lambda: H(implies(p, m)),
        ("notin", "immediately"): lambda: H(implies(fnim, p)),
        ("onlyIn", "immediately"): lambda: H(implies(fnim, not_(p))),
        ("onlyIn", "eventually"): lambda: H(implies(p, m)),
        ("onlyAfter", "immediately"): lambda: H(implies(FTP, not_(p))),
    }
    build = table.get((kind, timing))
    return build() if build else None


# ---------------------------------------------------------------- entry points


def _duration_ticks(
    req: Requirement, period_ms: float | None, file: str, line: int | None
) -> tuple[int, Formula | None]:
    t = req.timing
    n = ticks(t.duration, period_ms, file=file, line=line) if t.duration is not None else 0
    return n, t.stop


def formalize(
    req: Requirement,
    *,
    period_ms: float | None = None,
    file: str = "<input>",
    line: int | None = None,
) -> Formalization:
    """The past-time formula of ``req`` (holds at a tick iff no violation so far
    can be concluded, FRET's reading), whether it is monotone, and why not."""
    n, stop = _duration_ticks(req, period_ms, file, line)
    timing = req.timing.kind
    kind = req.scope.kind if req.scope else "null"
    cond = req.condition

    m = _mode(req)
    if m is None:
        left, right, negate = FTP, LAST, False
    else:
        left, right, negate = _interval(kind, m)
    p = _starting_at(req.response, left)
    stop = _starting_at(stop, left) if stop is not None else None
    cexpr = _starting_at(cond.expr, left) if cond is not None else None

    if m is not None and cond is None:
        special = _special(kind, timing, m, p)
        if special is not None:
            return Formalization(simplify(special), True, None)

    base = _Base(left, cexpr, cond is not None and cond.kind == "holding")
    form = base.form(timing, negate, p, stop, n)

    if right is LAST:
        # Interval runs to the end: it must have opened (null scope: always has).
        formula = form if left == FTP else implies(O(left), form)
    else:
        # Closed intervals are checked at their end; an interval still open at
        # the current tick is checked as it stands (FRET's after-until reading).
        closed = H(implies(and_(right, not_(FTP)), Y(form)))
        open_now = implies(_persists(not_(right), left), form)
        formula = and_(closed, open_now)

    monotone = (timing, negate) not in _PENDING
    return Formalization(simplify(formula), monotone, None if monotone else _note(timing, negate))


def _mode(req: Requirement) -> Formula | None:
    # persisted/occurred/prevOcc count from the start of the scope's interval (FRET's
    # $Left$); in the scope's own mode they have no such start (FRET's "NoBounds" forms).
    return _starting_at(req.scope.mode, FALSE, bounded=False) if req.scope is not None else None


def interval_started(req: Requirement) -> Requirement:
    """``req`` with the start of its scope's interval put into its temporal functions,
    as ``formalize`` puts it: the scope's mode, the condition and the response then
    read only declared variables (the analyses read them apart from the formula)."""
    m = _mode(req)
    left = FTP if m is None else _interval(req.scope.kind, m)[0]  # type: ignore[union-attr]
    t = req.timing
    return dataclasses.replace(
        req,
        scope=None if req.scope is None else dataclasses.replace(req.scope, mode=m),
        condition=None
        if req.condition is None
        else dataclasses.replace(req.condition, expr=_starting_at(req.condition.expr, left)),
        timing=t if t.stop is None else dataclasses.replace(t, stop=_starting_at(t.stop, left)),
        response=_starting_at(req.response, left),
    )


def _starting_at(f: Formula, start: Formula, *, bounded: bool = True) -> Formula:
    """``f`` with the interval start of its temporal functions set to ``start``;
    ``bounded`` False gives FRET's forms without an interval (the scope's mode)."""
    if f == INTERVAL_START:
        return start
    if isinstance(f, BinOp) and f.op == "|" and f.left == Not(BOUNDED):
        # Folded here so that `explain` shows FRET's formula, not `(! TRUE) | ...`.
        return _starting_at(f.right, start) if bounded else TRUE
    if f == BOUNDED:
        return TRUE if bounded else FALSE
    return map_children(f, lambda g: _starting_at(g, start, bounded=bounded))


def _note(timing: str, negate: bool) -> str:
    what = {
        ("eventually", False): "`eventually` is false until the response has happened",
        ("null", False): "a requirement without timing means `eventually`: it is false "
        "until the response has happened",
        ("finally", False): "`finally` only judges the last tick of the interval, so it is "
        "false whenever the response does not hold at the current tick",
        ("finally", True): "`finally` only judges the last tick of the interval, so it is "
        "false whenever the response holds at the current tick",
        ("always", True): "an `only` scope with `always` means the response must fail at "
        "some point outside the mode: it is false until it has",
        ("never", True): "an `only` scope with `never` means the response must happen at "
        "some point outside the mode: it is false until it has",
    }[(timing, negate)]
    return (
        f"non-monotone: {what}; it is monitored as a pending obligation (shown as pending "
        "in diagnostics, reported as a violation only if still pending when the trace "
        "ends) instead of firing every tick"
    )


# ---------------------------------------------------------------- English


_SCOPE_TEXT = {
    "null": "the whole execution",
    "in": "each interval in which {m} holds",
    "notin": "each interval in which {m} does not hold",
    "onlyIn": "each interval in which {m} does not hold (the response is only allowed in it)",
    "after": "the execution after {m} first stops holding",
    "before": "the execution before {m} first holds",
    "onlyAfter": "the execution before {m} first stops holding "
    "(the response is only allowed after it)",
    "onlyBefore": "the execution from when {m} first holds (the response is only allowed before)",
}


def _dur_text(req: Requirement, n: int) -> str:
    d = req.timing.duration
    assert d is not None
    tick_text = f"{n} tick{'s' if n != 1 else ''}"
    return tick_text if d.unit == "tick" else f"{tick_text} ({d})"


def describe(req: Requirement, period_ms: float | None = None) -> str:
    """Plain-English reading of a requirement (used by ``explain``)."""
    kind = req.scope.kind if req.scope else "null"
    start = Var("interval_start")  # how explain shows FRET's $Left$
    req = dataclasses.replace(
        req,
        scope=dataclasses.replace(
            req.scope, mode=simplify(_starting_at(req.scope.mode, FALSE, bounded=False))
        )
        if req.scope
        else None,
        condition=dataclasses.replace(req.condition, expr=_starting_at(req.condition.expr, start))
        if req.condition
        else None,
        response=_starting_at(req.response, start),
        timing=dataclasses.replace(
            req.timing, stop=_starting_at(req.timing.stop, start) if req.timing.stop else None
        ),
    )
    m = str(req.scope.mode) if req.scope else ""
    scope = _SCOPE_TEXT[kind].format(m=m)
    if req.condition is None:
        trigger = "the start of the interval"
    elif req.condition.kind == "holding":
        trigger = f"every tick at which {req.condition.expr} holds"
    else:
        trigger = (
            f"every tick at which {req.condition.expr} becomes true "
            "(or already holds when the interval starts)"
        )
    p = str(req.response)
    t = req.timing
    n = 0
    if t.duration is not None:
        try:
            n = ticks(t.duration, period_ms)
        except UserError:
            n = -1
    dur = (
        (_dur_text(req, n) if n >= 0 else f"{t.duration} (not convertible to ticks)")
        if t.duration is not None
        else ""
    )
    behaviour = {
        "immediately": f"{p} holds at the trigger",
        "next": f"{p} holds at the tick after the trigger",
        "eventually": f"{p} holds at some tick from the trigger to the end of the interval",
        "null": f"{p} holds at some tick from the trigger to the end of the interval",
        "always": f"{p} holds at every tick from the trigger to the end of the interval",
        "never": f"{p} holds at no tick from the trigger to the end of the interval",
        "within": f"{p} holds within {dur} of the trigger (or the interval ends first)",
        "for": f"{p} holds from the trigger for {dur} (or until the interval ends)",
        "after": f"{p} is false for {dur} after the trigger and holds on the tick after that",
        "until": f"{p} holds from the trigger until {t.stop} holds",
        "before": f"{p} holds at some tick strictly before {t.stop} holds",
        "finally": f"{p} holds at the last tick of the interval",
    }[t.kind]
    negated = kind in ("onlyIn", "onlyAfter", "onlyBefore")
    text = f"Scope: {scope}. Trigger: {trigger}. Required: "
    if negated:
        text += f"it is not the case that {behaviour} (outside the allowed part)."
    else:
        text += f"{behaviour}."
    return text
