"""Bounded model checking encoding: past-time formulas over a k-tick trace in z3.

One z3 constant per variable per tick; every subterm is unrolled tick by tick
with its metric bounds, so ``holds(f)[t]`` is a z3 Boolean that is true exactly
when ``monitors.verify.interpret.verdicts(f, trace)[t]`` would be for the same values.

Value encoding, chosen so that the semantics equal the interpreter's bit for bit
(not an abstraction of it):

- ``bool``   -> z3 Bool;
- ``int64``  -> BitVec 64: +, -, * and unary - wrap like int64; ``/`` is
  ``bvsdiv`` (truncates toward zero) and ``mod`` is ``bvsrem`` (sign of the
  dividend), both guarded so that a zero divisor gives 0 as in the C backend;
  integer ``^`` needs a constant exponent and is unrolled into multiplications;
- ``double`` -> z3 FP64 (IEEE binary64, round to nearest even): NaN, infinities
  and signed zeros behave as in C.  Mathematical reals would make analysis
  results disagree with the monitor (1e16 + 1 = 1e16, nan != nan).  ``mod`` is
  C's fmod, derived from IEEE remainder; an int64 mixed into arithmetic is
  rounded to double as C does; int64/double comparisons are exact (not after
  rounding), as in the interpreter.

Not encodable exactly, hence refused with ``Unsupported`` (the analyses report
the requirement as not analysed instead of approximating): real ``^`` (C's pow
has no exact IEEE definition in z3), the functions exp, log and the
trigonometric ones (libm's results are not IEEE-specified) and integer literals
outside int64.  abs, min, max, sqrt, floor and ceil are exact (sqrt is IEEE's
correctly rounded square root, floor and ceil round to an integral double).
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Iterable, Mapping, Sequence

import z3

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
    subterms,
)
from monitors.verify.interpret import Value

I64_MIN, I64_MAX = -(1 << 63), (1 << 63) - 1
F64 = z3.Float64()
RNE = z3.RNE()
Row = dict[str, z3.ExprRef]


class Unsupported(ValueError):
    """A formula that z3 cannot encode with exactly the interpreter's semantics."""


class OutOfTime(Exception):
    """The deadline passed (the analyses' time budget, docs/reference/faults.md)."""


def check_deadline(deadline: float | None) -> None:
    """Raise OutOfTime once ``time.monotonic()`` has passed ``deadline`` (None: never)."""
    if deadline is not None and time.monotonic() > deadline:
        raise OutOfTime


def encoding_cells(formulas: Iterable[Formula], k: int) -> int:
    """How many z3 terms (and operands) unrolling ``formulas`` over ``k`` ticks builds:
    k per distinct subterm, times the window for bounded temporal operators (what
    ``Encoder`` does; its time and memory are proportional to this).  Computed from the
    bounds, without building anything."""
    cells = 0
    for g in {g for f in formulas for g in subterms(f)}:
        if isinstance(g, Past) and g.op in ("O", "H") and g.hi is not None:
            cells += k * max(1, min(k, g.hi - (g.lo or 0) + 1))
        elif isinstance(g, Since):
            cells += k * max(1, min(k, (g.lo or 0) + 1 if g.hi is None else g.hi + 1))
        else:
            cells += k
    return cells


# ------------------------------------------------------------------ values


def fp_const(x: float) -> z3.FPRef:
    """A double constant, exact to the bit (NaN, -0.0 and infinities included)."""
    bits = struct.unpack("<Q", struct.pack("<d", x))[0]
    return z3.fpBVToFP(z3.BitVecVal(bits, 64), F64)


def z3_value(vtype: str, x: Value) -> z3.ExprRef:
    """A concrete value of a declared type as a z3 constant."""
    if vtype == "bool":
        return z3.BoolVal(bool(x))
    if vtype == "int64":
        return z3.BitVecVal(int(x), 64)
    return fp_const(float(x))


def fresh_row(types: Mapping[str, str], names: Iterable[str], tag: str) -> Row:
    """New z3 constants ``name@tag`` for one tick."""
    row: Row = {}
    for n in names:
        t = types[n]
        sym = f"{n}@{tag}"
        if t == "bool":
            row[n] = z3.Bool(sym)
        elif t == "int64":
            row[n] = z3.BitVec(sym, 64)
        else:
            row[n] = z3.FP(sym, F64)
    return row


