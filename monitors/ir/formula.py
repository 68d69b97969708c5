"""Past-time metric LTL formulas: the AST, FRET-syntax printer and parser.

This is the core language every stage shares (formalize produces it, interpret
judges it, c99/copilot compile it).  Terms are immutable and hashable so that
common subformulas can be shared.

Syntax (FRET's past-time output, fully parenthesized when printed):
  booleans   ! & | xor -> <->           (=>, <=> accepted when parsing)
  relations  = != < <= > >=
  arithmetic + - * / mod ^ and unary -
  temporal   Y p (previous, false at tick 0)   Z p (weak previous, true at tick 0)
             H p, O p, H[l,r] p, O[l,r] p, a S b, a S[l,r] b, a T b, a T[l,r] b
  constants  TRUE FALSE, integer and real literals; FTP is Z FALSE.
  functions  abs min max sqrt exp log sin cos tan asin acos atan floor ceil hypot ite
             (ARITH_FUNCTIONS: C99's <math.h> meaning; docs/reference/fretish.md)
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, TypeVar

from lark import Lark, Token, Transformer, Tree

from monitors.errors import UserError

BOOL_OPS = ("&", "|", "xor", "->", "<->")
REL_OPS = ("=", "!=", "<", "<=", ">", ">=")
ARITH_OPS = ("+", "-", "*", "/", "mod", "^")
# Arithmetic functions and their arities.  abs, min and max keep an int64 type
# when every argument is int64; the others are C's double functions.
ARITH_FUNCTIONS: dict[str, int] = {
    "abs": 1, "min": 2, "max": 2, "sqrt": 1, "exp": 1, "log": 1, "sin": 1, "cos": 1,
    "tan": 1, "asin": 1, "acos": 1, "atan": 1, "floor": 1, "ceil": 1, "hypot": 2, "ite": 3,
}  # fmt: skip
# ite(c, a, b) is FRET's if-then-else value: a where c holds, else b (Booleans or
# numbers; an int64 branch beside a double one is converted to double).
INT_FUNCTIONS = ("abs", "min", "max")
# FRET's typed names of abs, min and max (its predefined names; in a sentence FRET
# reserves the plain ones), read as the same functions.
FRET_FUNCTION_NAMES = {
    "absReal": "abs", "absInt": "abs", "minReal": "min", "minInt": "min",
    "maxReal": "max", "maxInt": "max",
}  # fmt: skip
# FRET's previous-value functions for numbers (preBool is a formula, see
# monitors/frontend/parse.py): a number's value at the previous tick, init at the first.
PRE_FUNCTIONS = {"preInt": "int64", "preReal": "double"}
# FRET's future-time predicates: FRET formalizes them only in future time, and a
# runtime monitor sees only the past.
FUTURE_FUNCTIONS = ("persists", "occurs", "nextOcc")


class Formula:
    """Base class of all formula nodes."""

    __slots__ = ()

    def children(self) -> tuple[Formula, ...]:
        return ()

    def __str__(self) -> str:
        return to_fret(self)


def _cached_hash(cls: type) -> type:
    """Keep a node's hash once computed: hashing a frozen node hashes its whole
    subtree, and every stage puts nodes in dicts (``subterms``), which made large
    requirement sets quadratic (docs/BENCHMARKS.md, "Scaling")."""
    compute = cls.__hash__

    def __hash__(self: Any) -> int:
        h = self._h
        if h is None:
            h = compute(self)
            object.__setattr__(self, "_h", h)
        return h

    cls.__hash__ = __hash__  # type: ignore[method-assign,assignment]
    return cls


@dataclass(frozen=True, slots=True, eq=False)
class Const(Formula):
    value: bool | int | float

    # 1, 1.0 and True are equal in Python but are different constants here
    # (integer vs real division, bool vs number): compare by type too.
    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Const)
            and type(other.value) is type(self.value)
            and (
                other.value == self.value
                or (self.value != self.value and other.value != other.value)
            )
        )

    def __hash__(self) -> int:
        return hash((Const, type(self.value), self.value))


@_cached_hash
@dataclass(frozen=True, slots=True)
class Var(Formula):
    name: str
    _h: int | None = field(default=None, init=False, repr=False, compare=False)


@_cached_hash
@dataclass(frozen=True, slots=True)
class Not(Formula):
    arg: Formula
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)


@_cached_hash
@dataclass(frozen=True, slots=True)
class Neg(Formula):
    """Arithmetic negation."""

    arg: Formula
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)


@_cached_hash
@dataclass(frozen=True, slots=True)
class BinOp(Formula):
    """Boolean connective, relation or arithmetic operator (see *_OPS)."""

    op: str
    left: Formula
    right: Formula
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)


@_cached_hash
@dataclass(frozen=True, slots=True)
class Call(Formula):
    """A function applied to its arguments: an arithmetic function (a key of
    ARITH_FUNCTIONS), or any other name as FRET passes it on, which the config
    must define (monitors/ir/functions.py expands those before typing)."""

    name: str
    args: tuple[Formula, ...]
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return self.args


@_cached_hash
@dataclass(frozen=True, slots=True)
class Past(Formula):
    """Unary temporal operator.

    op is Y, Z, H or O.  For H and O, ``lo``/``hi`` bound the distance in ticks
    into the past (``hi is None``: unbounded).  Y and Z have lo = hi = None.
    """

    op: str
    arg: Formula
    lo: int | None = None
    hi: int | None = None
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)


@_cached_hash
@dataclass(frozen=True, slots=True)
class Since(Formula):
    """``left S[lo,hi] right`` (op 'S') or its dual trigger ``left T right`` (op 'T')."""

    op: str
    left: Formula
    right: Formula
    lo: int | None = None
    hi: int | None = None
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)


@_cached_hash
@dataclass(frozen=True, slots=True)
class Pre(Formula):
    """FRET's ``preInt(init, x)`` / ``preReal(init, x)`` (name): x's value at the
    previous tick, and init's value at the first tick (Lustre's ``init -> pre x``)."""

    name: str  # a key of PRE_FUNCTIONS
    init: Formula
    arg: Formula
    _h: int | None = field(default=None, init=False, repr=False, compare=False)

    def children(self) -> tuple[Formula, ...]:
        return (self.init, self.arg)


TRUE = Const(True)
FALSE = Const(False)
FTP = Past("Z", FALSE)


# ---------------------------------------------------------------- constructors
# Small smart constructors used by the formalizer; they fold constants so that
# generated formulas stay readable, and never change the meaning.


def not_(a: Formula) -> Formula:
    if isinstance(a, Const) and isinstance(a.value, bool):
        return Const(not a.value)
    return Not(a)


def and_(*args: Formula) -> Formula:
    out: Formula | None = None
    for a in args:
        if a == TRUE:
            continue
        if a == FALSE:
            return FALSE
        out = a if out is None else BinOp("&", out, a)
    return TRUE if out is None else out


def or_(*args: Formula) -> Formula:
    out: Formula | None = None
    for a in args:
        if a == FALSE:
            continue
        if a == TRUE:
            return TRUE
        out = a if out is None else BinOp("|", out, a)
    return FALSE if out is None else out


def implies(a: Formula, b: Formula) -> Formula:
    if a == TRUE:
        return b
    if a == FALSE or b == TRUE:
        return TRUE
    return BinOp("->", a, b)


def Y(a: Formula) -> Formula:  # noqa: N802 - named after the operator
    return Past("Y", a)


def Z(a: Formula) -> Formula:  # noqa: N802
    return Past("Z", a)


def H(a: Formula, lo: int | None = None, hi: int | None = None) -> Formula:  # noqa: N802
    return Past("H", a, lo, hi)


def O(a: Formula, lo: int | None = None, hi: int | None = None) -> Formula:  # noqa: N802, E743
    return Past("O", a, lo, hi)


def S(a: Formula, b: Formula, lo: int | None = None, hi: int | None = None) -> Formula:  # noqa: N802
    return Since("S", a, b, lo, hi)


def arith_call(name: str, args: list[Formula], error: type[Exception]) -> Formula:
    """``name(args)``: a Call (checked when ``name`` is an arithmetic function, left
    for the config's functions otherwise, as FRET passes calls on), a Pre for
    preInt/preReal, or ``error`` saying why the call is wrong."""
    if name in FUTURE_FUNCTIONS:
        raise error(
            f"{name} is one of FRET's future-time predicates, which FRET formalizes only "
            "in future time; a runtime monitor sees only the past (use persisted, "
            "occurred or prevOcc)"
        )
    if name in PRE_FUNCTIONS:
        if len(args) != 2:
            raise error(f"{name} takes 2 arguments (init, value), not {len(args)}")
        return Pre(name, args[0], args[1])
    name = FRET_FUNCTION_NAMES.get(name, name)
    arity = ARITH_FUNCTIONS.get(name)
    if arity is None:
        return Call(name, tuple(args))
    if len(args) != arity:
        raise error(f"{name} takes {arity} argument{'s' * (arity > 1)}, not {len(args)}")
    return Call(name, tuple(args))


# ---------------------------------------------------------------- traversal


def subterms(f: Formula) -> list[Formula]:
    """All distinct subterms, children before parents (a topological order)."""
    seen: dict[Formula, None] = {}

    def visit(g: Formula) -> None:
        if g in seen:
            return
        for c in g.children():
            visit(c)
        seen[g] = None

    visit(f)
    return list(seen)


# Every stage walks formulas recursively (printer, simplifier, type checker,
# backends, interpreter, z3 encoding), so the parsers refuse deeper nesting up
# front; a formalized requirement with defines expanded stays well inside
# Python's recursion limit (docs/reference/config.md, "Limits").
MAX_DEPTH = 100
# The longest number text the parsers convert: far beyond int64 and double, and
# short of Python's limit on converting integers of thousands of digits.
MAX_NUMBER_CHARS = 400


def depth(f: Formula) -> int:
    """Nesting depth of ``f`` (a leaf is 1), computed without recursion."""
    best, stack = 0, [(f, 1)]
    while stack:
        g, d = stack.pop()
        best = max(best, d)
        stack.extend((c, d + 1) for c in g.children())
    return best


def too_deep(tree: Tree, counted: frozenset[str]) -> Tree | None:
    """The first node of a lark parse tree nested more than MAX_DEPTH of the
    ``counted`` rules deep (None if there is none), found without recursion,
    before any recursive transformer sees the tree."""
    stack: list[tuple[Tree, int]] = [(tree, 0)]
    while stack:
        node, d = stack.pop()
        d += node.data in counted
        if d > MAX_DEPTH:
            return node
        stack.extend((c, d) for c in node.children if isinstance(c, Tree))
    return None


def map_children(f: Formula, fn: Callable[[Formula], Formula]) -> Formula:
    """``f`` with ``fn`` applied to each direct child (leaves are returned as is)."""
    match f:
        case Not(a):
            return Not(fn(a))
        case Neg(a):
            return Neg(fn(a))
        case BinOp(op, a, b):
            return BinOp(op, fn(a), fn(b))
        case Past(op, a, lo, hi):
            return Past(op, fn(a), lo, hi)
        case Since(op, a, b, lo, hi):
            return Since(op, fn(a), fn(b), lo, hi)
        case Call(name, args):
            return Call(name, tuple(fn(a) for a in args))
        case Pre(name, init, a):
            return Pre(name, fn(init), fn(a))
    return f


def variables(f: Formula) -> list[str]:
    """Variable names in order of first appearance."""
    return list(dict.fromkeys(g.name for g in subterms(f) if isinstance(g, Var)))


def max_bound(f: Formula) -> int:
    """Largest finite time bound in the formula (0 when there is none)."""
    best = 0
    for g in subterms(f):
        for b in (getattr(g, "lo", None), getattr(g, "hi", None)):
            if isinstance(b, int):
                best = max(best, b)
    return best


def is_temporal(f: Formula) -> bool:
    """True when ``f``'s value depends on earlier ticks (it keeps state)."""
    return any(isinstance(g, Past | Since | Pre) for g in subterms(f))


# ---------------------------------------------------------------- printer


def _bounds(lo: int | None, hi: int | None) -> str:
    if hi is None and (lo is None or lo == 0):
        return ""
    return f"[{lo or 0},{'inf' if hi is None else hi}]"


def _const(v: bool | int | float) -> str:
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    return repr(v)


# FRET's renaming of the characters of a quoted name in its formulas (its
# support/utils.js special_char_map); the quotes themselves become _DQT_.
FRET_CHAR_CODES: dict[str, str] = {
    ".": "_DOT_", "%": "_PRC_", "#": "_HSH_", "$": "_DOL_", "&": "_AMP_",
    "@": "_ATS_", "!": "_BNG_", "?": "_QUS_", "-": "_HYP_", "*": "_AST_",
    "=": "_EQU_", "^": "_CRT_", " ": "_SPC_", "+": "_PLS_", ";": "_SEM_",
    ":": "_CLN_", ",": "_CMA_", "/": "_FSL_", "\\": "_BSL_", "|": "_VBR_",
    "~": "_TLD_", "<": "_LAN_", ">": "_RAN_", "(": "_LPR_", ")": "_RPR_",
    "{": "_LCB_", "}": "_RCB_", "[": "_LSQ_", "]": "_RSQ_", "'": "_SQT_",
    '"': "_DQT_", "`": "_BQT_",
}  # fmt: skip
_CODE_CHARS = {code: c for c, code in FRET_CHAR_CODES.items()}
_CODE_RE = re.compile("|".join(re.escape(c) for c in _CODE_CHARS))
_PLAIN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
# Names the formula text would read as something else (an operator, a literal, a
# keyword), and FRET's reserved letter combinations: written as FRET writes a
# quoted name, so `T` and `"left wheel"` print as _DQT_T_DQT_ and
# _DQT_left_SPC_wheel_DQT_ (docs/reference/fretish.md, "Names").
FORMULA_WORDS = frozenset("O H S Y Z X F G U V T A E abs max min FTP xor mod inf".split())
# Keywords in any case, as the lexers read them.
FORMULA_KEYWORDS = frozenset("mode next true false if then".split())


def name_problem(name: str) -> str | None:
    """Why a variable or mode name cannot be used (None if it can): the formula
    text must spell it in FRET's renaming and read it back as the same name."""
    if not name:
        return "an empty name"
    if not all(" " <= c <= "~" for c in name) or '"' in name or "\\" in name:
        return "a name is printable ASCII without '\"' or '\\'"
    if name.startswith("$"):
        return "'$' starts the supervisor's own names"
    if name.startswith("_DQT_") and name.endswith("_DQT_"):
        return "_DQT_..._DQT_ is how formula text writes a quoted name"
    if user_name(fret_name(name)) != name:
        return (
            "FRET's renaming of quoted names (_SPC_ for a space ...) would read it back differently"
        )
    return None


def _mangled(name: str) -> bool:
    return (
        not _PLAIN_NAME.fullmatch(name) or name in FORMULA_WORDS or name.lower() in FORMULA_KEYWORDS
    )


def fret_name(name: str) -> str:
    """A variable's name in formula text: itself, or, when formula text cannot
    hold it as is, FRET's spelling of the quoted name.  user_name undoes it."""
    if name.startswith("$") or not _mangled(name):  # $Left$: the supervisor's own
        return name
    return "_DQT_" + "".join(FRET_CHAR_CODES.get(c, c) for c in name) + "_DQT_"


def user_name(text: str) -> str:
    """The name a formula's identifier stands for (the inverse of fret_name)."""
    if len(text) > 10 and text.startswith("_DQT_") and text.endswith("_DQT_"):
        return _CODE_RE.sub(lambda m: _CODE_CHARS[m[0]], text[5:-5])
    return text


def to_fret(f: Formula) -> str:
    """Print in FRET's past-time syntax, fully parenthesized like FRET does."""
    match f:
        case Const(v):
            return _const(v)
        case Var(n):
            return fret_name(n)
        case Not(a):
            return f"(! {to_fret(a)})"
        case Neg(a):
            return f"(- {to_fret(a)})"
        case BinOp(op, a, b):
            return f"({to_fret(a)} {op} {to_fret(b)})"
        case Past(op, a, lo, hi):
            return f"({op}{_bounds(lo, hi)} {to_fret(a)})"
        case Since(op, a, b, lo, hi):
            return f"({to_fret(a)} {op}{_bounds(lo, hi)} {to_fret(b)})"
        case Call(name, args):
            return f"{name}({', '.join(to_fret(a) for a in args)})"
        case Pre(name, init, a):
            return f"{name}({to_fret(init)}, {to_fret(a)})"
    raise TypeError(f"not a formula: {f!r}")


# ---------------------------------------------------------------- parser

# The one grammar of expressions, shared with FRETISH sentences (fretish.lark).
EXPRESSIONS_GRAMMAR = Path(__file__).with_name("expressions.lark")
# lark names the rules a grammar imports from expressions.lark with this prefix.
_IMPORTED = "expressions__"
_EXPRESSION_RULES = (
    "ifthen",
    "prev_occ",
    "binop",
    "not_",
    "uminus",
    "number",
    "true",
    "false",
    "call",
    "var",
    "quoted_var",
)
# The rules of expressions.lark that nest (parentheses alone add no level).
EXPRESSION_NESTING = frozenset(
    _IMPORTED + r for r in ("ifthen", "prev_occ", "binop", "not_", "uminus", "call")
)

_T = TypeVar("_T", bound=type)


# The grammars are written for lark 1.x.  ROS's rosidl_parser wheel requires the old
# distribution of the same project, ``lark-parser`` 0.12, which installs into the same
# ``lark/`` folder: whichever pip unpacks last is what imports.
LARK_NEEDED = (1, 1)


def _lark_problem() -> UserError | None:
    import lark

    version = tuple(int(p) for p in re.findall(r"\d+", lark.__version__)[:2])
    if version >= LARK_NEEDED:
        return None
    return UserError(
        f"lark {lark.__version__} is installed, the grammars need lark "
        f"{'.'.join(map(str, LARK_NEEDED))} or newer (the old 'lark-parser' package, "
        "which ros-rosidl-parser requires, was unpacked over it)",
        file=str(Path(lark.__file__).parent),
        hint="pip install --force-reinstall --no-deps 'lark>=1.1'",
    )


# Building the LALR tables is most of a start's parsing (0.3-1 s); the application
# may keep them in a directory only it can write (its start-up cache,
# supervisor/cache.py), where lark checks them against the grammar on load.
_parser_cache_dir: Path | None = None


def use_parser_cache(directory: Path | None) -> None:
    """Keep the parsers' tables in ``directory`` (a directory of this user's that
    nobody else can write), or nowhere (None)."""
    global _parser_cache_dir
    _parser_cache_dir = directory


def _cache_file(grammar: str, options: dict[str, object]) -> str | None:
    if _parser_cache_dir is None:
        return None
    import hashlib
    import os
    import stat

    import lark

    text = f"{lark.__version__}\0{grammar}\0{sorted(options.items())!r}"
    path = _parser_cache_dir / f"lark-{hashlib.sha256(text.encode()).hexdigest()[:24]}.tables"
    try:
        st = path.lstat()
    except FileNotFoundError:
        return str(path)
    except OSError:
        return None
    ours = stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid()
    return str(path) if ours and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) else None


