"""Deciding "exists evars . forall uvars . body" with z3: the two-level question
behind the per-tick and the clairvoyant realizability checks."""

from __future__ import annotations

import time

import z3

from monitors.verify.analysis.solvers import solver


def exists_forall(
    body: z3.BoolRef,
    evars: list[z3.ExprRef],
    uvars: list[z3.ExprRef],
    timeout_ms: int,
    memory_mb: int | None = None,
) -> tuple[str, z3.ModelRef | None]:
    """Exists evars . forall uvars . body.  Two methods that fail on different
    problems: z3's quantifier engine, briefly (fast on bit-vectors where an output
    is a function of an input, hopeless for CEGIS), then a CEGIS loop (candidate
    inputs refuted by outputs that answer them; fast on Boolean games, where the
    quantifier engine can take minutes) for the rest of the time."""
    first = min(2000, max(1, timeout_ms // 4))
    s = solver(memory_mb)
    s.set(timeout=first)
    s.add(z3.ForAll(uvars, body) if uvars else body)
    r = s.check()
    if r == z3.sat:
        return "sat", s.model()
    if r == z3.unsat:
        return "unsat", None
    return _cegis(body, evars, uvars, max(1, timeout_ms - first), memory_mb)


def _cegis(
    body: z3.BoolRef,
    evars: list[z3.ExprRef],
    uvars: list[z3.ExprRef],
    timeout_ms: int,
    memory_mb: int | None,
) -> tuple[str, z3.ModelRef | None]:
    deadline = time.monotonic() + timeout_ms / 1000
    cand, refute = solver(memory_mb), solver(memory_mb)
    refute.add(z3.Not(body))
    while time.monotonic() < deadline:
        left = max(1, int((deadline - time.monotonic()) * 1000))
        cand.set(timeout=left)
        r = cand.check()
        if r == z3.unsat:
            return "unsat", None
        if r != z3.sat:
            break
        m = cand.model()
        pin = [(v, m.eval(v, model_completion=True)) for v in evars]
        refute.set(timeout=left)
        r2 = refute.check(*[v == x for v, x in pin])
        if r2 == z3.unsat:
            return "sat", m
        if r2 != z3.sat:
            break
        m2 = refute.model()
        answer = [(v, m2.eval(v, model_completion=True)) for v in uvars]
        cand.add(z3.substitute(body, *answer) if answer else body)
    return "unknown", None