def fresh_rows(
    types: Mapping[str, str],
    names: Iterable[str],
    k: int,
    tag: str = "",
    deadline: float | None = None,
) -> list[Row]:
    names = list(names)
    rows = []
    for t in range(k):
        if t % 256 == 0:
            check_deadline(deadline)
        rows.append(fresh_row(types, names, f"{tag}{t}"))
    return rows


def py_value(vtype: str, v: z3.ExprRef) -> Value:
    """A z3 numeral (from a model) as the interpreter's Python value."""
    if vtype == "bool":
        return z3.is_true(v)
    if vtype == "int64":
        assert isinstance(v, z3.BitVecNumRef), v
        return v.as_signed_long()
    assert isinstance(v, z3.FPNumRef), v
    if v.isNaN():
        return math.nan
    if v.isInf():
        return -math.inf if v.isNegative() else math.inf
    bits = (
        (int(v.isNegative()) << 63)
        | (v.exponent_as_long(biased=True) << 52)
        | v.significand_as_long()
    )
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


def model_trace(
    model: z3.ModelRef, rows: Sequence[Row], types: Mapping[str, str]
) -> list[dict[str, Value]]:
    """The concrete trace a model assigns to ``rows`` (unconstrained values completed)."""
    out = []
    for row in rows:
        out.append(
            {n: py_value(types[n], model.eval(x, model_completion=True)) for n, x in row.items()}
        )
    return out


def pin(
    rows: Sequence[Row], trace: Sequence[Mapping[str, Value]], types: Mapping[str, str]
) -> list:
    """Constraints fixing ``rows`` to a concrete trace (FP by bit pattern: NaN == NaN)."""
    out = []
    for row, values in zip(rows, trace, strict=True):
        for n, x in row.items():
            if n not in values:
                continue
            v = z3_value(types[n], values[n])
            if types[n] == "double":
                out.append(
                    z3.fpToIEEEBV(x) == z3.fpToIEEEBV(v)
                    if not math.isnan(values[n])
                    else z3.fpIsNaN(x)
                )
            else:
                out.append(x == v)
    return out


# ------------------------------------------------------------------ typing


def _const_type(v: object) -> str:
    if isinstance(v, bool):
        return "bool"
    return "int64" if isinstance(v, int) else "double"


# ------------------------------------------------------------------ encoder


