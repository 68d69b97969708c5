"""Copilot backend (``--backend copilot``): a MonitorSpec as a NASA Copilot spec.

Emits a Haskell program in the style of NASA OGMA (``extern`` streams for the
inputs, internal variables as bindings, one ``trigger "handler<ID>" (not phi) []``
per requirement, ``compileWith``), runs it with GHC to get Copilot's C99
(``<name>.c``, ``<name>.h``, ``<name>_types.h``), and builds and loads that C
through the same cffi path as the native backend.

Value semantics follow the reference interpreter (monitors/interpret.py):
- int64 ``+ - *`` and unary ``-`` are computed in Word64 and cast back, so they
  wrap instead of hitting C's signed-overflow undefined behaviour;
- Copilot's ``div``/``mod`` compile to C's ``/`` and ``%`` (truncation, sign of
  the dividend) and trap on zero and on INT64_MIN / -1: both are guarded with
  ``mux`` to give the interpreter's 0 / wrapped results;
- real ``/`` is IEEE, real ``^`` is C's pow(), as in the native backend.

Also as in the interpreter: int64 against double compares exactly (not via
C's rounding conversion), real ``^`` gives Python's inf/NaN where math.pow
raises, a bool used as a number is 0/1 and a number used as a condition is
``!= 0``.  Copilot's own Num/Integral instances are bypassed for arithmetic:
they fold constants unsoundly (``x * 0 = 0`` on doubles, Haskell's flooring
``mod`` on two constants, a reify-time error for ``div`` by constant 0).

Where Copilot cannot match (UserError, not silently different):
- real ``mod`` (C fmod): Copilot 3.13 has neither fmod nor a double-to-int cast;
- ``preInt(init, x)`` / ``preReal(init, x)`` with an init that is not a finite
  constant: Copilot's ``[init] ++ x`` takes a Haskell value, not a stream (with a
  constant init they are such a stream, shared by every requirement as the
  temporal streams are);
- the arithmetic functions (abs, min, max, sqrt, ...): their exact C semantics
  (int64 abs wrapping, NaN in min/max) are not written for Copilot yet; the
  native backend compiles them;
- an input named like a C library function (``log``, ``abs`` ...): Copilot's C
  includes <math.h>, <stdlib.h> and <string.h>; inputs named like Copilot's
  own symbols (``s0``, ``x_cpy`` ...) are rejected up front.
Size: Copilot inlines every non-stream subexpression where it is used, so
integer ``^ 63`` or deeply nested ``/`` produce large C (the native backend
uses temporaries).

Temporal operators are our own streams, not Copilot.Library.PTLTL: Copilot
3.13's library ``since`` holds at tick 0 when its second argument never held,
which is not the standard past-time since.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_OPS,
    BOOL_OPS,
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
from monitors.ir.spec import MonitorSpec, c_name

if TYPE_CHECKING:
    from monitors.backends.load import LoadedMonitor

INSTALL_HINT = (
    "install GHC and Copilot with: sudo apt-get install ghc libghc-copilot-dev (about 1 GB)"
)
COPILOT_PACKAGE = "copilot-c99"
# How GHC runs the generated program.  runghc (GHC's bytecode interpreter) is
# faster than `ghc -O0` + link + run for these one-shot programs (measured for
# the sRobot spec: ~0.5 s vs ~1-1.7 s), so it is the default.
DEFAULT_RUNNER = "runghc"

_ERR = "copilot"  # UserError 'file' for problems of the backend itself

# Names the Copilot 3.13 code generator uses for its own C symbols; an input
# with one of these names would clash in the generated C.
_COPILOT_INTERNAL = re.compile(r"^(s\d+(_idx|_get|_gen)?|.*_cpy|.*_guard|.*_arg\d+)$")

_PRELUDE = """\
-- Helpers: the standard past-time operators as plain Copilot streams.

-- Y p and Z p: p at the previous tick (false, resp. true, at tick 0).
prev, wprev :: Stream Bool -> Stream Bool
prev p = [False] ++ p
wprev p = [True] ++ p

