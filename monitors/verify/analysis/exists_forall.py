"""Deciding "exists evars . forall uvars . body" with z3: the two-level question
behind the per-tick and the clairvoyant realizability checks."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import z3

from monitors.verify.analysis.results import Limit
from monitors.verify.analysis.solvers import solver

if TYPE_CHECKING:  # the context imports nothing of this module's
    from monitors.verify.analysis.context import Context

# The share of the resource limit the quantifier engine gets first (CEGIS the rest).
QUANTIFIER_SHARE = 4


def exists_forall(
    ctx: Context,
    body: z3.BoolRef,
    evars: list[z3.ExprRef],
    uvars: list[z3.ExprRef],
) -> tuple[str, z3.ModelRef | None]:
    """Exists evars . forall uvars . body, within one resource limit of ``ctx``
    (and its wall-clock cap).  Two methods that fail on different problems: z3's
    quantifier engine, briefly (fast on bit-vectors where an output is a function
    of an input, hopeless for CEGIS), then a CEGIS loop (candidate inputs refuted
    by outputs that answer them; fast on Boolean games, where the quantifier engine
    can take minutes) for the rest of the limit."""
    cap = time.monotonic() + ctx.timeout_ms / 1000  # the wall-clock safety net, all calls
    s = solver(ctx.memory_mb)
    first = max(1, ctx.rlimit // QUANTIFIER_SHARE)
    s.add(z3.ForAll(uvars, body) if uvars else body)
    r = ctx.run(s, rlimit=first)
    if r == z3.sat:
        return "sat", s.model()
    if r == z3.unsat:
        return "unsat", None
    return _cegis(ctx, body, evars, uvars, ctx.rlimit - first, cap)


def _cegis(
    ctx: Context,
    body: z3.BoolRef,
    evars: list[z3.ExprRef],
    uvars: list[z3.ExprRef],
    rlimit: int,
    cap: float,
) -> tuple[str, z3.ModelRef | None]:
    """The CEGIS loop: its calls together within ``rlimit`` resource units (z3's
    count of its own steps: the loop stops at the same round on any machine)."""
    cand, refute = solver(ctx.memory_mb), solver(ctx.memory_mb)
    refute.add(z3.Not(body))
    left = rlimit

    def check(s: z3.Solver, assumptions: list[z3.BoolRef]) -> z3.CheckSatResult:
        nonlocal left
        ms = int((cap - time.monotonic()) * 1000)
        if ms <= 0:
            ctx.stopped_by = Limit.SOLVER_TIMEOUT
            return z3.unknown
        r = ctx.run(s, assumptions, left, ms)
        left -= ctx.last_steps
        return r

    while left > 0:
        r = check(cand, [])
        if r == z3.unsat:
            return "unsat", None
        if r != z3.sat:
            break
        m = cand.model()
        pin = [(v, m.eval(v, model_completion=True)) for v in evars]
        if left <= 0:
            ctx.stopped_by = Limit.SOLVER_RLIMIT
            break
        r2 = check(refute, [v == x for v, x in pin])
        if r2 == z3.unsat:
            return "sat", m
        if r2 != z3.sat:
            break
        m2 = refute.model()
        answer = [(v, m2.eval(v, model_completion=True)) for v in uvars]
        cand.add(z3.substitute(body, *answer) if answer else body)
    else:
        ctx.stopped_by = Limit.SOLVER_RLIMIT
    return "unknown", None