class Encoder:
    """Unrolls formulas over fixed per-tick variable rows.

    ``rows[t][name]`` is the z3 term for variable ``name`` at tick ``t`` (usually a
    fresh constant, or a concrete value to evaluate a formula on a given trace).
    Subterm encodings are cached, so formulas sharing subterms share z3 terms.
    """

    def __init__(
        self, types: Mapping[str, str], rows: Sequence[Row], deadline: float | None = None
    ) -> None:
        self.types = dict(types)
        self.rows = list(rows)
        self.k = len(self.rows)
        self.deadline = deadline  # time.monotonic() after which encoding raises OutOfTime
        self._table: dict[tuple, list[z3.ExprRef]] = {}
        self._types: dict[tuple, str] = {}
        self._keys: dict[int, tuple[Formula, tuple]] = {}

    def holds(self, f: Formula) -> list[z3.BoolRef]:
        """Per tick, a z3 Boolean true iff ``f`` holds at that tick."""
        if self.type_of(f) != "bool":
            raise Unsupported(f"{f} is not a boolean formula")
        return self.values(f)  # type: ignore[return-value]

    def values(self, f: Formula) -> list[z3.ExprRef]:
        self.type_of(f)  # fills the node types the encodings below rely on
        for g in self._nodes(f):  # children first: every lookup below is already filled
            key = self._key(g)
            if key not in self._table:
                check_deadline(self.deadline)
                self._table[key] = self._node(g)
        return self._table[self._key(f)]

    def type_of(self, f: Formula) -> str:
        for g in self._nodes(f):
            key = self._key(g)
            if key not in self._types:
                self._types[key] = self._node_type(g)
        return self._types[self._key(f)]

    def _key(self, g: Formula) -> tuple:
        """An exact structural key.  Formula equality treats the constants 0.0 and
        -0.0 as equal (as Python floats do), but they are different doubles
        (1.0 / -0.0 is -inf), so caching by formula equality could swap them."""
        hit = self._keys.get(id(g))
        if hit is not None and hit[0] is g:
            return hit[1]
        if isinstance(g, Const):
            key: tuple = ("C", type(g.value).__name__, repr(g.value))
        elif isinstance(g, Var):
            key = ("V", g.name)
        else:
            extra = (g.op, g.lo, g.hi) if isinstance(g, Past | Since) else ()
            extra = (g.op,) if isinstance(g, BinOp) else extra
            extra = (g.name,) if isinstance(g, Call | Pre) else extra
            key = (type(g).__name__, *extra, *(self._key(c) for c in g.children()))
        self._keys[id(g)] = (g, key)  # keeps g alive, so its id is not reused
        return key

    def _nodes(self, f: Formula) -> list[Formula]:
        """Distinct subterms (by exact key), children before parents."""
        seen: dict[tuple, Formula] = {}

        def visit(g: Formula) -> None:
            key = self._key(g)
            if key in seen:
                return
            for c in g.children():
                visit(c)
            seen[key] = g

        visit(f)
        return list(seen.values())

    def _t(self, g: Formula) -> list[z3.ExprRef]:
        return self._table[self._key(g)]

    def _ty(self, g: Formula) -> str:
        return self._types[self._key(g)]

    # -------------------------------------------------------------- types

    def _node_type(self, g: Formula) -> str:
        match g:
            case Const(v):
                return _const_type(v)
            case Var(name):
                if name not in self.types:
                    raise Unsupported(f"unknown variable '{name}'")
                return self.types[name]
            case Not(_) | Past() | Since():
                return "bool"
            case Neg(a):
                return self._ty(a)
            case BinOp(op, a, b) if op in BOOL_OPS or op in REL_OPS:
                return "bool"
            case BinOp(op, a, b) if op in ARITH_OPS:
                ta, tb = self._ty(a), self._ty(b)
                if "bool" in (ta, tb):
                    raise Unsupported(f"'{op}' on a boolean in {g}")
                return "double" if "double" in (ta, tb) else "int64"
            case Call("ite", (c, a, b)):
                tc, ta, tb = self._ty(c), self._ty(a), self._ty(b)
                if tc != "bool" or (ta == "bool") != (tb == "bool"):
                    raise Unsupported(f"ite needs a boolean condition and like branches in {g}")
                return ta if ta == tb else "double"
            case Pre(name, init, a):
                types = [self._ty(init), self._ty(a)]
                if "bool" in types or (name == "preInt" and "double" in types):
                    raise Unsupported(f"{name} on {' and '.join(types)} values in {g}")
                return "int64" if name == "preInt" else "double"
            case Call(name, args) if name not in ARITH_FUNCTIONS:
                # the config expands user functions before any analysis
                raise Unsupported(f"function {name}/{len(args)} is not defined")
            case Call(name, args):
                types = [self._ty(a) for a in args]
                if "bool" in types:
                    raise Unsupported(f"'{name}' on a boolean in {g}")
                if name in INT_FUNCTIONS and "double" not in types:
                    return "int64"
                return "double"
        raise Unsupported(f"cannot encode {g!r}")

    # -------------------------------------------------------------- nodes

    def _node(self, g: Formula) -> list[z3.ExprRef]:
        k, t = self.k, self._t
        match g:
            case Const(v):
                return [_const(v)] * k
            case Var(name):
                return [row[name] for row in self.rows]
            case Not(a):
                return [z3.Not(x) for x in t(a)]
            case Neg(a):
                if self._ty(a) == "double":
                    return [z3.fpNeg(x) for x in t(a)]
                return [-x for x in t(a)]
            case BinOp(op, a, b) if op in BOOL_OPS:
                return [_bool(op, x, y) for x, y in zip(t(a), t(b), strict=True)]
            case BinOp(op, a, b) if op in REL_OPS:
                ta, tb = self._ty(a), self._ty(b)
                return [_rel(op, x, ta, y, tb) for x, y in zip(t(a), t(b), strict=True)]
            case BinOp(op, a, b):
                ta, tb = self._ty(a), self._ty(b)
                if op == "^" and "double" not in (ta, tb):
                    if not (isinstance(b, Const) and type(b.value) is int and 0 <= b.value <= 63):
                        raise Unsupported("integer ^ needs a constant exponent from 0 to 63")
                    return [_ipow(x, b.value) for x in t(a)]
                return [_arith(op, x, ta, y, tb) for x, y in zip(t(a), t(b), strict=True)]
            case Call("ite", (c, a, b)):
                result = self._ty(g)
                ta, tb = self._ty(a), self._ty(b)
                if result == "double":
                    xs, ys = [_to_double(x, ta) for x in t(a)], [_to_double(y, tb) for y in t(b)]
                else:
                    xs, ys = t(a), t(b)
                return [z3.If(c_, x, y) for c_, x, y in zip(t(c), xs, ys, strict=True)]
            case Call(name, args):
                result = self._ty(g)
                columns = [
                    t(a) if result == "int64" else [_to_double(x, self._ty(a)) for x in t(a)]
                    for a in args
                ]
                return [_call(name, result, xs) for xs in zip(*columns, strict=True)]
            case Pre(_, init, a):
                # init at tick 0 (Lustre's init -> pre x), the argument one tick late
                if not k:
                    return []
                first, xs = t(init)[0], t(a)[:-1]
                if self._ty(g) == "double":
                    first = _to_double(first, self._ty(init))
                    xs = [_to_double(x, self._ty(a)) for x in xs]
                return [first, *xs]
            case Past("Y", a):
                return [z3.BoolVal(False)] + t(a)[:-1] if k else []
            case Past("Z", a):
                return [z3.BoolVal(True)] + t(a)[:-1] if k else []
            case Past(op, a, lo, hi):
                return self._window_op(op == "O", t(a), lo or 0, hi)
            case Since(op, a, b, lo, hi):
                return self._since(op == "S", t(a), t(b), lo or 0, hi)
        raise Unsupported(f"cannot encode {g!r}")

    def _window_op(self, once: bool, xs: list, lo: int, hi: int | None) -> list:
        """O/H over the ticks j with lo <= i - j <= hi (as interpret._window)."""
        join = _or if once else _and
        if hi is None:
            # unbounded: a running fold (linear size), shifted by lo
            run: list = []
            for i, x in enumerate(xs):
                run.append(x if i == 0 else join([run[-1], x]))
            empty = z3.BoolVal(not once)
            return [run[i - lo] if i >= lo else empty for i in range(self.k)]
        out = []
        for i in range(self.k):
            if i % 64 == 0:
                check_deadline(self.deadline)
            out.append(join([xs[j] for j in range(max(0, i - hi), i - lo + 1)]))
        return out

    def _since(self, strong: bool, xs: list, ys: list, lo: int, hi: int | None) -> list:
        """a S b: some j in the window has b(j) and a at every m in (j, i].
        a T b: every j in the window has b(j) or a at some m in (j, i].
        Size O(k * window): per tick one fold over its window, oldest tick first."""
        if hi is None:
            return self._since_from(strong, xs, ys, lo)
        out = []
        for i in range(self.k):
            if i % 16 == 0:
                check_deadline(self.deadline)
            acc = z3.BoolVal(not strong)  # no witness yet / nothing to answer for yet
            for j in range(max(0, i - hi), i + 1):
                if strong:  # a witness before j must see a at j; j itself may be one
                    acc = z3.And(acc, xs[j]) if j > max(0, i - hi) else z3.BoolVal(False)
                    acc = z3.Or(acc, ys[j]) if j <= i - lo else acc
                else:
                    acc = z3.Or(acc, xs[j]) if j > max(0, i - hi) else z3.BoolVal(True)
                    acc = z3.And(acc, ys[j]) if j <= i - lo else acc
            out.append(acc)
        return out

    def _since_from(self, strong: bool, xs: list, ys: list, lo: int) -> list:
        """Unbounded window, size O(k * (lo + 1)): the plain recurrence
        s(i) = b(i) | (a(i) & s(i-1)) at tick i - lo, and a throughout (i - lo, i]
        (for T, dually, t(i) = b(i) & (a(i) | t(i-1)), or a somewhere in (i - lo, i])."""
        core: list = []
        for i in range(self.k):
            if strong:
                core.append(ys[i] if i == 0 else z3.Or(ys[i], z3.And(xs[i], core[-1])))
            else:
                core.append(ys[i] if i == 0 else z3.And(ys[i], z3.Or(xs[i], core[-1])))
        if lo == 0:
            return core
        out = []
        for i in range(self.k):
            if i < lo:
                out.append(z3.BoolVal(not strong))
            elif strong:
                out.append(_and([*xs[i - lo + 1 : i + 1], core[i - lo]]))
            else:
                out.append(_or([*xs[i - lo + 1 : i + 1], core[i - lo]]))
        return out