-- H p and O p.
hist, once :: Stream Bool -> Stream Bool
hist p = h where h = p && ([True] ++ h)
once p = o where o = p || ([False] ++ o)

-- a S b (standard since: false until b has held; Language.Copilot's own `since`
-- is not) and its dual a T b.
sinceStd, trig :: Stream Bool -> Stream Bool -> Stream Bool
sinceStd a b = s where s = b || (a && ([False] ++ s))
trig a b = t where t = b && (a || ([True] ++ t))

-- p delayed by k ticks, `fill` before tick k (a Copilot buffer of k values).
delayed :: Bool -> P.Int -> Stream Bool -> Stream Bool
delayed fill k p = if k P.== 0 then p else P.replicate k fill ++ p

-- Ticks since p last held, saturating at cap (cap also means "never").
age :: Int64 -> Stream Bool -> Stream Int64
age cap p = n
  where
    n = mux p 0 (mux (before >= constant cap) (constant cap) (before + 1))
    before = [cap] ++ n

-- Consecutive ticks, up to and including now, at which a held; saturates at cap.
runLen :: Int64 -> Stream Bool -> Stream Int64
runLen cap a = n
  where
    n = mux a (mux (before >= constant cap) (constant cap) (before + 1)) 0
    before = [0] ++ n

-- O[l,l+w] p: p held between l and l+w ticks ago.
onceIn :: P.Int -> Int64 -> Stream Bool -> Stream Bool
onceIn l w p = age (w + 1) (delayed False l p) <= constant w

-- H[l,l+w] p.
histIn :: P.Int -> Int64 -> Stream Bool -> Stream Bool
histIn l w p = not (onceIn l w (not p))

-- O[l,inf] p and H[l,inf] p.
onceFrom, histFrom :: P.Int -> Stream Bool -> Stream Bool
onceFrom l p = delayed False l (once p)
histFrom l p = delayed True l (hist p)

-- a S[l,l+w] b: the latest b at least l ticks ago is at most l+w ticks ago,
-- and a held at every tick after it.
sinceIn :: P.Int -> Int64 -> Stream Bool -> Stream Bool -> Stream Bool
sinceIn l w a b = (c <= constant w) && ((constant l64 + c) <= runLen (l64 + w) a)
  where
    c = age (w + 1) (delayed False l b)
    l64 = P.fromIntegral l

-- a S[l,inf] b: a held for the last l ticks and (a S b) held l ticks ago.
sinceFrom :: P.Int -> Stream Bool -> Stream Bool -> Stream Bool
sinceFrom l a b = (runLen l64 a >= constant l64) && delayed False l (sinceStd a b)
  where
    l64 = P.fromIntegral l

-- a T[..] b = not ((not a) S[..] (not b)).
trigIn :: P.Int -> Int64 -> Stream Bool -> Stream Bool -> Stream Bool
trigIn l w a b = not (sinceIn l w (not a) (not b))

trigFrom :: P.Int -> Stream Bool -> Stream Bool -> Stream Bool
trigFrom l a b = not (sinceFrom l (not a) (not b))

-- Arithmetic as plain Copilot operator nodes.  Copilot's Num and Integral
-- instances rewrite constants by rules that are neither C's nor IEEE's
-- (x * 0 = 0 for doubles, Haskell's flooring `mod` of two constants, a
-- reify-time error for `div` by a constant 0), so formulas bypass them.
add2, sub2, mul2 :: (Core.Typed a, P.Num a) => Stream a -> Stream a -> Stream a
add2 = Op2 (Core.Add Core.typeOf)
sub2 = Op2 (Core.Sub Core.typeOf)
mul2 = Op2 (Core.Mul Core.typeOf)

fdiv2, pow2 :: Stream Double -> Stream Double -> Stream Double
fdiv2 = Op2 (Core.Fdiv Core.typeOf)
pow2 = Op2 (Core.Pow Core.typeOf)

-- Real negation: -1 * x is exact in IEEE, while Num's default 0 - x loses -0.0.
negD :: Stream Double -> Stream Double
negD = mul2 (constant (-1.0))

