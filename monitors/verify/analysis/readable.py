"""Readable example traces: values a person reads at a glance (small integers,
short decimals, the requirements' own constants and their neighbours) instead of
whatever z3's model holds (``7.5e-310``, ``-0.0``, ``8465``), asked of the solver
so that the trace still witnesses what it claims (docs/reference/commands.md,
"explain")."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import z3

from monitors.ir.formula import Const, subterms
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.results import Trace
from monitors.verify.bmc import OutOfTime, z3_value

# The polishing of one trace gets this share of the resource limit for the one call
# asking for every value readable, and the same again for the cell-by-cell fallback
# together: a trace the solver found is kept as it is rather than spending the
# analyses' budget on looks.
RLIMIT_SHARE = 10
MAX_TRIES = 48  # solver calls for the cell-by-cell fallback
SIGNIFICANT = 6  # digits a readable number has at most


def readable(x: float) -> bool:
    """At most ``SIGNIFICANT`` significant digits, and not a denormal."""
    if x == 0 or math.isnan(x) or math.isinf(x):
        return True
    if abs(x) < 1e-6:
        return False
    return float(f"{x:.{SIGNIFICANT}g}") == x


def _short(x: float) -> float:
    """``x`` to ``SIGNIFICANT`` digits (c + 0.1 is 2.1, not 2.1000000000000001)."""
    return float(f"{x:.{SIGNIFICANT}g}")


def candidates(ctx: Context, vtype: str) -> list[float | int]:
    """Readable values for a variable of ``vtype``, most readable first: 0, the
    requirements' constants and range ends with their neighbours, then 1 and -1."""
    consts: list[float] = []
    for r in ctx.reqs.values():
        for f in subterms(r.formula):
            if isinstance(f, Const) and not isinstance(f.value, bool):
                consts.append(float(f.value))
    for v in ctx.vars.values():
        if v.range is not None:
            consts.extend(float(b) for b in v.range)
    steps = (0.0, 1.0, -1.0) if vtype == "int64" else (0.0, 1.0, -1.0, 0.5, -0.5, 0.1, -0.1)
    out: dict[float, None] = {0.0: None}
    for c in consts:
        if math.isfinite(c):
            for d in steps:
                out.setdefault(_short(c + d), None)
    out.update({1.0: None, -1.0: None})
    if vtype == "int64":
        ints = dict.fromkeys(int(x) for x in out if x == int(x) and abs(x) < 2**63)
        return list(ints)
    return list(out)


def _is(x: z3.ExprRef, vtype: str, value: float | int) -> z3.BoolRef:
    """``x`` is exactly ``value`` (for doubles by bit pattern: 0.0, not -0.0)."""
    c = z3_value(vtype, value)
    if vtype == "double":
        return z3.fpToIEEEBV(x) == z3.fpToIEEEBV(c)
    return x == c


def readable_trace(ctx: Context, lits: Sequence[z3.BoolRef], n: int, names: Iterable[str]) -> Trace:
    """A trace of ``n`` ticks satisfying ``lits`` (which the solver's last call found
    satisfiable), with readable values for the variables ``names``: all of them at
    once when the solver finds such a trace, else cell by cell, each kept only when
    the rest still holds.  Falls back to the solver's own values."""
    model = ctx.solver.model()
    cells = [
        (t, name)
        for t in range(n)
        for name in names
        if ctx.types.get(name) in ("int64", "double") and name in ctx.rows[t]
    ]
    if not cells:
        return ctx.model_trace(model, n)
    try:
        return _polished(ctx, lits, n, cells, model)
    except OutOfTime:  # the time budget ran out: the solver's own values will do
        return ctx.model_trace(model, n)


def _polished(
    ctx: Context,
    lits: Sequence[z3.BoolRef],
    n: int,
    cells: list[tuple[int, str]],
    model: z3.ModelRef,
) -> Trace:
    cands = {vt: candidates(ctx, vt) for vt in ("int64", "double")}

    def one_of(t: int, name: str) -> z3.BoolRef:
        x, vt = ctx.rows[t][name], ctx.types[name]
        return z3.Or([_is(x, vt, c) for c in cands[vt]])

    left = max(1, ctx.rlimit // RLIMIT_SHARE)
    every = ctx.fresh_lit("readable", lambda: z3.And([one_of(t, m) for t, m in cells]))
    if ctx.check([*lits, every], rlimit=left) == z3.sat:
        return ctx.model_trace(ctx.solver.model(), n)
    trace = ctx.model_trace(model, n)
    fixed: list[z3.BoolRef] = []
    left = max(1, ctx.rlimit // RLIMIT_SHARE)
    tries = MAX_TRIES
    for t, name in cells:
        v = trace[t][name]
        if isinstance(v, float) and readable(v) and not (v == 0 and math.copysign(1, v) < 0):
            continue
        if isinstance(v, int) and not isinstance(v, bool) and abs(v) < 10**SIGNIFICANT:
            continue
        for c in cands[ctx.types[name]]:
            if tries == 0 or left <= 0:
                break
            tries -= 1
            x, vt = ctx.rows[t][name], ctx.types[name]
            lit = ctx.fresh_lit("readable", lambda x=x, vt=vt, c=c: _is(x, vt, c))
            found = ctx.check([*lits, *fixed, lit], rlimit=left) == z3.sat
            left -= ctx.last_steps
            if found:
                fixed.append(lit)
                model = ctx.solver.model()
                break
    if fixed:
        trace = ctx.model_trace(model, n)
    return trace