def _and(xs: list) -> z3.BoolRef:
    if not xs:
        return z3.BoolVal(True)
    return xs[0] if len(xs) == 1 else z3.And(*xs)


def _or(xs: list) -> z3.BoolRef:
    if not xs:
        return z3.BoolVal(False)
    return xs[0] if len(xs) == 1 else z3.Or(*xs)


def _const(v: bool | int | float) -> z3.ExprRef:
    if isinstance(v, bool):
        return z3.BoolVal(v)
    if isinstance(v, int):
        if not I64_MIN <= v <= I64_MAX:
            raise Unsupported(f"integer constant {v} does not fit in int64")
        return z3.BitVecVal(v, 64)
    return fp_const(v)


def _bool(op: str, a: z3.BoolRef, b: z3.BoolRef) -> z3.BoolRef:
    match op:
        case "&":
            return z3.And(a, b)
        case "|":
            return z3.Or(a, b)
        case "xor":
            return z3.Xor(a, b)
        case "->":
            return z3.Implies(a, b)
    return a == b  # <->


def _call(name: str, result: str, xs: Sequence[z3.ExprRef]) -> z3.ExprRef:
    """An arithmetic function as the interpreter defines it (interpret.call)."""
    if name == "min":
        less = xs[1] < xs[0] if result == "int64" else z3.fpLT(xs[1], xs[0])
        return z3.If(less, xs[1], xs[0])
    if name == "max":
        more = xs[1] > xs[0] if result == "int64" else z3.fpGT(xs[1], xs[0])
        return z3.If(more, xs[1], xs[0])
    if name == "abs":
        return z3.If(xs[0] < 0, -xs[0], xs[0]) if result == "int64" else z3.fpAbs(xs[0])
    if name == "sqrt":
        return z3.fpSqrt(RNE, xs[0])
    if name in ("floor", "ceil"):
        return z3.fpRoundToIntegral(z3.RTN() if name == "floor" else z3.RTP(), xs[0])
    raise Unsupported(f"C's {name} has no exact IEEE definition that z3 could encode")