-- int64 arithmetic wraps like the reference interpreter: computed in Word64,
-- since signed overflow is undefined behaviour in C.
w64 :: Stream Int64 -> Stream Word64
w64 = unsafeCast

i64 :: Stream Word64 -> Stream Int64
i64 = unsafeCast

addW, subW, mulW :: Stream Int64 -> Stream Int64 -> Stream Int64
addW a b = i64 (add2 (w64 a) (w64 b))
subW a b = i64 (sub2 (w64 a) (w64 b))
mulW a b = i64 (mul2 (w64 a) (w64 b))

negW :: Stream Int64 -> Stream Int64
negW a = i64 (sub2 (constant 0) (w64 a))

-- C's / and % truncate like the interpreter but trap on zero and on
-- INT64_MIN / -1: x / 0 = x mod 0 = 0, x / -1 = -x (wrapping), x mod -1 = 0.
divW, modW :: Stream Int64 -> Stream Int64 -> Stream Int64
divW a b = mux (b == 0) 0 (mux (b == (-1)) (negW a) (Op2 (Core.Div Core.typeOf) a b))
modW a b = mux ((b == 0) || (b == (-1))) 0 (Op2 (Core.Mod Core.typeOf) a b)

-- Integer power with a constant exponent: repeated wrapping multiplication.
powW :: Stream Int64 -> P.Int -> Stream Int64
powW _ 0 = constant 1
powW a k = mulW a (powW a (k P.- 1))

toD :: Stream Int64 -> Stream Double
toD = unsafeCast

b2i :: Stream Bool -> Stream Int64
b2i = cast

-- Real power: C's pow, except where Python's math.pow raises for finite
-- operands (overflow, 0 to a negative power, ...): inf if a > 0, else NaN.
powD :: Stream Double -> Stream Double -> Stream Double
powD a b = mux (finite a && finite b && not (finite r)) (mux (a > 0.0) r (sub2 r r)) r
  where
    r = pow2 a b
    finite x = sub2 x x == 0.0

-- int64 `op` double, exact as Python compares (C would round the int64): when
-- (double)a /= b the rounded comparison is right, rounding being monotonic;
-- on a tie b is an integer within 2^10 of a, and with a = q*2^32 + r,
-- a `op` b  <=>  r `op` (b - q*2^32), where both sides are exact doubles.
cmpID :: (Stream Double -> Stream Double -> Stream Bool) -> Stream Int64 -> Stream Double -> Stream Bool
cmpID op a b = mux (toD a == b) (toD r `op` sub2 b (mul2 (toD q) (constant 4294967296.0))) (toD a `op` b)
  where
    q = Op2 (Core.Div Core.typeOf) a (constant 4294967296)
    r = Op2 (Core.Mod Core.typeOf) a (constant 4294967296)
