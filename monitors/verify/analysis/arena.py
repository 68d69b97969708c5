"""The arenas a bounded realizability game is played on: the requirements over
the variables themselves, or the same game abstracted to Booleans (one per
comparison), which z3 solves far faster."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import z3

from monitors.ir.formula import (
    REL_OPS,
    BinOp,
    Formula,
    Pre,
    Var,
    map_children,
    subterms,
    variables,
)
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.requirements import VarInfo
from monitors.verify.bmc import Encoder, Row, fp_const, fresh_row, fresh_rows, tick_encoding


@dataclass
class Arena:
    """What a bounded game is played on: per-tick variables, the requirements'
    truth per tick, and per tick what the environment may choose (input ranges)
    and what the controller must choose (output ranges)."""

    rows: list[Row]
    ins: list[str]
    outs: list[str]
    holds: dict[str, list[z3.BoolRef]]
    env_tick: list[z3.BoolRef]
    out_tick: list[z3.BoolRef]
    # concrete inputs (for the context's rows) from a model of this arena
    concretize: Callable[[z3.ModelRef, int], list[dict[str, z3.ExprRef]]]
    boolean: bool  # the Boolean abstraction (fast games) or the values themselves


class NoAbstraction(Exception):
    """The requirements do not allow the Boolean abstraction (see abstract_arena)."""


def concrete_arena(ctx: Context, ins: list[str], outs: list[str]) -> Arena:
    """The game over the variables' values, ranges per tick as the choices' limits."""

    def ranges(names: list[str], t: int) -> z3.BoolRef:
        return z3.And([ctx.at(ctx.ranges[n])[t] for n in names if n in ctx.ranges] or [True])

    def concretize(model: z3.ModelRef, n: int) -> list[dict[str, z3.ExprRef]]:
        return [
            {m: model.eval(ctx.rows[t][m], model_completion=True) for m in ins} for t in range(n)
        ]

    return Arena(
        ctx.rows,
        ins,
        outs,
        ctx.holds,
        [ranges(ins, t) for t in range(ctx.k)],
        [ranges(outs, t) for t in range(ctx.k)],
        concretize,
        False,
    )


MAX_ATOMS_PER_GROUP = 10


def abstract_arena(
    ctx: Context, ins: list[str], outs: list[str], ids: list[str], prefix: str
) -> Arena:
    """The same game over Booleans: each comparison (``s0 > 86``, ``level0 = 0``)
    becomes a Boolean variable, and each tick the environment (controller) may pick
    exactly the combinations of input (output) comparisons that some values within
    the ranges make true.  Exact when no comparison mixes inputs and outputs (then
    the requirements see the values only through these comparisons, and ticks are
    independent choices); z3 solves the Boolean game far faster than the one over
    64-bit values.  ``ids`` are the game's requirements, ``prefix`` names its
    Boolean variables.  Raises NoAbstraction when a comparison mixes inputs and
    outputs or too many comparisons share variables."""
    atoms, abstract = _comparisons_as_booleans(ctx, ins, outs, ids)
    in_set = set(ins)
    side = {name: ("in" if set(variables(f)) <= in_set else "out") for f, name in atoms.items()}
    bools_in = [n for n in ins if ctx.types[n] == "bool"]
    bools_out = [n for n in outs if ctx.types[n] == "bool"]
    a_ins = bools_in + [n for n in atoms.values() if side[n] == "in"]
    a_outs = bools_out + [n for n in atoms.values() if side[n] == "out"]
    types = {n: "bool" for n in a_ins + a_outs}
    rows = fresh_rows(types, a_ins + a_outs, ctx.k, prefix, ctx.deadline)
    enc = Encoder(types, rows, ctx.deadline)
    holds = {r: enc.holds(f) for r, f in abstract.items()}
    by_atom = {name: f for f, name in atoms.items()}
    tables = _feasibility_tables(ctx, by_atom)

    def allowed(s: str, t: int) -> z3.BoolRef:
        parts = [
            z3.Or(
                [
                    z3.And([rows[t][n] == z3.BoolVal(v) for n, v in zip(group, c, strict=True)])
                    for c in combos
                ]
                or [z3.BoolVal(False)]
            )
            for group, combos in tables
            if side[group[0]] == s
        ]
        return z3.And(parts) if parts else z3.BoolVal(True)

    def concretize(model: z3.ModelRef, n: int) -> list[dict[str, z3.ExprRef]]:
        out = []
        for t in range(n):
            row: dict[str, z3.ExprRef] = {}
            for b in bools_in:
                row[b] = model.eval(rows[t][b], model_completion=True)
            for group, _ in tables:
                if side[group[0]] != "in":
                    continue
                want = [z3.is_true(model.eval(rows[t][a], model_completion=True)) for a in group]
                row.update(_realize(ctx, [by_atom[a] for a in group], want))
            for m in ins:  # inputs no comparison mentions: any value in range
                row.setdefault(m, quiet_value(ctx.vars[m]))
            out.append(row)
        return out

    return Arena(
        rows,
        a_ins,
        a_outs,
        holds,
        [allowed("in", t) for t in range(ctx.k)],
        [allowed("out", t) for t in range(ctx.k)],
        concretize,
        True,
    )


def _comparisons_as_booleans(
    ctx: Context, ins: list[str], outs: list[str], ids: list[str]
) -> tuple[dict[Formula, str], dict[str, Formula]]:
    """Each non-Boolean comparison of the requirements ``ids`` named ``cmp<i>`` (in
    the order met), and the requirements with those names in their place; raises
    NoAbstraction (see abstract_arena)."""
    in_set, out_set = set(ins), set(outs)
    types_enc = Encoder(ctx.types, [])
    atoms: dict[Formula, str] = {}

    def go(f: Formula) -> Formula:
        if isinstance(f, BinOp) and f.op in REL_OPS and types_enc.type_of(f.left) != "bool":
            vs = set(variables(f))
            if not vs:
                return f
            if vs & in_set and vs & out_set:
                raise NoAbstraction(f"{f} compares inputs with outputs")
            if any(isinstance(g, Pre) for g in subterms(f)):
                # a previous value ties this tick's comparison to the last tick's
                # values: not an independent choice per tick
                raise NoAbstraction(f"{f} compares a previous value (preInt/preReal)")
            return Var(atoms.setdefault(f, f"cmp{len(atoms)}"))
        return map_children(f, go)

    abstract = {r: go(ctx.reqs[r].formula) for r in ids}
    return atoms, abstract


def _feasibility_tables(
    ctx: Context, by_atom: dict[str, Formula]
) -> list[tuple[list[str], list[tuple[bool, ...]]]]:
    """Comparisons sharing a variable constrain each other: per group of them, the
    combinations of truth values some values within the ranges make true."""
    groups = _components_of({n: set(variables(f)) for n, f in by_atom.items()})
    tables = []
    for group in groups:
        if len(group) > MAX_ATOMS_PER_GROUP:
            raise NoAbstraction(f"{len(group)} comparisons share variables")
        tables.append((group, _feasible(ctx, [by_atom[n] for n in group])))
    return tables


def _components_of(uses: dict[str, set[str]]) -> list[list[str]]:
    """Names grouped by the variables they share (connected components)."""
    groups: list[tuple[set[str], list[str]]] = []
    for name, vs in uses.items():
        merged = [g for g in groups if g[0] & vs]
        keep = [g for g in groups if not g[0] & vs]
        vars_ = set(vs).union(*(g[0] for g in merged))
        members = [m for g in merged for m in g[1]] + [name]
        groups = keep + [(vars_, members)]
    return [sorted(g[1], key=list(uses).index) for g in groups]


def _atom_solver(ctx: Context, fs: list[Formula]) -> tuple[z3.Solver, list[z3.BoolRef], Row]:
    names = list(dict.fromkeys(v for f in fs for v in variables(f)))
    row = fresh_row(ctx.types, names, "atom")
    s = ctx.new_solver()
    for n in names:
        if n in ctx.ranges:
            s.add(tick_encoding(ctx.types, ctx.ranges[n], row))
    return s, [tick_encoding(ctx.types, f, row) for f in fs], row


def _feasible(ctx: Context, fs: list[Formula]) -> list[tuple[bool, ...]]:
    """Every combination of truth values of the comparisons ``fs`` that values
    within the ranges can produce (all-SAT)."""
    s, xs, _ = _atom_solver(ctx, fs)
    combos = []
    while True:
        r = ctx.run(s)
        if r == z3.unknown:
            raise NoAbstraction("feasible comparisons not decided")
        if r == z3.unsat:
            return combos
        m = s.model()
        c = tuple(z3.is_true(m.eval(x, model_completion=True)) for x in xs)
        combos.append(c)
        s.add(z3.Or([x != z3.BoolVal(v) for x, v in zip(xs, c, strict=True)]))


def _realize(ctx: Context, fs: list[Formula], want: list[bool]) -> dict[str, z3.ExprRef]:
    """Values within the ranges that give the comparisons ``fs`` the truth values ``want``."""
    s, xs, row = _atom_solver(ctx, fs)
    s.add([x == z3.BoolVal(v) for x, v in zip(xs, want, strict=True)])
    assert ctx.run(s) == z3.sat, "a feasible comparison combination has no values"
    m = s.model()
    return {n: m.eval(x, model_completion=True) for n, x in row.items()}


def quiet_value(v: VarInfo) -> z3.ExprRef:
    """A quiet default for an input: false, 0, or the range end nearest to 0."""
    lo, hi = v.range if v.range is not None else (0.0, 0.0)
    x = min(max(0.0, lo), hi)
    if v.type == "bool":
        return z3.BoolVal(False)
    if v.type == "int64":
        return z3.BitVecVal(min(max(0, math.ceil(lo)), math.floor(hi)) if v.range else 0, 64)
    return fp_const(x)