def _to_double(x: z3.ExprRef, t: str) -> z3.FPRef:
    # C's (double)int64: round to nearest even, as Python's float(int)
    return x if t == "double" else z3.fpSignedToFP(RNE, x, F64)


_TWO63 = fp_const(2.0**63)


def _cmp_int_double(i: z3.BitVecRef, d: z3.FPRef) -> tuple[z3.BoolRef, z3.BoolRef, z3.BoolRef]:
    """Exact (i < d, i == d, i > d) for an int64 and a double (all false for NaN).

    Rounding is monotone, so round(i) < d implies i < d; when round(i) == d, d is
    an integer of magnitude <= 2^63 and i is compared with it exactly (2^63 itself
    is above every int64)."""
    r = z3.fpSignedToFP(RNE, i, F64)
    lt_r, gt_r, eq_r = z3.fpLT(r, d), z3.fpGT(r, d), z3.fpEQ(r, d)
    top = z3.fpEQ(d, _TWO63)
    di = z3.fpToSBV(z3.RTZ(), d, z3.BitVecSort(64))
    lt = z3.Or(lt_r, z3.And(eq_r, z3.Or(top, i < di)))
    gt = z3.Or(gt_r, z3.And(eq_r, z3.Not(top), i > di))
    eq = z3.And(eq_r, z3.Not(top), i == di)
    return lt, eq, gt


def _rel(op: str, a: z3.ExprRef, ta: str, b: z3.ExprRef, tb: str) -> z3.BoolRef:
    if ta == "bool" or tb == "bool":
        if ta != tb or op not in ("=", "!="):
            raise Unsupported(f"'{op}' between {ta} and {tb}")
        return a == b if op == "=" else a != b
    if ta == tb == "int64":
        return {
            "=": lambda: a == b,
            "!=": lambda: a != b,
            "<": lambda: a < b,
            "<=": lambda: a <= b,
            ">": lambda: a > b,
            ">=": lambda: a >= b,
        }[op]()
    if ta == tb == "double":
        return {
            "=": lambda: z3.fpEQ(a, b),
            "!=": lambda: z3.Not(z3.fpEQ(a, b)),
            "<": lambda: z3.fpLT(a, b),
            "<=": lambda: z3.fpLEQ(a, b),
            ">": lambda: z3.fpGT(a, b),
            ">=": lambda: z3.fpGEQ(a, b),
        }[op]()
    if ta == "int64":
        lt, eq, gt = _cmp_int_double(a, b)
    else:  # double on the left: mirror
        gt, eq, lt = _cmp_int_double(b, a)
    return {
        "=": lambda: eq,
        "!=": lambda: z3.Not(eq),
        "<": lambda: lt,
        "<=": lambda: z3.Or(lt, eq),
        ">": lambda: gt,
        ">=": lambda: z3.Or(gt, eq),
    }[op]()