"""

_HS_TYPES = {"bool": "Bool", "int64": "Int64", "double": "Double"}


def _comment(text: str) -> str:
    """``text`` inside a Haskell line comment: printable ASCII only, so that no
    newline in a name or formula ends the comment."""
    if all(" " <= c <= "~" for c in text):
        return text
    return "".join(c if " " <= c <= "~" else f"<U+{ord(c):04X}>" for c in text)


def _hs_string(s: str) -> str:
    """A Haskell string literal (escapes are Haskell's, not Python's)."""
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif 32 <= ord(ch) < 127:
            out.append(ch)
        else:
            out.append(f"\\{ord(ch)}\\&")
    return '"' + "".join(out) + '"'


@dataclass
class _Gen:
    spec: MonitorSpec
    env: dict[str, str] = field(default_factory=dict)  # formula name -> type
    names: dict[str, str] = field(default_factory=dict)  # formula name -> Haskell binding
    # Caches are keyed by the printed formula, not the node: dataclass equality
    # makes Const(1) == Const(1.0) == Const(True), which must not share a type.
    temporal: dict[str, str] = field(default_factory=dict)  # shared temporal streams
    bindings: list[str] = field(default_factory=list)
    types: dict[str, str] = field(default_factory=dict)

    # ------------------------------------------------------------- typing
    # As in the interpreter and the native backend: a bool used as a number is
    # 0/1 and a number used as a condition is "!= 0"; int64 meets double as double.
    def type_of(self, f: Formula) -> str:
        key = to_fret(f)
        t = self.types.get(key)
        if t is None:
            t = self._type_of(f)
            self.types[key] = t
        return t

    def _type_of(self, f: Formula) -> str:
        match f:
            case Const(v):
                if isinstance(v, bool):
                    return "bool"
                return "int64" if isinstance(v, int) else "double"
            case Var(name):
                if name not in self.env:
                    raise UserError(f"unknown variable '{name}'", file=_ERR)
                return self.env[name]
            case Not() | Past() | Since():
                for c in f.children():
                    self.type_of(c)
                return "bool"
            case Neg(a):
                return "double" if self.type_of(a) == "double" else "int64"
            case BinOp(op, a, b) if op in BOOL_OPS or op in REL_OPS:
                self.type_of(a), self.type_of(b)
                return "bool"
            case BinOp(op, a, b) if op in ARITH_OPS:
                return self._num_type(a, b)
            case Pre(name, init, _):
                for c in f.children():
                    self.type_of(c)
                if not _finite_number(init):
                    raise UserError(
                        f"the Copilot backend needs a constant initial value for {name}: "
                        f"{to_fret(f)} (Copilot's [init] ++ x takes a number, not a stream)",
                        file=_ERR,
                        hint="write a number as init, or compile with the native backend "
                        "(--backend native)",
                    )
                if name == "preInt" and "double" in (self.type_of(init), self.type_of(f.arg)):
                    raise UserError(f"preInt needs int64 values: {to_fret(f)}", file=_ERR)
                return "int64" if name == "preInt" else "double"
            case Call(name, _):
                raise UserError(
                    f"the Copilot backend does not compile the function {name}: {to_fret(f)}",
                    file=_ERR,
                    hint="compile with the native backend (--backend native)",
                )
        raise UserError(f"cannot translate {f!r} to Copilot", file=_ERR)

    def _num_type(self, a: Formula, b: Formula) -> str:
        return "double" if "double" in (self.type_of(a), self.type_of(b)) else "int64"

    # ------------------------------------------------------------- expressions
    def expr(self, f: Formula, want: str | None = None) -> str:
        """Haskell for f, converted to type ``want`` when given."""
        t = self.type_of(f)
        code = self._expr(f)
        if want is None or want == t:
            return code
        if want == "bool":
            return f"({code} /= {'0.0' if t == 'double' else '0'})"
        if t == "bool":
            code = f"(b2i {code})"
        return f"(toD {code})" if want == "double" else code

    def _expr(self, f: Formula) -> str:
        match f:
            case Const(v) if isinstance(v, bool):
                return "true" if v else "false"
            case Const(v) if isinstance(v, int):
                if not -(2**63) <= v < 2**63:
                    raise UserError(f"integer constant {v} does not fit in int64", file=_ERR)
                return f"(constant ({v} :: Int64))"
            case Const(v):
                v = float(v)
                if math.isnan(v):
                    return "(fdiv2 (constant 0.0) (constant 0.0))"
                if math.isinf(v):  # Copilot would print 'Infinity' into the C
                    return f"(fdiv2 (constant {'1.0' if v > 0 else '(-1.0)'}) (constant 0.0))"
                return f"(constant ({v!r} :: Double))"
            case Var(name):
                return self.names[name]
            case Not(a):
                return f"(not {self.expr(a, 'bool')})"
            case Neg(a):
                if self.type_of(f) == "double":
                    return f"(negD {self.expr(a)})"
                return f"(negW {self.expr(a, 'int64')})"
            case BinOp(op, a, b) if op in BOOL_OPS:
                x, y = self.expr(a, "bool"), self.expr(b, "bool")
                hs = {"&": "&&", "|": "||", "xor": "`xor`", "->": "==>", "<->": "=="}[op]
                return f"({x} {hs} {y})"
            case BinOp(op, a, b) if op in REL_OPS:
                return self._rel(op, a, b)
            case BinOp(op, a, b) if op in ARITH_OPS:
                return self._arith(f, op, a, b)
            case Past() | Since() | Pre():
                return self._temporal(f)
        raise UserError(f"cannot translate {f!r} to Copilot", file=_ERR)

    def _rel(self, op: str, a: Formula, b: Formula) -> str:
        ta, tb = self.type_of(a), self.type_of(b)
        hs = {"=": "==", "!=": "/="}.get(op, op)
        if ta == tb == "bool" and op in ("=", "!="):
            return f"({self.expr(a)} {hs} {self.expr(b)})"
        if "double" in (ta, tb) and ta != tb:
            # int64 against double: exact, as Python compares (see cmpID)
            if ta == "double":
                hs = {"<": ">", "<=": ">=", ">": "<", ">=": "<="}.get(hs, hs)
                a, b = b, a
            return f"(cmpID ({hs}) {self.expr(a, 'int64')} {self.expr(b)})"
        want = "double" if "double" in (ta, tb) else "int64"
        return f"({self.expr(a, want)} {hs} {self.expr(b, want)})"

    def _arith(self, f: Formula, op: str, a: Formula, b: Formula) -> str:
        if self.type_of(f) == "double":
            if op == "mod":
                raise UserError(
                    f"the Copilot backend cannot compute real 'mod' in {to_fret(f)}: "
                    "Copilot 3.13 has no fmod",
                    file=_ERR,
                    hint="use the native backend (--backend c99) or integer operands",
                )
            x, y = self.expr(a, "double"), self.expr(b, "double")
            fn = {"+": "add2", "-": "sub2", "*": "mul2", "/": "fdiv2", "^": "powD"}[op]
            return f"({fn} {x} {y})"
        x = self.expr(a, "int64")
        if op == "^":
            if not (isinstance(b, Const) and isinstance(b.value, int) and 0 <= b.value <= 63):
                raise UserError(
                    f"integer power needs a constant exponent from 0 to 63 in {to_fret(f)}",
                    file=_ERR,
                )
            return f"(powW {x} {b.value})"
        fn = {"+": "addW", "-": "subW", "*": "mulW", "/": "divW", "mod": "modW"}[op]
        return f"({fn} {x} {self.expr(b, 'int64')})"

    def _temporal(self, f: Formula) -> str:
        """Temporal subterms become top-level bindings, shared by every requirement."""
        key = to_fret(f)
        name = self.temporal.get(key)
        if name is not None:
            return name
        stream = "Bool"
        match f:
            case Pre(_, Const(v), a):
                # a number's previous value, v at the first tick (checked in _type_of)
                t = self.type_of(f)
                stream = _HS_TYPES[t]
                lit = f"({v:d} :: Int64)" if t == "int64" else f"({float(v)!r} :: Double)"
                body = f"[{lit}] ++ {self.expr(a, t)}"
            case Past(op, a, lo, hi):
                body = self._past(op, self.expr(a, "bool"), lo or 0, hi)
            case Since(op, a, b, lo, hi):
                x, y = self.expr(a, "bool"), self.expr(b, "bool")
                body = self._since(op, x, y, lo or 0, hi)
            case _:
                raise AssertionError(f)
        name = f"t{len(self.temporal)}"
        self.temporal[key] = name
        self.bindings.append(
            f"-- {_comment(to_fret(f))}\n{name} :: Stream {stream}\n{name} = {body}\n"
        )
        return name

    @staticmethod
    def _past(op: str, x: str, lo: int, hi: int | None) -> str:
        if op == "Y":
            return f"prev {x}"
        if op == "Z":
            return f"wprev {x}"
        if hi is not None and hi < lo:  # empty window
            return "true" if op == "H" else "false"
        fn = {"H": ("hist", "histFrom", "histIn"), "O": ("once", "onceFrom", "onceIn")}[op]
        if hi is None:
            return f"{fn[0]} {x}" if lo == 0 else f"{fn[1]} {lo} {x}"
        return f"{fn[2]} {lo} {hi - lo} {x}"

    @staticmethod
    def _since(op: str, x: str, y: str, lo: int, hi: int | None) -> str:
        if hi is not None and hi < lo:
            return "true" if op == "T" else "false"
        fn = {"S": ("sinceStd", "sinceFrom", "sinceIn"), "T": ("trig", "trigFrom", "trigIn")}[op]
        if hi is None:
            return f"{fn[0]} {x} {y}" if lo == 0 else f"{fn[1]} {lo} {x} {y}"
        return f"{fn[2]} {lo} {hi - lo} {x} {y}"


def _finite_number(f: Formula) -> bool:
    """A numeric constant Copilot can hold as a Haskell literal (no NaN or inf)."""
    if not isinstance(f, Const) or isinstance(f.value, bool):
        return False
    return isinstance(f.value, int) or math.isfinite(f.value)


def output_name(spec: MonitorSpec) -> str:
    """Base name of the generated files: <name>.c, <name>.h, <name>_types.h."""
    return c_name(spec.prefix) if spec.prefix else "monitor"


def generate_haskell(spec: MonitorSpec, out_dir: Path | None = None) -> str:
    """The Copilot spec for ``spec`` as a Haskell program.  When run, it writes
    the C files into ``out_dir`` (default: the current directory)."""
    if spec.margins:
        # margins are the native backend's (docs/reference/margins.md)
        raise UserError(
            "the Copilot backend computes no margins",
            file=_ERR,
            hint="use the native backend (--backend native), or turn margins off",
        )
    g = _Gen(spec)
    _name_variables(spec, g)
    lines = [
        f"-- Copilot spec for component {_comment(repr(spec.component))}, "
        "generated by safety-supervisor.",
        "module Main (main) where",
        "",
        "import qualified Copilot.Core as Core",
        "import Copilot.Compile.C99",
        "import Copilot.Language.Stream (Stream (Op2))",
        "import Language.Copilot",
        "import qualified Prelude as P",
        "",
        "-- Inputs: globals defined by the host, read at each step.",
        *_variable_streams(spec, g),
    ]
    # after the variables: the triggers' temporal subformulas add to g.bindings
    triggers = _triggers(spec, g)
    if g.bindings:
        lines.append("-- Temporal subformulas.")
        lines += g.bindings
    lines += ["spec :: Spec", "spec = do"] + (triggers or ["  P.return ()"]) + [""]
    lines += _main(spec, out_dir)
    return "\n".join(lines)


def _name_variables(spec: MonitorSpec, g: _Gen) -> None:
    """Each input's and internal variable's type and Haskell name into ``g``; raises
    UserError for a type Copilot cannot hold or a C name that is taken."""
    c_names: dict[str, str] = {}
    for kind, name, typ in [("input", v.name, v.type) for v in spec.inputs] + [
        ("internal variable", d.name, d.type) for d in spec.defines
    ]:
        if typ not in _HS_TYPES:
            raise UserError(f"{kind} '{name}' has unsupported type '{typ}'", file=_ERR)
        cn = c_name(name)
        if cn in c_names:
            raise UserError(
                f"{kind} '{name}' and '{c_names[cn]}' have the same C name '{cn}'", file=_ERR
            )
        if kind == "input" and (_COPILOT_INTERNAL.match(cn) or cn == spec.step_name):
            raise UserError(
                f"input '{name}' clashes with a name Copilot uses in its generated C",
                file=_ERR,
                hint="rename the variable or use the native backend",
            )
        c_names[cn] = name
        g.env[name] = typ
        g.names[name] = ("in_" if kind == "input" else "def_") + cn


def _variable_streams(spec: MonitorSpec, g: _Gen) -> list[str]:
    """A stream per input (an extern the host defines) and per internal variable."""
    lines = []
    for v in spec.inputs:
        hs = _HS_TYPES[v.type]
        n = g.names[v.name]
        lines += [f"{n} :: Stream {hs}", f"{n} = extern {_hs_string(c_name(v.name))} Nothing", ""]
    if spec.defines:
        lines.append("-- Internal variables.")
    for d in spec.defines:
        if g.type_of(d.expr) != d.type and not (
            d.type == "double" and g.type_of(d.expr) == "int64"
        ):
            raise UserError(
                f"internal variable '{d.name}' is declared {d.type} but "
                f"{to_fret(d.expr)} is {g.type_of(d.expr)}",
                file=_ERR,
            )
        n = g.names[d.name]
        lines += [f"{n} :: Stream {_HS_TYPES[d.type]}", f"{n} = {g.expr(d.expr, d.type)}", ""]
    return lines


def _triggers(spec: MonitorSpec, g: _Gen) -> list[str]:
    """One trigger per requirement, calling its handler when the requirement fails."""
    triggers = []
    handlers: set[str] = set()
    for req in spec.requirements:
        handler = c_name(req.handler)  # the host shim's name for it (build.py)
        if handler in handlers:
            raise UserError(f"requirement id '{req.id}' repeats C handler {handler}", file=_ERR)
        handlers.add(handler)
        triggers.append(
            f"  -- {_comment(req.id)}: {_comment(to_fret(req.formula))}\n"
            f"  trigger {_hs_string(handler)} (not {g.expr(req.formula, 'bool')}) []"
        )
    return triggers


def _main(spec: MonitorSpec, out_dir: Path | None) -> list[str]:
    """``main``: compiles the spec to C with the step function's name and the output
    directory, then the helper functions' prelude."""
    settings = "mkDefaultCSettings"
    fields = []
    if spec.prefix:
        fields.append(f"cSettingsStepFunctionName = {_hs_string(spec.step_name)}")
    if out_dir is not None:
        fields.append(f"cSettingsOutputDirectory = {_hs_string(str(out_dir))}")
    if fields:
        settings = "(mkDefaultCSettings { " + ", ".join(fields) + " })"
    return [
        "main :: IO ()",
        "main = do",
        "  s <- reify spec",
        f"  compileWith {settings} {_hs_string(output_name(spec))} s",
        "",
        _PRELUDE,
    ]


