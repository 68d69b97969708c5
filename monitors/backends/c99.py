"""Native backend: a MonitorSpec as hard real-time C99 (``monitor.c`` + ``monitor.h``).

Interface (docs/reference/c-interface.md, Copilot-compatible): the inputs are ``extern`` globals
defined by the host; ``step()`` (``<prefix>_step``) evaluates every
requirement once and calls ``handler<ID>()`` where its formula is false;
``monitor_reset()`` (``<prefix>_reset``) resets everything and
``monitor_reset_<ID>()`` (``<reset name>_<ID>``) one requirement.  Each
requirement owns its temporal state (one static struct), so resetting one never
disturbs another's pending obligations.

No allocation, loops or recursion; every reset is a fixed list of assignments.
Temporal operators (arguments taken as booleans, i = current tick):

  Y a, Z a        one stored bit (initially 0 for Y, 1 for Z).
  O a             latch.   H a = !O !a.
  a S b           s := b | (a & s).   a T b = !(!a S !b).
  O[0,w] a        counter c of ticks since a last held, saturating at w+1
                  (w+1 means "not within w"): holds iff c <= w.
  a S[0,w] b      counter k = age of the newest j with b(j) and a on (j, i]:
                  k := b ? 0 : (a & k <= w ? k+1 : w+1); holds iff k <= w.
                  (If a held at i, the candidates of i-1 stay candidates, one
                  tick older; if not, only j = i can be one.)
  lo > 0          X[lo,hi] = the [0,hi-lo] version delayed by lo ticks:
                  O[lo,hi] a at i = O[0,hi-lo] a at i-lo (false while i < lo), and
                  a S[lo,hi] b = H[0,lo-1] a  &  delay_lo(a S[0,hi-lo] b),
                  where H[0,lo-1] a is a counter of consecutive ticks with a
                  (saturating at lo).  Unbounded hi: the unbounded core, delayed.
  delay_L x       a 64-bit shift register when L <= 64, else a ring buffer of L
                  bytes with a fill counter (reset = two assignments).
  H[..], T[..]    by duality with O[..] and S[..].
  preInt(init, x), preReal(init, x)
                  a typed member holding x of the previous tick and a first-tick
                  flag (initially, and after every reset, 1): the value is
                  ``first ? init : prev``, then prev := x, first := 0.  A define
                  using one is expanded into each requirement, as a temporal
                  define is, so each requirement owns (and resets) its own.

Margins (``spec.margins``; docs/reference/margins.md): the step also writes each
requirement's margin, the robustness of monitors/verify/robustness.py, into
``monitor_margins[]`` (``<prefix>_margins``).  Only the boolean subformulas the
requirement's margin reads get a margin (``_margins_needed``); a relation is the
difference of its sides as doubles; connectives are ternary min/max; Y/Z keep the
previous margin; unbounded O/H/S a running value; a lower bound of O/H is a delay
ring of margins, a bounded O/H window a ring maxed as a tree, a bounded S one slot
per candidate, each min'ed with a's margin every tick.  Windows beyond
MARGIN_WINDOW_TICKS / MARGIN_DELAY_TICKS (monitors/ir/spec.py) take their boolean
verdict's margin instead.  Margin state lives in the requirement's struct, so the
resets reset it.

Values follow monitors/interpret.py exactly: int64 arithmetic is done in
uint64_t and wrapped back without undefined behaviour, ``/`` and ``mod``
guard 0 and INT64_MIN / -1, int ``^`` (constant exponent 0..63) is unrolled
into multiplications, real ``^`` is pow() with Python's math.pow error cases,
int64-vs-double relations compare exactly (as Python does), not via a lossy
conversion.  <math.h> is not included (its many names, e.g. ``log``, would
clash with input names); pow/fmod and the math functions a formula calls
(sqrt, sin, ..., fabs for a real abs) are declared directly, which C99 7.1.4
allows, and an input named like one of those is an error.  int64 abs/min/max
are branch-free ternaries (abs wraps INT64_MIN to itself); real min/max are
the same ternaries as the interpreter's, not fmin/fmax; ``ite`` is C's ``?:``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from monitors.errors import UserError
from monitors.ir.formula import (
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
    is_temporal,
    subterms,
    to_fret,
)
from monitors.ir.spec import (
    C_TYPES,
    MonitorSpec,
    RequirementSpec,
    c_name,
    expand_defines,
    margin_falls_back,
)

INT64_MIN = -(1 << 63)
INT64_MAX = (1 << 63) - 1
# Longest delay line the layout can index (uint32_t position and fill count).  What
# the config allows is the memory limit checked before generation (``state_bytes``).
MAX_DELAY = (1 << 32) - 1
# (size, alignment) of each state member's C type on the LP64 and ILP32 ABIs we build for.
_C_SIZE = {
    "bool": (1, 1), "uint8_t": (1, 1), "uint32_t": (4, 4), "uint64_t": (8, 8),
    "int64_t": (8, 8), "double": (8, 8),
}  # fmt: skip

# Identifiers the generated C (or the host shim) declares itself.
_RESERVED = re.compile(
    r"ss_\w*|pow|fmod|memcpy|u?int(8|16|32|64|ptr|max)_t|u?int_(least|fast)(8|16|32|64)_t"
    r"|U?INT\w*_(MAX|MIN|C)|(PTRDIFF|SIZE|SIG_ATOMIC|WCHAR|WINT)_(MAX|MIN)"
    r"|__bool_true_false_are_defined"
)
_C_REL = {"=": "==", "!=": "!=", "<": "<", "<=": "<=", ">": ">", ">=": ">="}
# ss__cmp_id result bits: 1 less, 2 equal, 4 greater, 0 unordered (NaN).
_REL_MASK = {"<": 1, "<=": 3, "=": 2, ">": 4, ">=": 6}
_MIRROR = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "=": "=", "!=": "!="}

_HELPERS: dict[str, str] = {
    "wrap": """/* uint64_t -> int64_t two's complement, without implementation-defined casts */
