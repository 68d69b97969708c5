"""Which limit stopped a z3 query (monitors/verify/analysis/context.py): its resource
limit, a count of z3's own steps that stops the same query at the same point on any
machine, or the wall-clock cap kept as a safety net; the finding says which."""

from __future__ import annotations

import z3

from monitors.ir.formula import parse_formula
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.requirements import Req, VarInfo
from monitors.verify.analysis.results import Limit

# Double multiplication over free values: z3 bit-blasts it, millions of steps.
HARD = "H ((x * y = 7.25) & ((x + y) * x = 11.5) & (y > 0.001))"
VARS = {"x": VarInfo("x", "double", "input"), "y": VarInfo("y", "double", "input")}


def context(timeout_s: float, rlimit: int) -> Context:
    return Context([Req("hard", parse_formula(HARD))], VARS, 1, timeout_s, rlimit=rlimit)


def test_the_resource_limit_stops_a_query_at_the_same_step_every_time() -> None:
    runs = []
    for _ in range(2):
        ctx = context(timeout_s=600, rlimit=20_000)
        assert ctx.check([ctx.ok_lit("hard", 1)]) == z3.unknown
        runs.append(ctx.last_steps)
        assert ctx.stopped_by is Limit.SOLVER_RLIMIT
        assert ctx.stop_text() == "z3 gave up: resource limit 20000"
    assert runs[0] == runs[1] and runs[0] >= 20_000


def test_the_wall_clock_cap_is_named_when_it_stops_a_query() -> None:
    ctx = context(timeout_s=0.05, rlimit=4_000_000_000)
    assert ctx.check([ctx.ok_lit("hard", 1)]) == z3.unknown
    assert ctx.stopped_by is Limit.SOLVER_TIMEOUT
    assert ctx.stop_text() == "z3 gave up: wall-clock cap 0.05 s"
    assert ctx.last_steps < 4_000_000_000