# ------------------------------------------------------------------ running GHC


def _tool(name: str) -> str | None:
    return shutil.which(name)


def copilot_available() -> bool:
    """True when ghc and the Copilot C99 library are installed."""
    return _missing() is None


def _missing() -> str | None:
    """Why Copilot cannot be used, or None."""
    ghc = _tool("ghc")
    if ghc is None:
        return "GHC (the Haskell compiler) is not installed: 'ghc' is not on PATH"
    # ghc-pkg sits next to ghc; it answers in milliseconds (ghc -e takes ~0.3 s).
    pkg = shutil.which("ghc-pkg", path=os.path.dirname(ghc)) or _tool("ghc-pkg")
    if pkg is None:
        return "'ghc-pkg' is not found next to ghc, so Copilot cannot be located"
    r = subprocess.run(
        [pkg, "list", "--simple-output", COPILOT_PACKAGE],
        capture_output=True,
        text=True,
        check=False,
    )
    if r.returncode != 0 or not r.stdout.strip():
        return "the NASA Copilot library (copilot-c99) is not installed for GHC"
    return None


def require_copilot() -> None:
    why = _missing()
    if why is not None:
        raise UserError(
            f"--backend copilot needs NASA Copilot 3.x: {why}", file=_ERR, hint=INSTALL_HINT
        )