def expression_parser(grammar: str, **options: object) -> Lark:
    """An LALR parser of ``grammar``, which may ``%import expressions (...)``."""
    problem = _lark_problem()
    if problem is not None:
        raise problem
    cache_file = _cache_file(grammar, options)
    if cache_file is not None:
        options = {**options, "cache": cache_file}
    return Lark(
        grammar,
        parser="lalr",
        import_paths=[str(EXPRESSIONS_GRAMMAR.parent)],
        maybe_placeholders=False,
        **options,
    )


def reads_expressions(cls: _T) -> _T:
    """Class decorator for a lark Transformer: its methods named after the rules
    of expressions.lark (``binop``, ``var``, ...) also transform those rules as
    a grammar imports them (lark prefixes them with ``expressions__``)."""
    for name in _EXPRESSION_RULES:
        if hasattr(cls, name):
            setattr(cls, _IMPORTED + name, getattr(cls, name))
    return cls


# FRET's formula text: the shared expressions with the past-time operators.  A
# unary operator binds like `!`; S and T bind like the implications (loosest,
# as in FRET's own LTL grammar).  Bounds are `[l,r]`, `[l,inf]` or, as older
# FRET versions print them, `[<=n]` `[<n]` `[=n]`.
_GRAMMAR = r"""
?start: expr
%import expressions (expr, impl, disj, neg, NAME, NUMBER, IF, THEN, TRUE_KW, FALSE_KW, MINUS, REL_OP, IMPL_OP, OR_OP, AND_OP, NOT_OP, ADD_OP, MUL_OP, POW_OP)
%extend neg: PAST_OP bounds? neg           -> past
%extend impl: impl SINCE_OP bounds? disj   -> since
bounds: "[" INT "," (INT | "inf") "]"
      | "[" CMP_BOUND "]"                  -> cmp_bounds
SINCE_OP.2: /[ST](?![A-Za-z0-9_])/
PAST_OP.2: /[YZHO](?![A-Za-z0-9_])/
CMP_BOUND: /(<=|<|=)[^\]]*/
INT: /-?\d+/
%import common.WS
%ignore WS
"""