static int64_t ss__wrap(uint64_t u)
{
    return u <= (uint64_t)INT64_MAX ? (int64_t)u : -(int64_t)(~u) - 1;
}""",
    "div": """/* '/' truncates; x / 0 = 0; INT64_MIN / -1 wraps (C would trap) */
static int64_t ss__div(int64_t a, int64_t b)
{
    if (b == 0) {
        return 0;
    }
    if (b == -1) {
        return ss__wrap(0u - (uint64_t)a);
    }
    return a / b;
}""",
    "mod": """/* 'mod' has the dividend's sign; x mod 0 = 0; x mod -1 = 0 (C traps on INT64_MIN % -1) */
static int64_t ss__mod(int64_t a, int64_t b)
{
    if (b == 0 || b == -1) {
        return 0;
    }
    return a % b;
}""",
    "cmp_id": """/* Exact int64-vs-double comparison (as Python compares): 1 a<b, 2 a==b, 4 a>b, 0 NaN */
static int ss__cmp_id(int64_t a, double b)
{
    int64_t t;
    double frac;
    if (b != b) {
        return 0;
    }
    if (b >= 9223372036854775808.0) {
        return 1;
    }
    if (b < -9223372036854775808.0) {
        return 4;
    }
    t = (int64_t)b;
    if (a != t) {
        return a < t ? 1 : 4;
    }
    frac = b - (double)t;
    return frac > 0.0 ? 1 : (frac < 0.0 ? 4 : 2);
}""",
    "minf": """/* margins' infinity: a constant, so that an atom's margin costs no call */
static const double ss__m_inf = 1e308 * 10.0;""",
    "inf": """static double ss__inf(void)
{
    return 1e308 * 10.0;
}""",
    "fmod": "double fmod(double x, double y);",
    "pow": """double pow(double x, double y);

/* C's pow, except where Python's math.pow raises for finite operands (overflow, 0 to a
   negative power, negative base to a fraction): inf when a > 0, else NaN, as the
   reference interpreter defines it */
static double ss__pow(double a, double b)
{
    const double r = pow(a, b);
    if (a - a == 0.0 && b - b == 0.0 && !(r - r == 0.0)) {
        return a > 0.0 ? r : r - r;
    }
    return r;
}""",
}
# The C library functions a formula's calls use (declared, not #included).
_C_MATH = {
    "abs": "fabs", "sqrt": "sqrt", "exp": "exp", "log": "log", "sin": "sin", "cos": "cos",
    "tan": "tan", "asin": "asin", "acos": "acos", "atan": "atan", "floor": "floor",
    "ceil": "ceil",
}  # fmt: skip
_HELPERS.update({f"fn_{c}": f"double {c}(double x);" for c in _C_MATH.values()})
_C_MATH2 = {"hypot": "hypot"}  # two double arguments
_HELPERS.update({f"fn_{c}": f"double {c}(double x, double y);" for c in _C_MATH2.values()})
_HELPER_DEPS = {"div": ("wrap",)}


def _math_names(spec: MonitorSpec) -> set[str]:
    """The C math functions the spec's formulas may call on doubles."""
    formulas = [r.formula for r in spec.requirements] + [d.expr for d in spec.defines]
    return {
        {**_C_MATH, **_C_MATH2}[g.name]
        for f in formulas
        for g in subterms(f)
        if isinstance(g, Call) and (g.name in _C_MATH or g.name in _C_MATH2)
    }


def reset_each_name(spec: MonitorSpec, req: RequirementSpec) -> str:
    """C name of the function that resets one requirement's streams."""
    return f"{spec.reset_name}_{c_name(req.id)}"


def _comment(text: str) -> str:
    """``text`` inside one line's block comment, whatever it holds: printable
    ASCII only (a newline or a backslash before one would end or splice the
    line), and no ``*/``."""
    if not all(" " <= c <= "~" and c != "\\" for c in text):
        text = "".join(c if " " <= c <= "~" and c != "\\" else f"<U+{ord(c):04X}>" for c in text)
    return text.replace("*/", "* /")


def _as_bool(e: str, t: str) -> str:
    return e if t == "bool" else f"({e} != 0)"


def _as_int(e: str, t: str) -> str:
    return e if t == "int64" else f"((int64_t){e})"


def _as_double(e: str, t: str) -> str:
    return e if t == "double" else f"((double){e})"


def _ulit(n: int, ctype: str) -> str:
    return f"{n}u" if ctype == "uint32_t" else f"UINT64_C({n})"


def _const_type(v: bool | int | float) -> str:
    return "bool" if isinstance(v, bool) else "int64" if isinstance(v, int) else "double"


def _counter_type(limit: int) -> str:
    return "uint32_t" if limit < (1 << 32) - 1 else "uint64_t"