def _ghc_error(stderr: str) -> str:
    """GHC's or Copilot's failure as one readable line."""
    text = stderr.strip()
    m = re.search(
        r"^\S*:(\d+):(\d+)(?:-\d+)?: error:\s*(.*?)(?=^\S*:\d+:\d+|\Z)", text, re.M | re.S
    )
    if m:
        body = " ".join(part.strip(" •") for part in m.group(3).splitlines() if part.strip())
        body = re.sub(r"\s+", " ", body.split(" | ")[0])
        return f"line {m.group(1)}:{m.group(2)} of the generated Copilot spec: {body[:300]}"
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return " ".join(lines)[:300] if lines else "no error message"


def run_haskell(
    source: str, work_dir: Path, *, runner: str = DEFAULT_RUNNER, timeout: float = 600
) -> float:
    """Run a Haskell program (a generated Copilot spec) with GHC in a scratch
    directory; returns the seconds taken.  Failures become a one-line UserError."""
    with tempfile.TemporaryDirectory(prefix="copilot-", dir=work_dir) as tmp:
        hs = Path(tmp) / "Spec.hs"
        hs.write_text(source)
        if runner == "runghc":
            cmds = [["runghc", str(hs)]]
        elif runner == "ghc":
            exe = Path(tmp) / "spec"
            cmds = [["ghc", "-O0", "-v0", "-outputdir", tmp, "-o", str(exe), str(hs)], [str(exe)]]
        else:
            raise ValueError(f"unknown runner {runner!r}")
        start = time.perf_counter()
        for cmd in cmds:
            try:
                r = subprocess.run(
                    cmd, cwd=tmp, capture_output=True, text=True, timeout=timeout, check=False
                )
            except subprocess.TimeoutExpired:
                raise UserError(
                    f"GHC did not finish the Copilot spec within {timeout:.0f} s", file=_ERR
                ) from None
            except FileNotFoundError:
                require_copilot()
                raise
            if r.returncode != 0:
                raise UserError(f"Copilot failed: {_ghc_error(r.stderr)}", file=_ERR)
        return time.perf_counter() - start


