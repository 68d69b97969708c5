"""FRETISH sentences -> Requirement (scope, condition, timing, response).

The grammar is ``fretish.lark`` (LALR, contextual lexer, positions kept), so
every error is one line ``FILE:LINE:COL: expected X near 'tok'`` pointing at
the offending token, never a traceback.

Deliberate differences from FRET 3.0 (documented extensions / refusals):
- ``C is true`` / ``C is false`` (any case) are accepted; FRET only takes
  ``TRUE``/``FALSE``/``True``/``False`` there.
- A timing written after the response (``satisfy q within 3 ticks``) is
  rejected, like FRET, but with a message saying where the timing goes.
- A negative duration (``within -3 ticks``) is rejected; FRET accepts it and
  produces a meaningless formula.
- ``with probability OP P`` is refused (a monitor sees one run); P outside
  0..1 is FRET's "Illegal probability".
- Keywords are only keywords where the grammar expects them, so a mode or a
  variable may be called ``hereafter``, ``beforehand`` or ``auto``.  FRET's
  reserved names (``O H S Y Z X F G U V T A E abs max min mode next``) are
  refused unquoted everywhere a name is expected; quoted (``"T"``) they are names,
  as FRET's quoted names are (docs/reference/fretish.md, "Names").
- Functions: ``persisted(m, n, p)`` (p held from m to n ticks ago, and n ticks
  have passed) and ``occurred(m, n, p)`` (p happened between m and n ticks ago),
  with the formulas FRET prints for them; ``(n, p)`` is ``(0, n, p)``, and a
  window written far end first (``(3, 1, p)``) is refused; they count from the
  start of the scope's interval (INTERVAL_START, set by formalize);
  ``at the previous occurrence of p, q`` (also ``prevOcc(p, q)``) likewise, with
  FRET's unbounded form in the scope's mode (BOUNDED, set by formalize);
  ``preBool(init, p)`` (p at the previous tick, init at the first) with FRET's
  formula; the arithmetic functions of monitors/ir/formula.py (ARITH_FUNCTIONS:
  abs, min, max, sqrt, sin, ...; FRET refuses abs, min and max in sentences, as
  NuSMV keywords, and we accept them: they are its absReal, minReal ...); ``preInt`` and
  ``preReal`` (a number's previous value).  Any other call is kept as FRET keeps
  it, for the config's ``functions`` to define; FRET's future-time predicates
  (``persists``, ``occurs``, ``nextOcc``) are refused.
- ``FTP`` in an expression is FRET's first-time-point constant (``Z FALSE``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from fractions import Fraction
from functools import cache
from pathlib import Path

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import (
    UnexpectedCharacters,
    UnexpectedEOF,
    UnexpectedInput,
    UnexpectedToken,
    VisitError,
)

from monitors.errors import UserError
from monitors.ir.formula import (
    EXPRESSION_NESTING,
    FALSE,
    FTP,
    MAX_DEPTH,
    MAX_NUMBER_CHARS,
    TRUE,
    BinOp,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Since,
    Var,
    and_,
    arith_call,
    expression_parser,
    name_problem,
    reads_expressions,
    too_deep,
)

# FRET's $Left$: the first tick of the scope's interval.  persisted and occurred
# count only ticks since it (FRET's templates); formalize puts the scope's start in
# (docs/reference/fretish.md, "Functions").  No name can contain '$'.
INTERVAL_START = Var("$Left$")
# TRUE except in the scope's mode, where FRET uses its unbounded ("NoBounds") forms;
# only `at the previous occurrence of` needs it, as its unbounded form is not its
# bounded one with no interval start.  formalize puts it in.
BOUNDED = Var("$Bounded$")

UNITS = ("tick", "hour", "minute", "second", "millisecond", "microsecond")
_RESERVED_HINT = (
    "FRET reserves O H S Y Z X F G U V T A E abs max min mode next unquoted; "
    'quote it ("T") or rename it'
)
RESERVED = frozenset("O H S Y Z X F G U V T A E abs max min mode next".split())
# Reserved as names, yet functions in a sentence.  FRET refuses them there too, as
# NuSMV keywords; a monitor does not go through NuSMV, and they are FRET's absReal,
# minReal, maxReal (docs/reference/fretish.md, "Deliberate differences from FRET").
SENTENCE_FUNCTIONS = frozenset({"abs", "min", "max"})


@dataclass(frozen=True)
class Duration:
    amount: Fraction
    unit: str  # one of UNITS

    def __str__(self) -> str:
        plural = "" if self.amount == 1 else "s"
        return f"{_num(self.amount)} {self.unit}{plural}"


@dataclass(frozen=True)
class Scope:
    kind: str  # in notin onlyIn after before onlyAfter onlyBefore
    mode: Formula


@dataclass(frozen=True)
class Condition:
    kind: str  # regular | holding
    expr: Formula


@dataclass(frozen=True)
class Timing:
    kind: str  # immediately next eventually always never within for after until before finally null
    duration: Duration | None = None
    stop: Formula | None = None


@dataclass(frozen=True)
class Requirement:
    text: str
    component: str
    scope: Scope | None
    condition: Condition | None
    timing: Timing
    response: Formula


def _num(x: Fraction) -> str:
    return str(x.numerator) if x.denominator == 1 else str(float(x))


# ---------------------------------------------------------------- errors


class _Located(Exception):
    """Raised inside the transformer; carries the position of the bad token."""

    def __init__(self, message: str, line: int, col: int, hint: str | None = None) -> None:
        super().__init__(message)
        self.message, self.line, self.col, self.hint = message, line, col, hint


def _at(tok: Token) -> tuple[int, int]:
    return (tok.line or 1, tok.column or 1)


# Readable names for what lark says it expected.
_TERMINAL_TEXT = {
    "SHALL": "'shall'",
    "SATISFY": "'satisfy'",
    "NAME": "a name",
    "UNIT": "a time unit (ticks, seconds, milliseconds, ...)",
    "NUMBER": "a number",
    "LPAR": "'('",
    "RPAR": "')'",
    "REL_OP": "a comparison",
    "MODE": "'mode'",
    "IN": "'in'",
    "TIMEPOINT": "'timepoint'",
    "THEN": "'then'",
    "$END": "end of sentence",
}
_EXPR_START = {"NAME", "NUMBER", "LPAR", "NOT_OP", "MINUS", "TRUE_KW", "FALSE_KW", "PREV_OCC"}
_TIMING_WORDS = {
    "IMMEDIATELY", "INITIALLY", "AT", "EVENTUALLY", "ALWAYS", "NEVER", "WITHIN", "FOR",
    "AFTER", "UNTIL", "BEFORE", "FINALLY",
}  # fmt: skip
# Words of the sentence after `shall` that cannot name the component.
_SENTENCE_WORDS = frozenset(
    "shall satisfy with always never eventually immediately initially finally within for "
    "after until before at".split()
)
_TIMING_START = {"IMMEDIATELY", "EVENTUALLY", "ALWAYS", "NEVER", "WITHIN", "FOR", "UNTIL"}


def _expected_text(expected: set[str]) -> str:
    if "UNIT" in expected:
        return _TERMINAL_TEXT["UNIT"]
    if "$END" in expected:
        return "an operator or the end of the requirement"
    if "UPON" in expected and "WHENEVER" in expected:
        return "a qualifier (upon, when, whenever, if, where, unless)"
    if expected and expected <= _TIMING_WORDS:
        return "a timing (always, within N ticks, ...)"
    if "SATISFY" in expected and expected & _TIMING_START:
        return "a timing (always, within N ticks, ...) or 'satisfy'"
    if "SATISFY" in expected:
        return "'satisfy'"
    if "SHALL" in expected:
        return "'shall'"
    if expected & _EXPR_START and "NAME" in expected:
        return "an expression"
    names = sorted(_TERMINAL_TEXT.get(e, f"'{e.lower()}'") for e in expected if e != "COMMA")
    if len(names) > 4:
        names = names[:4] + ["..."]
    return " or ".join(names) if names else "something else"


def _near(text: str, pos: int) -> str:
    rest = text[pos:].split()
    return rest[0] if rest else ""


# FRET's `AT THE NEXT OCCURRENCE OF` (the previous one is an expression of the grammar).
_OCCURRENCE = re.compile(r"\bat\s+the\s+next\s+occurrence\s+of\b", re.IGNORECASE)


def _occurrence_error(text: str) -> UserError | None:
    """A sentence using FRET's next-occurrence expression fails to parse somewhere
    after it; say what the construct is and why it is refused instead."""
    m = _OCCURRENCE.search(text)
    if m is None:
        return None
    before = text[: m.start()]
    line, col = before.count("\n") + 1, m.start() - (before.rfind("\n") + 1) + 1
    why = "FRET's past-time semantics has no formula for it (it looks into the future)"
    return UserError(
        f"'at the next occurrence of P, Q' cannot be monitored: {why}",
        line=line,
        col=col,
        hint="state it with the timing of the sentence or with occurred(n, p)",
    )


_AFTER_SHALL = re.compile(r"\bshall\s*,?\s*(?:the\s+)?([A-Za-z_]\w*)\s*,?\s*$", re.IGNORECASE)


def _missing_component(e: UnexpectedToken, text: str) -> UserError | None:
    """`in m, shall within 2 ticks ...`: the timing word was taken as the component
    after `shall` and the parse failed on what follows it; say so at that word."""
    # Only right after the component can 'with' (probability) and 'satisfy' both come.
    if not {"SATISFY", "WITH"} <= set(e.expected) or e.token.start_pos is None:
        return None
    m = _AFTER_SHALL.search(text[: e.token.start_pos])
    if m is None or m.group(1).lower() not in _SENTENCE_WORDS:
        return None
    word = m.group(1)
    before = text[: m.start(1)]
    line, col = before.count("\n") + 1, m.start(1) - (before.rfind("\n") + 1) + 1
    return UserError(
        f"'{word}' is a FRETISH keyword, not a component name: the component is missing",
        line=line,
        col=col,
        hint=f"write: COMPONENT shall {word.lower()} ...",
    )


_PREVIOUS = re.compile(r"\bat\s+the\s+previous\s+occurrence\s+of\b", re.IGNORECASE)


def _previous_misplaced(e: UnexpectedInput, text: str) -> UserError | None:
    """The parse failed inside `at the previous occurrence of`: it stands where only an
    operand may (`x & at the ...`), and it is a whole expression, like if-then."""
    pos = getattr(getattr(e, "token", None), "start_pos", None)
    if pos is None:
        pos = getattr(e, "pos_in_stream", None)
    if pos is None:
        return None
    for m in _PREVIOUS.finditer(text):
        if m.start() < pos < m.end():
            before = text[: m.start()]
            line, col = before.count("\n") + 1, m.start() - (before.rfind("\n") + 1) + 1
            return UserError(
                "'at the previous occurrence of P, Q' is a whole expression here: "
                "it cannot be an operand",
                line=line,
                col=col,
                hint="put it in parentheses: x & (at the previous occurrence of p, q)",
            )
    return None


def _syntax_error(e: UnexpectedInput, text: str) -> UserError:
    occurrence = _occurrence_error(text) or _previous_misplaced(e, text)
    if occurrence is not None:
        return occurrence
    if isinstance(e, UnexpectedEOF) or (isinstance(e, UnexpectedToken) and e.token.type == "$END"):
        expected = set(getattr(e, "expected", ()) or ())
        line, col = _end_position(text)
        return UserError(
            f"expected {_expected_text(expected)} at end of sentence", line=line, col=col
        )
    if isinstance(e, UnexpectedToken):
        tok = e.token
        missing = _missing_component(e, text)
        if missing is not None:
            return missing
        msg = f"expected {_expected_text(set(e.expected))} near '{tok}'"
        hint = None
        if "UNIT" in e.expected:
            msg = f"duration without a time unit near '{tok}'"
            hint = "FRET needs a unit: ticks, hours, minutes, seconds, milliseconds, microseconds"
        elif tok.type == "STRING":
            msg = "free-form text is not FRETISH; FRET does not formalize it"
        elif "UPON" in e.expected and "WHENEVER" in e.expected:
            hint = "each 'and'/'or' between conditions needs its own qualifier; or use & and |"
        elif tok.type in ("MODE", "NEXT") and "NAME" in e.expected:
            msg = f"'{tok}' is reserved in FRETISH and cannot be used as a name"
            hint = _RESERVED_HINT
        elif str(tok).lower() in ("and", "or", "not") and e.expected & {"$END", "SHALL"}:
            hint = "inside an expression FRETISH writes & | ! for and, or, not"
        return UserError(msg, line=tok.line, col=tok.column, hint=hint)
    if isinstance(e, UnexpectedCharacters):
        return UserError(
            f"unexpected character '{text[e.pos_in_stream]}' near '{_near(text, e.pos_in_stream)}'",
            line=e.line,
            col=e.column,
        )
    return UserError(str(e).splitlines()[0])


def _end_position(text: str) -> tuple[int, int]:
    lines = text.rstrip().split("\n")
    return len(lines), len(lines[-1]) + 1


# ---------------------------------------------------------------- tree -> AST


def _toks(items: list, *types: str) -> list[Token]:
    return [t for t in items if isinstance(t, Token) and t.type in types]


def _formulas(items: list) -> list[Formula]:
    return [x for x in items if isinstance(x, Formula)]


_UNIT_OF = {
    "tick": "tick",
    "hour": "hour",
    "minute": "minute",
    "ms": "millisecond",
    "millisec": "millisecond",
    "millisecond": "millisecond",
    "microsec": "microsecond",
    "microsecond": "microsecond",
    "sec": "second",
    "second": "second",
}


@reads_expressions
class _Build(Transformer):
    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    # -- sentence
    def start(self, items: list) -> Requirement:
        return items[0]

    def freeform(self, items: list) -> Requirement:
        line, col = _at(items[0])
        raise _Located("free-form text is not FRETISH; FRET does not formalize it", line, col)

    def requirement(self, items: list) -> Requirement:
        scope = next((x for x in items if isinstance(x, Scope)), None)
        cond = next((x for x in items if isinstance(x, Condition)), None)
        component = next(x for x in items if isinstance(x, _Component))
        timing = next((x for x in items if isinstance(x, Timing)), Timing("null"))
        post = next((x for x in items if isinstance(x, _PostTiming)), None)
        if post is not None:
            raise _Located(
                f"the timing '{post.words}' must come before 'satisfy'",
                post.line,
                post.col,
                hint=f"write: {component.name} shall {post.words} satisfy ...",
            )
        response = _formulas(items)[-1]
        return Requirement(
            text=self.text.strip(),
            component=component.name,
            scope=scope,
            condition=cond,
            timing=timing,
            response=response,
        )

    # -- scope
    def scope(self, items: list) -> Scope:
        return items[0]

    def _scope(self, kind: str, items: list) -> Scope:
        return Scope(kind, _formulas(items)[-1])

    def only_in(self, items: list) -> Scope:
        return self._scope("onlyIn", items)

    def only_after(self, items: list) -> Scope:
        return self._scope("onlyAfter", items)

    def only_before(self, items: list) -> Scope:
        return self._scope("onlyBefore", items)

    def only_notin(self, items: list) -> Scope:
        # Parsed only to explain: FRET's grammar has no `only` form of `not in`.
        line, col = _at(items[0])
        raise _Located(
            "FRET has no 'only when not in' scope ('only' goes with in, during, while, "
            "after, before)",
            line,
            col,
            hint="to forbid the response in the mode, write: in M, COMPONENT shall never satisfy R",
        )

    def notin(self, items: list) -> Scope:
        return self._scope("notin", items)

    def in_(self, items: list) -> Scope:
        return self._scope("in", items)

    def after(self, items: list) -> Scope:
        return self._scope("after", items)

    def before(self, items: list) -> Scope:
        return self._scope("before", items)

    def smode(self, items: list) -> Formula:
        return _formulas(items)[0]

    # -- condition
    def condition(self, items: list) -> Condition:
        # FRET combines the qualifiers left to right, one clause at a time, not by
        # boolean precedence: `when a or when b and when c` is ((a | b) & c)
        # (docs/reference/fretish.md).  Commas and juxtaposition mean 'and'.  The
        # condition is regular as soon as one qualifier is regular (FRET's rule).
        quals = [x for x in items if isinstance(x, _Qualifier)]
        joins = [x for x in items if type(x) is str]  # join_and/join_or results, not tokens
        expr = quals[0].expr
        for j, q in zip(joins, quals[1:], strict=True):
            expr = BinOp("|" if j == "or" else "&", expr, q.expr)
        kind = "holding" if all(q.word == "whenever" for q in quals) else "regular"
        return Condition(kind, expr)

    def join_and(self, _: list) -> str:
        return "and"

    def join_or(self, _: list) -> str:
        return "or"

    def qword(self, items: list) -> Token:
        return items[0]

    def qualifier(self, items: list) -> _Qualifier:
        word = str(items[0]).lower()
        expr = items[1]
        negate = word == "unless"
        if len(items) > 2 and items[2] == "false":
            negate = not negate
        return _Qualifier(word, Not(expr) if negate else expr)

    def is_true(self, _: list) -> str:
        return "true"

    def is_false(self, _: list) -> str:
        return "false"

    # -- component, probability
    def component(self, items: list) -> _Component:
        name = _toks(items, "NAME", "STRING")[0]
        if name.type == "STRING":
            return _Component(str(name).strip('"'))
        # Right after `shall` a timing word would be read as the component name
        # (`in m, shall always satisfy p`); FRET's lexer never takes these words
        # as names, so the component is missing.
        if str(name).lower() in _SENTENCE_WORDS:
            line, col = _at(name)
            raise _Located(
                f"'{name}' is a FRETISH keyword, not a component name: the component is missing",
                line,
                col,
                hint=f"write: COMPONENT shall {str(name).lower()} ...",
            )
        return _Component(str(name))

    def probability(self, items: list) -> None:
        if _toks(items, "WHAT"):
            line, col = _at(items[0])
            raise _Located(
                "'with what probability' asks a model checker (PRISM) for a probability; "
                "a monitor sees a single run and cannot compute one",
                line,
                col,
                hint="remove 'with what probability' to require the response on every run",
            )
        op, num = _toks(items, "REL_OP")[0], _toks(items, "NUMBER")[0]
        value = float(num)
        # FRET's checkReqt: outside 0..1, or a strict bound no run can meet.
        if not 0.0 <= value <= 1.0 or (op == ">" and value >= 1) or (op == "<" and value <= 0):
            line, col = _at(num)
            raise _Located(
                f"illegal probability {op} {num}: FRET needs 0 <= P <= 1, P < 1 after '>' "
                "and P > 0 after '<'",
                line,
                col,
            )
        # FRET hands probabilistic requirements to a model checker (PRISM); its ptLTL
        # formula drops the bound.  One run cannot show a probability, so monitoring
        # the formula would silently strengthen the requirement: refuse instead.
        line, col = _at(items[0])
        raise _Located(
            f"'with probability {op} {num}' cannot be monitored: FRET checks a probability "
            "bound by model checking (PRISM), and a monitor sees a single run",
            line,
            col,
            hint="remove 'with probability ...' to require the response on every run",
        )

    # -- timing
    def t_immediately(self, _: list) -> Timing:
        return Timing("immediately")

    def t_next(self, _: list) -> Timing:
        return Timing("next")

    def t_eventually(self, _: list) -> Timing:
        return Timing("eventually")

    def t_always(self, _: list) -> Timing:
        return Timing("always")

    def t_never(self, _: list) -> Timing:
        return Timing("never")

    def t_finally(self, _: list) -> Timing:
        return Timing("finally")

    def t_within(self, items: list) -> Timing:
        return Timing("within", duration=items[-1])

    def t_for(self, items: list) -> Timing:
        return Timing("for", duration=items[-1])

    def t_after(self, items: list) -> Timing:
        return Timing("after", duration=items[-1])

    def t_until(self, items: list) -> Timing:
        return Timing("until", stop=_formulas(items)[0])

    def t_before(self, items: list) -> Timing:
        return Timing("before", stop=_formulas(items)[0])

    @v_args(meta=True)
    def post_timing(self, meta: object, items: list) -> _PostTiming:
        start, end = meta.start_pos, meta.end_pos  # type: ignore[attr-defined]
        words = " ".join(self.text[start:end].lstrip(",").split())
        return _PostTiming(words, meta.line, meta.column)  # type: ignore[attr-defined]

    def duration(self, items: list) -> Duration:
        num = _toks(items, "NUMBER")[0]
        _number_text(num)
        line, col = _at(items[0])
        if _toks(items, "MINUS"):
            raise _Located(f"negative duration -{num}: a duration must be 0 or more", line, col)
        units = _toks(items, "UNIT")
        if not units:  # the grammar makes UNIT optional only to say this clearly
            raise _Located(
                f"duration {num} has no time unit",
                *_at(num),
                hint="FRET needs a unit: ticks, hours, minutes, seconds, milliseconds, microseconds",
            )
        word = str(units[0]).lower()
        word = word[:-1] if word.endswith("s") and word != "ms" else word
        return Duration(Fraction(str(num)), _UNIT_OF[word])

    # -- expressions
    def ifthen(self, items: list) -> Formula:
        a, b = _formulas(items)
        return BinOp("->", a, b)

    def binop(self, items: list) -> Formula:
        a, op, b = items
        text = str(op).lower()
        text = {"=>": "->", "<=>": "<->"}.get(text, text)
        return BinOp(text, a, b)

    def not_(self, items: list) -> Formula:
        return Not(items[-1])

    def uminus(self, items: list) -> Formula:
        a = items[-1]
        if isinstance(a, Const) and not isinstance(a.value, bool):
            return Const(-a.value)
        return Neg(a)

    def number(self, items: list) -> Formula:
        text = _number_text(items[0])
        if any(c in text for c in ".eE"):
            return Const(float(text))
        return Const(int(text))

    def true(self, _: list) -> Formula:
        return TRUE

    def false(self, _: list) -> Formula:
        return FALSE

    def var(self, items: list) -> Formula:
        if str(items[0]) == "FTP":  # FRET's "first time point" constant
            return FTP
        return Var(_name(items[0]))

    def quoted_var(self, items: list) -> Formula:
        # FRET's quoted name: any name, keyword-like ones too ("T", "mode");
        # formula text writes it in FRET's renaming (monitors/ir/formula.py, fret_name).
        tok = items[0]
        name = str(tok)[1:-1]
        why = name_problem(name)
        if why is not None:
            raise _Located(f"{tok} cannot be used as a name: {why}", *_at(tok))
        return Var(name)

    def prev_occ(self, items: list) -> Formula:
        p, q = _formulas(items[1:])
        return previous_occurrence(p, q)

    def call(self, items: list) -> Formula:
        fn = items[0]
        args = _formulas(items[1:])
        name = str(fn)
        if name == "prevOcc" and len(args) == 2:  # FRET's name for the same thing
            return previous_occurrence(args[0], args[1])
        if name in ("persisted", "occurred") and len(args) in (2, 3):
            lo, hi = _window(args, fn)
            if name == "occurred":  # FRET: (! $Left$) S[m,n] p
                return Since("S", Not(INTERVAL_START), args[-1], lo, hi)
            # FRET: (H[m,n] p) & (H[<n] ! $Left$): p held from m to n ticks ago, and n
            # ticks have passed in the scope's interval.  H[<0] is TRUE.
            if hi == 0:
                return args[-1]
            return and_(Past("H", args[-1], lo, hi), Past("H", Not(INTERVAL_START), 0, hi - 1))
        line, col = _at(fn)
        if name in RESERVED and name not in SENTENCE_FUNCTIONS:
            raise _Located(f"'{name}' is reserved in FRETISH and cannot be used", line, col)
        if name == "preBool" and len(args) == 2:
            # FRET: ((Z FALSE) & init) | ((Y TRUE) & (Y p)), from the trace's start in
            # every scope (FRET's mode-relative version is not the one it uses).
            return BinOp(
                "|", BinOp("&", FTP, args[0]), BinOp("&", Past("Y", TRUE), Past("Y", args[1]))
            )
        if name in _FRET_TEMPORAL:  # the right name with the wrong number of arguments
            raise _Located(
                f"{name} takes {_FRET_TEMPORAL[name]}, not {len(args)} argument"
                f"{'s' * (len(args) != 1)}",
                line,
                col,
            )
        # Arithmetic functions, preInt/preReal, and any other name: FRET passes calls
        # on, and the config defines them (docs/reference/config.md, "functions").
        try:
            return arith_call(name, args, ValueError)
        except ValueError as e:
            raise _Located(str(e), line, col) from None


# FRET's temporal functions this reader expands, and the arguments they take.
_FRET_TEMPORAL = {
    "persisted": "2 or 3 arguments (n, p) or (m, n, p)",
    "occurred": "2 or 3 arguments (n, p) or (m, n, p)",
    "prevOcc": "2 arguments (p, q)",
    "preBool": "2 arguments (init, p)",
}


def previous_occurrence(p: Formula, q: Formula) -> Formula:
    """FRET's ``prevOcc(p, q)``: q held at the last tick p held before this one, counted
    from the scope's interval start (true at that start, and while p has not held
    since it); in the scope's mode, FRET's unbounded form ``Y(!p S (p & q))``.  With
    BOUNDED true this is FRET's bounded template
    ``Left | Y(((!Left & !p) S p) -> ((!Left & !p) S (p & q)))``, with BOUNDED and
    Left false its unbounded one (docs/reference/fretish.md, "Functions")."""
    quiet = BinOp("&", Not(INTERVAL_START), Not(p))
    seen = BinOp("|", Not(BOUNDED), Since("S", quiet, p))
    held = Since("S", quiet, BinOp("&", p, q))
    return BinOp("|", INTERVAL_START, Past("Y", BinOp("->", seen, held)))


def _number_text(tok: Token) -> str:
    """A number's text; longer than any int64 or double needs is an error (Python
    refuses to convert integers of thousands of digits)."""
    text = str(tok)
    if len(text) > MAX_NUMBER_CHARS:
        line, col = _at(tok)
        raise _Located(f"number '{text[:20]}...' is too long", line, col)
    return text


def _name(tok: Token) -> str:
    name = str(tok)
    if name in RESERVED:
        line, col = _at(tok)
        raise _Located(
            f"'{name}' is reserved in FRETISH and cannot be used as a name",
            line,
            col,
            hint=_RESERVED_HINT,
        )
    return name


def _window(args: list[Formula], fn: Token) -> tuple[int, int]:
    """The ticks-ago window (m, n) of persisted/occurred: (0, n) for (n, p).  FRET
    prints H[3,1] for persisted(3, 1, p), an empty window: refused, as nobody means it."""
    counts = [_tick_arg(a, fn) for a in args[:-1]]
    lo, hi = (0, counts[0]) if len(counts) == 1 else (counts[0], counts[1])
    if lo > hi:
        line, col = _at(fn)
        raise _Located(
            f"{fn}({lo}, {hi}, ...) looks from {lo} to {hi} ticks ago: the window is empty",
            line,
            col,
            hint=f"the nearer tick comes first: {fn}({hi}, {lo}, ...)",
        )
    return lo, hi


def _tick_arg(f: Formula, fn: Token) -> int:
    if isinstance(f, Const) and isinstance(f.value, int) and not isinstance(f.value, bool):
        if f.value >= 0:
            return f.value
    line, col = _at(fn)
    raise _Located(
        f"{fn}(...) needs a tick count (a whole number >= 0) before its last argument", line, col
    )


@dataclass(frozen=True)
class _Qualifier:
    word: str
    expr: Formula


@dataclass(frozen=True)
class _Component:
    name: str


@dataclass(frozen=True)
class _PostTiming:
    words: str
    line: int
    col: int


# ---------------------------------------------------------------- entry point


# The rules of fretish.lark that nest: those of its expressions.
_NESTING_RULES = EXPRESSION_NESTING


@cache
def _parser() -> Lark:
    grammar = (Path(__file__).with_name("fretish.lark")).read_text()
    # The expression rules are monitors/ir/expressions.lark, shared with FRET's formula text.
    return expression_parser(grammar, propagate_positions=True)


def parse_requirement(
    text: str, *, file: str = "<input>", line: int = 1, col: int = 1
) -> Requirement:
    """Parse one FRETISH sentence.  ``line``/``col`` say where ``text`` starts in
    ``file`` so that errors point at the offending token in that file."""
    parser = _parser()  # outside the try: a wrong lark is not an error in the text
    try:
        if not text.strip():
            raise UserError("empty requirement", line=1, col=1)
        tree = parser.parse(text)
        deep = too_deep(tree, _NESTING_RULES)
        if deep is not None:
            raise UserError(
                f"expression nested more than {MAX_DEPTH} operators deep",
                line=deep.meta.line,
                col=deep.meta.column,
                hint="split it with internal variables (define:)",
            )
        return _Build(text).transform(tree)
    except VisitError as e:
        orig = e.orig_exc
        if isinstance(orig, _Located):
            err = UserError(orig.message, line=orig.line, col=orig.col, hint=orig.hint)
            raise err.at(file, line, col) from None
        raise
    except UnexpectedInput as e:
        raise _syntax_error(e, text).at(file, line, col) from None
    except UserError as e:
        raise e.at(file, line, col) from None