class FormulaSyntaxError(ValueError):
    """A formula string that is not in FRET's past-time syntax."""


@reads_expressions
class _Build(Transformer):
    def ifthen(self, a: list) -> Formula:
        return BinOp("->", a[-3], a[-1])

    def prev_occ(self, a: list) -> Formula:
        # Its formula depends on the scope's interval start, which formula text does
        # not have; FRET prints it expanded (docs/reference/fretish.md, "Functions").
        raise FormulaSyntaxError(
            "'at the previous occurrence of' belongs in a FRETISH sentence, not in formula text"
        )

    def binop(self, a: list) -> Formula:
        left, op, right = a
        text = str(op).lower()
        return BinOp({"=>": "->", "<=>": "<->"}.get(text, text), left, right)

    def since(self, a: list) -> Formula:
        if len(a) == 4:
            (lo, hi) = a[2]
            if hi is not None and hi < lo:
                return TRUE if str(a[1]) == "T" else FALSE
            return Since(str(a[1]), a[0], a[3], lo, hi)
        return Since(str(a[1]), a[0], a[2])

    def not_(self, a: list) -> Formula:
        return Not(a[-1])

    def uminus(self, a: list) -> Formula:
        if isinstance(a[-1], Const) and not isinstance(a[-1].value, bool):
            return Const(-a[-1].value)
        return Neg(a[-1])

    def past(self, a: list) -> Formula:
        op = str(a[0])
        if len(a) == 3:
            lo, hi = a[1]
            if op in ("Y", "Z"):
                raise FormulaSyntaxError(f"{op} takes no time bounds")
            if hi is not None and hi < lo:  # empty window: FRET prints O[0,-1] for 'within 0'
                return TRUE if op == "H" else FALSE
            return Past(op, a[2], lo, hi)
        return Past(op, a[1])

    def bounds(self, a: list) -> tuple[int, int | None]:
        if any(len(str(x)) > MAX_NUMBER_CHARS for x in a):
            raise FormulaSyntaxError("time bound too long")
        lo = int(a[0])
        hi = int(a[1]) if len(a) > 1 else None
        if lo < 0:
            raise FormulaSyntaxError(f"malformed time bounds [{lo},{hi}]")
        return lo, hi

    def cmp_bounds(self, a: list) -> tuple[int, int]:
        # Older FRET versions: [<=n] is [0,n], [<n] is [0,n-1], [=n] is [n,n].
        text = str(a[0])
        op = "<=" if text.startswith("<=") else text[0]
        n = text[len(op) :].strip()
        if not n.isdigit() or len(n) > MAX_NUMBER_CHARS:
            raise FormulaSyntaxError(
                f"malformed time bounds [{text}] (FRET writes these for non-integer durations)"
            )
        return {"<=": (0, int(n)), "<": (0, int(n) - 1), "=": (int(n), int(n))}[op]

    def true(self, _: list) -> Formula:
        return TRUE

    def false(self, _: list) -> Formula:
        return FALSE

    def number(self, a: list) -> Formula:
        text = str(a[0])
        if len(text) > MAX_NUMBER_CHARS:
            raise FormulaSyntaxError(f"number '{text[:20]}...' is too long")
        if any(c in text for c in ".eE"):
            return Const(float(text))
        return Const(int(text))

    def var(self, a: list[Token]) -> Formula:
        if str(a[0]) == "FTP":  # FRET's "first time point" constant
            return FTP
        return Var(user_name(str(a[0])))

    def quoted_var(self, a: list[Token]) -> Formula:
        return Var(str(a[0])[1:-1])

    def call(self, a: list) -> Formula:
        return arith_call(str(a[0]), a[1:], FormulaSyntaxError)


# The rules of _GRAMMAR that nest (parentheses alone add no level).
_NESTING_RULES = EXPRESSION_NESTING | {"since", "past"}


@cache
def _parser() -> Lark:
    return expression_parser(_GRAMMAR)


def parse_formula(text: str) -> Formula:
    """Parse FRET past-time syntax (what FRET prints as ``ptLTL``/``pt``)."""
    from lark.exceptions import LarkError, VisitError

    parser = _parser()  # outside the try: a wrong lark is not a syntax error
    try:
        tree = parser.parse(text)
        if too_deep(tree, _NESTING_RULES) is not None:
            raise FormulaSyntaxError(f"nested more than {MAX_DEPTH} operators deep")
        return _Build().transform(tree)
    except VisitError as e:
        if isinstance(e.orig_exc, FormulaSyntaxError):
            raise e.orig_exc from None
        raise
    except LarkError as e:
        raise FormulaSyntaxError(str(e).splitlines()[0]) from None