@dataclass
class CopilotRun:
    c_files: list[Path]
    seconds: float


def compile_copilot(
    spec: MonitorSpec, out_dir: Path, *, runner: str = DEFAULT_RUNNER, timeout: float = 600
) -> list[Path]:
    """Generate the Copilot spec, run it with GHC and return the generated C
    files (``<name>.c``, ``<name>.h``, ``<name>_types.h``) in ``out_dir``.  The
    Haskell spec is kept next to them as ``<name>.hs``."""
    return run_copilot(spec, out_dir, runner=runner, timeout=timeout).c_files


def run_copilot(
    spec: MonitorSpec, out_dir: Path, *, runner: str = DEFAULT_RUNNER, timeout: float = 600
) -> CopilotRun:
    """compile_copilot, also reporting how long GHC took."""
    require_copilot()
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    name = output_name(spec)
    source = generate_haskell(spec, out_dir)
    (out_dir / f"{name}.hs").write_text(source)
    seconds = run_haskell(source, out_dir, runner=runner, timeout=timeout)
    files = [out_dir / f"{name}.c", out_dir / f"{name}.h", out_dir / f"{name}_types.h"]
    for f in files:
        if not f.exists():
            raise UserError(f"Copilot did not produce {f.name}", file=_ERR)
    return CopilotRun(files, seconds)


def build_copilot_monitor(
    spec: MonitorSpec, out_dir: Path, *, runner: str = DEFAULT_RUNNER
) -> LoadedMonitor:
    """Compile ``spec`` with Copilot (C in ``out_dir/copilot``), build it like the
    native backend (build.py: hidden symbols, -Bsymbolic, so Copilot's ``step``
    and ``s0_get`` never meet glibc's or another monitor's) and load it.  Copilot
    has no reset function: LoadedMonitor.reset() loads a fresh copy."""
    from monitors.backends.build import build_library
    from monitors.backends.load import load_monitor

    out_dir = Path(out_dir)
    c_files = compile_copilot(spec, out_dir / "copilot", runner=runner)
    sources = [f for f in c_files if f.suffix == ".c"]
    try:
        lib = build_library(
            spec, sources, c_files[0].parent, out_dir, reset=False, reset_each=False
        )
    except UserError as e:
        if e.hint is None and re.search(r"redeclared|conflicting types", e.message):
            e.hint = (
                "Copilot's C includes <math.h>, <stdlib.h> and <string.h>, so an input "
                "cannot be named like a C library function; rename it or use the native backend"
            )
        raise
    return load_monitor(lib, spec)