@dataclass
class _Req:
    """Code for one requirement: its private state struct and its step block."""

    index: int
    fields: list[str] = field(default_factory=list)  # struct member declarations
    layout: list[tuple[str, int]] = field(default_factory=list)  # (C type, array length)
    inits: list[tuple[str, str]] = field(default_factory=list)  # (member, initial value)
    body: list[str] = field(default_factory=list)
    margin_bytes: int = 0  # of the members only margins need
    margin_fallbacks: list[str] = field(default_factory=list)  # windows kept as booleans

    @property
    def struct(self) -> str:
        return f"ss__r{self.index}"

    @property
    def size(self) -> int:
        """sizeof the state struct: members in order, each at its alignment, the
        whole rounded up to the largest alignment (C99 6.7.2.1)."""
        offset, align = 0, 1
        for ctype, length in self.layout:
            size, a = _C_SIZE[ctype]
            offset = -(-offset // a) * a + size * length
            align = max(align, a)
        return -(-offset // align) * align if self.layout else 0


class _Gen:
    def __init__(self, spec: MonitorSpec) -> None:
        self.spec = spec
        self.helpers: set[str] = set()
        self.n = 0
        self.env: dict[str, str] = {}  # formula variable -> type
        self.names: dict[str, str] = {}  # formula variable -> C expression
        self.define_decls: list[str] = []  # file-scope values of the defines
        self.margin_names: dict[str, str] = {}  # boolean define -> C name of its margin
        self._check_names()
        if spec.margins:
            if spec.bool_margin == float("inf"):
                self.use("minf")
                self.bm, self.neg_bm = "ss__m_inf", "(-ss__m_inf)"
            else:
                self.bm = self.const(float(spec.bool_margin))
                self.neg_bm = self.const(-float(spec.bool_margin))
            # a static initializer needs a constant expression: no ss__inf() call
            self.neg_inf_init = "(-1e308 * 10.0)"

    # ------------------------------------------------------------ names
    def _check_names(self) -> None:
        seen: dict[str, str] = {}

        def claim(cname: str, what: str) -> None:
            if _RESERVED.fullmatch(cname):
                raise UserError(
                    f"{what} has the C name '{cname}', which the generated C reserves",
                    hint="rename it",
                )
            if cname in seen:
                raise UserError(f"{what} and {seen[cname]} both become '{cname}' in C")
            seen[cname] = what

        spec = self.spec
        for v in spec.inputs:
            if v.type not in C_TYPES:
                raise UserError(f"input '{v.name}' has unknown type '{v.type}'")
            claim(c_name(v.name), f"input '{v.name}'")
            self.env[v.name] = v.type
            self.names[v.name] = c_name(v.name)
        for d in spec.defines:
            claim(c_name(d.name), f"internal variable '{d.name}'")
        claim(spec.step_name, "the step function")
        if spec.margins:
            claim(margins_name(spec), "the margins array")
        claim(spec.reset_name, "the reset function")
        for r in spec.requirements:
            claim(c_name(r.handler), f"handler of requirement '{r.id}'")
            claim(reset_each_name(spec, r), f"reset function of requirement '{r.id}'")
        for fn in sorted(_math_names(spec)):
            if fn in seen:
                raise UserError(
                    f"{seen[fn]} has the C name '{fn}', the C math function a formula calls",
                    hint="rename it",
                )

    def fresh(self) -> str:
        self.n += 1
        return f"ss__v{self.n}"

    def use(self, helper: str) -> None:
        self.helpers.add(helper)
        for dep in _HELPER_DEPS.get(helper, ()):
            self.helpers.add(dep)

    # ------------------------------------------------------------ types
    def node_type(self, g: Formula, vals: dict[Formula, tuple[str, str]]) -> str:
        """Type from the children's entries in ``vals`` (as the interpreter does)."""
        match g:
            case Neg(a):
                return "double" if vals[a][1] == "double" else "int64"
            case BinOp(op, a, b) if op in ARITH_OPS:
                return "double" if "double" in (vals[a][1], vals[b][1]) else "int64"
            case Call("ite", (_, a, b)):
                ta, tb = vals[a][1], vals[b][1]
                if ta == tb == "bool":
                    return "bool"
                return "double" if "double" in (ta, tb) else "int64"
            case Call(name, args):
                ints = all(vals[a][1] != "double" for a in args)
                return "int64" if name in INT_FUNCTIONS and ints else "double"
            case Pre(name):
                return "int64" if name == "preInt" else "double"
        return "bool"

    # ------------------------------------------------------------ values
    def const(self, v: bool | int | float) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            if not INT64_MIN <= v <= INT64_MAX:
                raise UserError(f"integer constant {v} does not fit in int64")
            if v == INT64_MIN:
                return "(-INT64_C(9223372036854775807) - 1)"
            return f"INT64_C({v})" if v >= 0 else f"(-INT64_C({-v}))"
        if v != v:
            self.use("inf")
            return "(ss__inf() - ss__inf())"
        if v in (float("inf"), float("-inf")):
            self.use("inf")
            return "ss__inf()" if v > 0 else "(-ss__inf())"
        text = float(v).hex()  # exact: C99 hexadecimal floating constant
        return f"({text})" if text.startswith("-") else text

    def expr(self, g: Formula, vals: dict[Formula, tuple[str, str]], body: list[str]) -> str:
        """C expression for a non-temporal node (children already in ``vals``)."""
        match g:
            case Not(a):
                return f"(!{_as_bool(*vals[a])})"
            case Neg(a):
                e, t = vals[a]
                if t == "double":
                    return f"(-{e})"
                self.use("wrap")
                return f"ss__wrap(0u - (uint64_t){_as_int(e, t)})"
            case BinOp(op, a, b) if op in BOOL_OPS:
                x, y = _as_bool(*vals[a]), _as_bool(*vals[b])
                return {
                    "&": f"({x} && {y})",
                    "|": f"({x} || {y})",
                    "xor": f"({x} != {y})",
                    "->": f"(!{x} || {y})",
                    "<->": f"({x} == {y})",
                }[op]
            case BinOp(op, a, b) if op in REL_OPS:
                return self.relation(op, vals[a], vals[b])
            case BinOp(op, a, b) if op in ARITH_OPS:
                return self.arith(op, g, vals[a], vals[b], body)
            case Call(name, args):
                return self.call(name, [vals[a] for a in args], self.node_type(g, vals))
        raise TypeError(f"not a formula node: {g!r}")

    def call(self, name: str, args: list[tuple[str, str]], result: str) -> str:
        """An arithmetic function; arguments are variables or constants (no side
        effects), so a ternary may name one twice."""
        if name not in _C_MATH and name not in _C_MATH2 and name not in ("min", "max", "ite"):
            # user functions are expanded by the config before C is generated
            raise UserError(f"function {name}/{len(args)} is not defined")
        if name == "ite":
            conv = {"bool": _as_bool, "int64": _as_int, "double": _as_double}[result]
            c, a, b = _as_bool(*args[0]), conv(*args[1]), conv(*args[2])
            return f"({c} ? {a} : {b})"
        if result == "int64":
            xs = [_as_int(*a) for a in args]
            if name == "abs":
                self.use("wrap")
                return f"ss__wrap({xs[0]} < 0 ? 0u - (uint64_t){xs[0]} : (uint64_t){xs[0]})"
        else:
            xs = [_as_double(*a) for a in args]
        if name == "min":
            return f"({xs[1]} < {xs[0]} ? {xs[1]} : {xs[0]})"
        if name == "max":
            return f"({xs[1]} > {xs[0]} ? {xs[1]} : {xs[0]})"
        if name in _C_MATH2:
            self.use(f"fn_{_C_MATH2[name]}")
            return f"{_C_MATH2[name]}({xs[0]}, {xs[1]})"
        self.use(f"fn_{_C_MATH[name]}")
        return f"{_C_MATH[name]}({xs[0]})"

    def relation(self, op: str, a: tuple[str, str], b: tuple[str, str]) -> str:
        (x, tx), (y, ty) = a, b
        if "double" not in (tx, ty):
            return f"({_as_int(x, tx)} {_C_REL[op]} {_as_int(y, ty)})"
        if tx != "int64" and ty != "int64":  # double or bool: converting is exact
            return f"({_as_double(x, tx)} {_C_REL[op]} {_as_double(y, ty)})"
        if tx == "double":  # put the int64 on the left
            (x, tx), (y, ty), op = (y, ty), (x, tx), _MIRROR[op]
        self.use("cmp_id")
        if op == "!=":
            return f"((ss__cmp_id({x}, {y}) & 2) == 0)"
        return f"((ss__cmp_id({x}, {y}) & {_REL_MASK[op]}) != 0)"

    def arith(
        self, op: str, g: BinOp, a: tuple[str, str], b: tuple[str, str], body: list[str]
    ) -> str:
        (x, tx), (y, ty) = a, b
        if "double" in (tx, ty):
            x, y = _as_double(x, tx), _as_double(y, ty)
            if op == "mod":
                self.use("fmod")
                return f"fmod({x}, {y})"
            if op == "^":
                self.use("pow")
                return f"ss__pow({x}, {y})"
            return f"({x} {op} {y})"
        x, y = _as_int(x, tx), _as_int(y, ty)
        self.use("wrap")
        if op in ("+", "-", "*"):
            return f"ss__wrap((uint64_t){x} {op} (uint64_t){y})"
        if op in ("/", "mod"):
            self.use("div" if op == "/" else "mod")
            return f"ss__{'div' if op == '/' else 'mod'}({x}, {y})"
        # int ^: constant exponent, unrolled square-and-multiply in uint64_t
        e = g.right.value if isinstance(g.right, Const) else None
        if not isinstance(e, int) or not 0 <= e <= 63:
            raise UserError(
                f"integer '^' needs a constant exponent from 0 to 63: {to_fret(g)}",
                hint="write the power as a product, or use a real base",
            )
        factors: list[str] = []
        square = self.fresh()
        body.append(f"const uint64_t {square} = (uint64_t){x};")
        bit = 1
        while True:
            if e & bit:
                factors.append(square)
            if e < bit * 2:
                break
            nxt = self.fresh()
            body.append(f"const uint64_t {nxt} = {square} * {square};")
            square, bit = nxt, bit * 2
        if not factors:
            factors.append("1u")
        return f"ss__wrap({' * '.join(factors)})"

    # ------------------------------------------------------------ state
    def member(
        self,
        req: _Req,
        ctype: str,
        init: str | None,
        length: int | None = None,
        *,
        margin: bool = False,
    ) -> str:
        name = f"f{len(req.fields)}"
        if margin:
            req.margin_bytes += _C_SIZE[ctype][0] * (1 if length is None else length)
        req.fields.append(f"{ctype} {name}{'' if length is None else f'[{length}]'};")
        req.layout.append((ctype, 1 if length is None else length))
        if init is not None:
            req.inits.append((name, init))
        return f"{req.struct}.{name}"

    def local(self, req: _Req, e: str) -> str:
        v = self.fresh()
        req.body.append(f"const bool {v} = {e};")
        return v

    def delay(self, req: _Req, x: str, length: int) -> str:
        """x as it was ``length`` ticks ago (false before tick ``length``)."""
        if length <= 64:
            r = self.member(req, "uint64_t", "0u")
            out = self.local(req, f"(({r} >> {length - 1}) & 1u) != 0")
            req.body.append(f"{r} = ({r} << 1) | ({x} ? 1u : 0u);")
            return out
        buf = self.member(req, "uint8_t", None, length)
        idx = self.member(req, "uint32_t", "0u")
        fill = self.member(req, "uint32_t", "0u")
        out = self.local(req, f"({fill} == {length}u) && ({buf}[{idx}] != 0u)")
        req.body.append(f"{buf}[{idx}] = {x} ? 1u : 0u;")
        req.body.append(f"{idx} = ({idx} + 1u == {length}u) ? 0u : {idx} + 1u;")
        req.body.append(f"{fill} = ({fill} == {length}u) ? {fill} : {fill} + 1u;")
        return out

    def once(self, req: _Req, x: str, lo: int, hi: int | None) -> str:
        """O[lo,hi] x."""
        if hi is None:
            latch = self.member(req, "bool", "false")
            req.body.append(f"{latch} = {latch} || {x};")
            core = self.local(req, latch)
        else:
            w = hi - lo
            t = _counter_type(w + 1)
            c = self.member(req, t, _ulit(w + 1, t))
            req.body.append(
                f"{c} = {x} ? {_ulit(0, t)} : (({c} <= {_ulit(w, t)}) ? {c} + 1u : {c});"
            )
            core = self.local(req, f"{c} <= {_ulit(w, t)}")
        return self.delay(req, core, lo) if lo > 0 else core

    def since(self, req: _Req, a: str, b: str, lo: int, hi: int | None) -> str:
        """a S[lo,hi] b."""
        if hi is None:
            s = self.member(req, "bool", "false")
            req.body.append(f"{s} = {b} || ({a} && {s});")
            core = self.local(req, s)
        else:
            w = hi - lo
            t = _counter_type(w + 1)
            k = self.member(req, t, _ulit(w + 1, t))
            req.body.append(
                f"{k} = {b} ? {_ulit(0, t)} : (({a} && {k} <= {_ulit(w, t)}) ? {k} + 1u : "
                f"{_ulit(w + 1, t)});"
            )
            core = self.local(req, f"{k} <= {_ulit(w, t)}")
        if lo == 0:
            return core
        t = _counter_type(lo)
        n = self.member(req, t, _ulit(0, t))
        req.body.append(f"{n} = {a} ? (({n} < {_ulit(lo, t)}) ? {n} + 1u : {n}) : {_ulit(0, t)};")
        delayed = self.delay(req, core, lo)
        return self.local(req, f"({n} >= {_ulit(lo, t)}) && {delayed}")

    def temporal(self, req: _Req, g: Past | Since, vals: dict[Formula, tuple[str, str]]) -> str:
        lo = g.lo or 0
        if isinstance(g, Past):
            a = _as_bool(*vals[g.arg])
            if g.op in ("Y", "Z"):
                prev = self.member(req, "bool", "false" if g.op == "Y" else "true")
                out = self.local(req, prev)
                req.body.append(f"{prev} = {a};")
                return out
            if g.hi is not None and g.hi < lo:  # empty window
                return "false" if g.op == "O" else "true"
            if g.op == "O":
                return self.once(req, a, lo, g.hi)
            return self.local(req, f"!{self.once(req, f'(!{a})', lo, g.hi)}")
        a, b = _as_bool(*vals[g.left]), _as_bool(*vals[g.right])
        if g.hi is not None and g.hi < lo:
            return "false" if g.op == "S" else "true"
        if g.op == "S":
            return self.since(req, a, b, lo, g.hi)
        return self.local(req, f"!{self.since(req, f'(!{a})', f'(!{b})', lo, g.hi)}")

    def pre(self, req: _Req, g: Pre, vals: dict[Formula, tuple[str, str]]) -> str:
        """preInt/preReal: init at the first tick after a reset, the argument's
        previous value afterwards (see the module docstring)."""
        t = "int64" if g.name == "preInt" else "double"
        (x, tx), (i, ti) = vals[g.arg], vals[g.init]
        if t == "int64" and "double" in (tx, ti):
            # converting a double to int64 is undefined for NaN and large values
            raise UserError(f"preInt needs int64 values: {to_fret(g)}", hint="use preReal")
        conv = _as_int if t == "int64" else _as_double
        prev = self.member(req, C_TYPES[t], "0" if t == "int64" else "0.0")
        first = self.member(req, "bool", "true")
        out = self.fresh()
        req.body.append(f"const {C_TYPES[t]} {out} = {first} ? {conv(i, ti)} : {prev};")
        req.body.append(f"{prev} = {conv(x, tx)};")
        req.body.append(f"{first} = false;")
        return out

    # ------------------------------------------------------------ requirements
    def node(
        self, g: Formula, vals: dict[Formula, tuple[str, str]], req: _Req | None, body: list[str]
    ) -> tuple[str, str]:
        match g:
            case Const(v):
                return self.const(v), _const_type(v)
            case Var(name):
                if name not in self.names:
                    raise UserError(f"unknown variable '{name}'")
                return self.names[name], self.env[name]
            case Past() | Since():
                assert req is not None
                return self.temporal(req, g, vals), "bool"
            case Pre(name):
                # _define_plan expands stateful defines into the requirements
                assert req is not None
                return self.pre(req, g, vals), "int64" if name == "preInt" else "double"
        t = self.node_type(g, vals)
        e = self.expr(g, vals, body)
        v = self.fresh()
        body.append(f"const {C_TYPES[t]} {v} = {e};")
        return v, t

    def formula(
        self, f: Formula, req: _Req | None, body: list[str]
    ) -> tuple[tuple[str, str], str | None]:
        """(C value and type of ``f``, C name of its margin when the spec asks for
        margins and ``f`` is boolean)."""
        vals: dict[Formula, tuple[str, str]] = {}
        margins: dict[Formula, str] = {}
        needed = _margins_needed(f) if self.spec.margins else set()
        for g in subterms(f):
            vals[g] = self.node(g, vals, req, body)
            if g in needed and vals[g][1] == "bool":
                margins[g] = self.margin(g, vals, margins, req, body)
        return vals[f], margins.get(f)

    # ------------------------------------------------------------ margins
    # The quantitative semantics of monitors/verify/robustness.py, value for value
    # (docs/reference/margins.md); every window is a fixed list of assignments.
    def mlocal(self, body: list[str], e: str) -> str:
        v = self.fresh()
        body.append(f"const double {v} = {e};")
        return v

    def atom(self, e: str, t: str) -> str:
        return f"({_as_bool(e, t)} ? {self.bm} : {self.neg_bm})"

    def mmin(self, body: list[str], x: str, y: str) -> str:
        return self.mlocal(body, f"({y} < {x} ? {y} : {x})")

    def mmax(self, body: list[str], x: str, y: str) -> str:
        return self.mlocal(body, f"({y} > {x} ? {y} : {x})")

    def margin(
        self,
        g: Formula,
        vals: dict[Formula, tuple[str, str]],
        ms: dict[Formula, str],
        req: _Req | None,
        body: list[str],
    ) -> str:
        match g:
            case Not(a):
                return self.mlocal(body, f"(-{ms[a]})")
            case BinOp(op, a, b) if op in BOOL_OPS:
                x, y = ms[a], ms[b]
                if op == "&":
                    return self.mmin(body, x, y)
                if op == "|":
                    return self.mmax(body, x, y)
                nx = self.mlocal(body, f"(-{x})")
                if op == "->":
                    return self.mmax(body, nx, y)
                ny = self.mlocal(body, f"(-{y})")
                if op == "<->":
                    return self.mmin(body, self.mmax(body, nx, y), self.mmax(body, x, ny))
                return self.mmax(body, self.mmin(body, x, ny), self.mmin(body, nx, y))
            case BinOp(op, a, b) if op in REL_OPS:
                return self.relation_margin(op, vals[a], vals[b], vals[g], body)
            case Var(name) if name in self.margin_names:
                return self.margin_names[name]
            case Past() | Since() if margin_falls_back(g):
                assert req is not None
                req.margin_fallbacks.append(to_fret(g))
                return self.mlocal(body, self.atom(*vals[g]))
            case Past() | Since() if g.hi is not None and g.hi < (g.lo or 0):
                return self.mlocal(body, self.atom(*vals[g]))  # empty window: a constant
            case Past(op, a) if op in ("Y", "Z"):
                assert req is not None
                init = self._init_const(self.neg_bm if op == "Y" else self.bm)
                prev = self.member(req, "double", init, margin=True)
                out = self.mlocal(body, prev)
                body.append(f"{prev} = {ms[a]};")
                return out
            case Past(op, a, lo, hi):
                assert req is not None
                x = ms[a] if op == "O" else self.mlocal(body, f"(-{ms[a]})")
                got = self.window_max(req, body, x, lo or 0, hi)
                return got if op == "O" else self.mlocal(body, f"(-{got})")
            case Since(op, a, b, lo, hi):
                assert req is not None
                x, y = ms[a], ms[b]
                if op == "T":
                    x, y = self.mlocal(body, f"(-{x})"), self.mlocal(body, f"(-{y})")
                got = self.since_margin(req, body, x, y, lo or 0, hi)
                return got if op == "S" else self.mlocal(body, f"(-{got})")
        return self.mlocal(body, self.atom(*vals[g]))  # a boolean atom

    def _init_const(self, c: str) -> str:
        """``c`` as a static initializer may hold it (no ss__inf() call)."""
        return {"ss__m_inf": "(1e308 * 10.0)", "(-ss__m_inf)": self.neg_inf_init}.get(c, c)

    def relation_margin(
        self, op: str, a: tuple[str, str], b: tuple[str, str], rel: tuple[str, str], body: list[str]
    ) -> str:
        (x, tx), (y, ty) = a, b
        if tx == ty == "bool":
            return self.mlocal(body, self.atom(*rel))
        dx = self.mlocal(body, _as_double(x, tx))
        dy = self.mlocal(body, _as_double(y, ty))
        if op in ("<", "<="):
            d = self.mlocal(body, f"({dy} - {dx})")
        elif op in (">", ">="):
            d = self.mlocal(body, f"({dx} - {dy})")
        else:
            t = self.mlocal(body, f"({dx} - {dy})")
            d = self.mlocal(
                body, f"({t} < 0 ? {t} : -{t})" if op == "=" else f"({t} < 0 ? -{t} : {t})"
            )
        if "double" not in (tx, ty):
            return d  # int64 and bool convert to finite doubles: never NaN
        # NaN: two equal infinities are 0 apart; a NaN operand is a boolean atom
        return self.mlocal(body, f"({d} == {d} ? {d} : ({dx} == {dy} ? 0.0 : {self.atom(*rel)}))")

    def _slots(self, req: _Req, count: int) -> tuple[str, str]:
        """``count`` stored margins, newest first (-inf until filled), and how many
        ticks have filled them (saturating at ``count``), updated first."""
        buf = self._array(req, count)
        n = self.member(req, "uint32_t", "0u", margin=True)
        req.body.append(f"{n} = ({n} < {count}u) ? {n} + 1u : {n};")
        return buf, n

    def _array(self, req: _Req, length: int) -> str:
        """``length`` stored margins, -inf until written."""
        buf = self.member(req, "double", None, length, margin=True)
        req.inits += [(f"{buf.split('.')[-1]}[{k}]", self.neg_inf_init) for k in range(length)]
        return buf

    def _ring(
        self, req: _Req, body: list[str], x: str, length: int, *, read: bool = False
    ) -> tuple[str, str | None]:
        """A ring of the last ``length`` values of ``x`` (-inf before them): (the
        array, with ``read`` the value ``x`` had ``length`` ticks ago), one write
        per tick."""
        buf = self._array(req, length)
        pos = self.member(req, "uint32_t", "0u", margin=True)
        old = self.mlocal(body, f"{buf}[{pos}]") if read else None
        body.append(f"{buf}[{pos}] = {x};")
        body.append(f"{pos} = ({pos} + 1u == {length}u) ? 0u : {pos} + 1u;")
        return buf, old

    def _tree_max(self, body: list[str], items: list[str]) -> str:
        """max of ``items`` pairwise: log2(n) dependent comparisons, not n (no
        margin is NaN, so the order does not change the value)."""
        while len(items) > 1:
            pairs = [self.mmax(body, a, b) for a, b in zip(items[::2], items[1::2], strict=False)]
            items = pairs + items[len(pairs) * 2 :]
        return items[0]

    def _window(self, body: list[str], start: str, slots: list[str], n: str, lo: int) -> str:
        """max of ``start`` and ``slots``; -bool_margin while i < lo (fewer than
        lo + 1 ticks seen: the window is empty)."""
        best = self._tree_max(body, [start, *slots])
        return self.mlocal(body, f"({n} > {lo}u) ? {best} : {self.neg_bm}")

    def window_max(self, req: _Req, body: list[str], x: str, lo: int, hi: int | None) -> str:
        """O[lo,hi] over the margins ``x``: ``x`` delayed by lo ticks (a ring of lo),
        then the running max (unbounded) or the max of a ring of hi - lo + 1."""
        if lo > 0:
            n = self.member(req, "uint32_t", "0u", margin=True)
            body.append(f"{n} = ({n} <= {lo}u) ? {n} + 1u : {n};")
            _, delayed = self._ring(req, body, x, lo, read=True)
            assert delayed is not None
            x = delayed
        if hi is None:
            m = self.member(req, "double", self.neg_inf_init, margin=True)
            body.append(f"{m} = ({x} > {m} ? {x} : {m});")
            best = m
        else:
            w = hi - lo + 1
            buf, _ = self._ring(req, body, x, w)
            best = self._tree_max(body, [f"{buf}[{k}]" for k in range(w)])
        if lo == 0:  # the window holds this tick: never empty
            return self.mlocal(body, best)
        return self.mlocal(body, f"({n} > {lo}u) ? {best} : {self.neg_bm}")

    def since_margin(
        self, req: _Req, body: list[str], x: str, y: str, lo: int, hi: int | None
    ) -> str:
        """a S[lo,hi] b over the margins ``x`` (a) and ``y`` (b): slot k holds
        min(b at i-k, a over (i-k, i])."""
        if hi is None and lo == 0:
            s = self.member(req, "double", self.neg_inf_init, margin=True)
            t = self.mmin(body, x, s)
            body.append(f"{s} = ({t} > {y} ? {t} : {y});")
            return self.mlocal(body, s)
        count = (hi if hi is not None else lo) + 1
        buf, n = self._slots(req, count)
        r = None
        if hi is None:
            # the candidates older than lo ticks, each min'ed with a at every tick since
            r = self.member(req, "double", self.neg_inf_init, margin=True)
            older = self.mmax(body, r, f"{buf}[{lo}]")
            body.append(f"{r} = ({x} < {older} ? {x} : {older});")
        for k in range(count - 1, 0, -1):
            body.append(f"{buf}[{k}] = ({x} < {buf}[{k - 1}] ? {x} : {buf}[{k - 1}]);")
        body.append(f"{buf}[0] = {y};")
        if hi is not None:
            rest = [f"{buf}[{k}]" for k in range(lo + 1, hi + 1)]
            return self._window(body, f"{buf}[{lo}]", rest, n, lo)
        assert r is not None
        return self._window(body, r, [f"{buf}[{lo}]"], n, lo)


def _margins_needed(f: Formula) -> set[Formula]:
    """The subformulas whose margins ``f``'s margin reads: through the boolean
    connectives and the temporal operators that keep their margins (a relation
    reads values, an atom or a fallen-back window its verdict)."""
    needed: set[Formula] = set()
    stack = [f]
    while stack:
        g = stack.pop()
        if g in needed:
            continue
        needed.add(g)
        match g:
            case Not() | BinOp(op=("&" | "|" | "xor" | "->" | "<->")):
                stack.extend(g.children())
            case Past() | Since() if not margin_falls_back(g):
                if g.hi is None or g.hi >= (g.lo or 0):
                    stack.extend(g.children())
    return needed


def _stateful(f: Formula) -> bool:
    """Whether ``f`` keeps state between ticks: a temporal operator or a previous
    value (preInt/preReal), which a define must not share between requirements."""
    return is_temporal(f)


def _define_plan(spec: MonitorSpec) -> tuple[list, list[Formula]]:
    """(non-temporal defines used, in dependency order; requirement formulas with the
    temporal defines expanded, so that each requirement owns their state)."""
    by_name = {d.name: d for d in spec.defines}
    temporal = [d for d in spec.defines if _stateful(expand_defines(d.expr, spec.defines))]
    formulas = [expand_defines(r.formula, temporal) for r in spec.requirements]
    order: list = []
    state: dict[str, int] = {}

    def visit(name: str) -> None:
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            raise UserError(f"internal variable '{name}' is defined in terms of itself")
        state[name] = 1
        for g in subterms(by_name[name].expr):
            if isinstance(g, Var) and g.name in by_name:
                visit(g.name)
        state[name] = 2
        order.append(by_name[name])

    for f in formulas:
        for g in subterms(f):
            if isinstance(g, Var) and g.name in by_name:
                visit(g.name)
    return order, formulas


def _requirements(spec: MonitorSpec) -> tuple[_Gen, list[str], list[Formula], list[_Req]]:
    """The generator's pass over the defines and requirements: the step code and the
    state layout.  Its cost follows the formulas' size, never their time bounds (a
    bound only becomes a number in the C text), so it is also how ``state_bytes``
    learns the layout before anything is written or compiled."""
    gen = _Gen(spec)
    defines, formulas = _define_plan(spec)
    top: list[str] = []
    for d in defines:
        (e, t), m = gen.formula(d.expr, None, top)
        # file scope: each requirement's own function reads it (see generate)
        gen.define_decls.append(f"static {C_TYPES[t]} {c_name(d.name)};")
        top.append(f"{c_name(d.name)} = {e};")
        gen.env[d.name], gen.names[d.name] = t, c_name(d.name)
        if m is not None:  # a boolean define's margin, read by the requirements using it
            gen.margin_names[d.name] = f"ss__m_{c_name(d.name)}"
            gen.define_decls.append(f"static double {gen.margin_names[d.name]};")
            top.append(f"{gen.margin_names[d.name]} = {m};")
    reqs: list[_Req] = []
    for i, (r, f) in enumerate(zip(spec.requirements, formulas, strict=True)):
        req = _Req(i)
        (e, t), m = gen.formula(f, req, req.body)
        if m is not None:
            req.body.append(f"{margins_name(spec)}[{i}] = {m};")
        req.body.append(f"if (!{_as_bool(e, t)}) {{")
        req.body.append(f"    {c_name(r.handler)}();")
        req.body.append("}")
        reqs.append(req)
    return gen, top, formulas, reqs


def margins_name(spec: MonitorSpec) -> str:
    """C name of the array of the requirements' margins (spec order)."""
    return f"{spec.prefix}_margins" if spec.prefix else "monitor_margins"


@dataclass(frozen=True)
class MarginState:
    """What one requirement's margin costs in the C monitor (``check`` prints it)."""

    bytes: int  # state members only margins need
    fallbacks: tuple[str, ...]  # windows too long to keep: their margin is boolean


def margin_state(spec: MonitorSpec) -> dict[str, MarginState]:
    """Each requirement's margin state, by requirement id (empty without margins)."""
    if not spec.margins:
        return {}
    _, _, _, reqs = _requirements(spec)
    return {
        r.id: MarginState(req.margin_bytes, tuple(req.margin_fallbacks))
        for r, req in zip(spec.requirements, reqs, strict=True)
    }


def state_bytes(spec: MonitorSpec) -> dict[str, int]:
    """Static memory of each requirement's state struct in the generated monitor, in
    bytes (the sizes the compiler gives ``ss__r<N>``), by requirement id."""
    _, _, _, reqs = _requirements(spec)
    return {r.id: req.size for r, req in zip(spec.requirements, reqs, strict=True)}


def generate(spec: MonitorSpec) -> tuple[str, str]:
    """The text of (monitor.c, monitor.h) for ``spec``."""
    gen, top, formulas, req_list = _requirements(spec)
    reqs = list(zip(spec.requirements, req_list, strict=True))
    for r, req in reqs:
        length = max(n for _, n in req.layout) if req.layout else 0
        if length > MAX_DELAY:
            raise UserError(
                f"requirement '{r.id}' has a lower time bound of {length} ticks, longer than "
                f"a delay line can be ({MAX_DELAY} ticks)",
                hint="use a longer tick (step.period_ms) or a shorter bound",
            )

    h = _header(spec)
    c = [
        "/* Monitor generated by safety-supervisor (native C99 backend): hard real-time,",
        "   no dynamic allocation, no loops, no recursion.  Do not edit. */",
        '#include "monitor.h"',
        "",
    ]
    for name in _HELPERS:
        if name in gen.helpers:
            c += [_HELPERS[name], ""]
    for r, req in reqs:
        if not req.fields:
            continue
        c.append(f"/* state of {_comment(r.id)} */")
        c.append("static struct {")
        c += [f"    {m}" for m in req.fields]
        inits = ", ".join(f".{m} = {v}" for m, v in req.inits)
        c.append(f"}} {req.struct} = {{ {inits} }};" if inits else f"}} {req.struct};")
        c.append("")
    if gen.define_decls:
        c += ["/* the defines' values at this tick */", *gen.define_decls, ""]
    if spec.margins:
        c += [
            "/* each requirement's margin at the last step (docs/reference/margins.md) */",
            f"double {margins_name(spec)}[{max(1, len(spec.requirements))}];",
            "",
        ]
    # One function per requirement, called in order by the step: the compiler's
    # optimiser then works on many small functions instead of one of the whole set's
    # size, which keeps compile time linear in the number of requirements
    # (docs/BENCHMARKS.md, "Scaling").
    for (r, req), f in zip(reqs, formulas, strict=True):
        c.append(f"/* {_comment(r.id)}: {_comment(to_fret(f))} */")
        c += [f"static void {_step_of(req)}(void)", "{"]
        c += [f"    {s}" for s in req.body]
        c += ["}", ""]
    c += [f"void {spec.step_name}(void)", "{"]
    c += [f"    {s}" for s in top]
    c += [f"    {_step_of(req)}();" for _, req in reqs]
    c += ["}", ""]
    for r, req in reqs:
        c += [f"void {reset_each_name(spec, r)}(void)", "{"]
        c += [f"    {req.struct}.{m} = {v};" for m, v in req.inits]
        c += ["}", ""]
    c += [f"void {spec.reset_name}(void)", "{"]
    c += [f"    {reset_each_name(spec, r)}();" for r in spec.requirements]
    c += ["}", ""]
    return "\n".join(c), h


def _step_of(req: _Req) -> str:
    return f"ss__step_r{req.index}"


def _header(spec: MonitorSpec) -> str:
    h = [
        "/* Monitor interface generated by safety-supervisor (Copilot-compatible). */",
        "#ifndef SS_MONITOR_H",
        "#define SS_MONITOR_H",
        "",
        "#include <stdbool.h>",
        "#include <stdint.h>",
        "",
        "/* inputs: defined by the host, set before each step */",
    ]
    h += [f"extern {C_TYPES[v.type]} {c_name(v.name)};" for v in spec.inputs]
    h += ["", "/* called by step when the requirement is violated: defined by the host */"]
    h += [f"extern void {c_name(r.handler)}(void);" for r in spec.requirements]
    h += ["", "/* evaluate every requirement for one tick */", f"void {spec.step_name}(void);"]
    if spec.margins:
        h += [
            "",
            "/* each requirement's margin after the last step (spec order) */",
            f"extern double {margins_name(spec)}[{max(1, len(spec.requirements))}];",
        ]
    h += [
        "",
        "/* back to tick 0: everything, or one requirement */",
        f"void {spec.reset_name}(void);",
    ]
    h += [f"void {reset_each_name(spec, r)}(void);" for r in spec.requirements]
    h += ["", "#endif", ""]
    return "\n".join(h)


def write_c(spec: MonitorSpec, out_dir: Path) -> tuple[Path, Path]:
    """Write ``monitor.c`` and ``monitor.h`` into ``out_dir``; returns their paths."""
    c_text, h_text = generate(spec)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c_path, h_path = out_dir / "monitor.c", out_dir / "monitor.h"
    c_path.write_text(c_text)
    h_path.write_text(h_text)
    return c_path, h_path