def _ipow(x: z3.BitVecRef, n: int) -> z3.BitVecRef:
    # square-and-multiply: wraps exactly like repeated int64 multiplication
    result: z3.BitVecRef = z3.BitVecVal(1, 64)
    base = x
    while n:
        if n & 1:
            result = result * base
        n >>= 1
        if n:
            base = base * base
    return z3.simplify(result) if z3.is_bv_value(x) else result


def _fmod(a: z3.FPRef, b: z3.FPRef) -> z3.FPRef:
    """C's fmod (truncated quotient, sign of a) from IEEE remainder (nearest quotient):
    they differ by |b| when the remainder's sign is not a's; that sum is exact."""
    r = z3.fpRem(a, b)
    wrong_sign = z3.And(z3.Not(z3.fpIsZero(r)), z3.fpIsNegative(r) != z3.fpIsNegative(a))
    step = z3.If(z3.fpIsNegative(a), z3.fpNeg(z3.fpAbs(b)), z3.fpAbs(b))
    nan = z3.Or(z3.fpIsZero(b), z3.fpIsInf(a), z3.fpIsNaN(a), z3.fpIsNaN(b))
    return z3.If(nan, z3.fpNaN(F64), z3.If(wrong_sign, z3.fpAdd(RNE, r, step), r))


def _arith(op: str, a: z3.ExprRef, ta: str, b: z3.ExprRef, tb: str) -> z3.ExprRef:
    if "double" in (ta, tb):
        x, y = _to_double(a, ta), _to_double(b, tb)
        match op:
            case "+":
                return z3.fpAdd(RNE, x, y)
            case "-":
                return z3.fpSub(RNE, x, y)
            case "*":
                return z3.fpMul(RNE, x, y)
            case "/":
                return z3.fpDiv(RNE, x, y)
            case "mod":
                return _fmod(x, y)
        raise Unsupported("real '^' (C's pow) cannot be encoded exactly")
    zero = z3.BitVecVal(0, 64)
    match op:
        case "+":
            return a + b
        case "-":
            return a - b
        case "*":
            return a * b
        case "/":
            return z3.If(b == zero, zero, a / b)  # z3py '/' on bit-vectors is bvsdiv
        case "mod":
            return z3.If(b == zero, zero, z3.SRem(a, b))
    raise Unsupported(f"unknown operator {op}")


# ------------------------------------------------------------------ shapes


def is_propositional(f: Formula) -> bool:
    """No temporal operator and no previous value (preInt/preReal): a per-tick fact."""
    return not any(isinstance(g, Past | Since | Pre) for g in subterms(f))


def pure_invariant(f: Formula) -> Formula | None:
    """``p`` when ``f`` is ``H p`` with ``p`` propositional, else None.

    Only then does "f holds at every tick" mean "p holds at every tick, each tick
    on its own", so a single-tick encoding proves facts for unbounded traces."""
    if isinstance(f, Past) and f.op == "H" and not f.lo and f.hi is None:
        if is_propositional(f.arg):
            return f.arg
    return None


def tick_encoding(types: Mapping[str, str], p: Formula, row: Row) -> z3.BoolRef:
    """The per-tick (k = 1, no history) encoding of a propositional ``p`` on ``row``.

    Valid for the body of a pure invariant ``H p`` only: at tick 0 a temporal
    operator would see an empty past, which is not what it sees later."""
    if not is_propositional(p):
        raise Unsupported(f"{p} is temporal; a per-tick encoding would be unsound")
    return Encoder(types, [row]).holds(p)[0]


def evaluate_z3(
    f: Formula, trace: Sequence[Mapping[str, Value]], types: Mapping[str, str]
) -> list[bool]:
    """Truth of ``f`` at each tick of a concrete trace, computed by z3 (for tests:
    must equal ``interpret.verdicts``)."""
    rows = [{n: z3_value(types[n], v) for n, v in row.items()} for row in trace]
    out = []
    for x in Encoder(types, rows).holds(f):
        v = z3.simplify(x)
        if not (z3.is_true(v) or z3.is_false(v)):
            raise AssertionError(f"z3 did not evaluate {f} to a constant: {v}")
        out.append(z3.is_true(v))
    return out
