"""Example traces for the report: a shortest trace satisfying a requirement and
one violating it, both re-checked with the interpreter."""

from __future__ import annotations

from collections.abc import Callable

import z3

from monitors.ir.formula import variables
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.readable import readable_trace
from monitors.verify.analysis.results import Example, Trace
from monitors.verify.analysis.wording import and_list


def examples(ctx: Context, rid: str) -> tuple[Example | None, Example | None]:
    """A satisfying and a violating example of ``rid`` (None, None if it was not analysed)."""
    if rid not in ctx.holds:
        return None, None
    return satisfying_example(ctx, rid), violating_example(ctx, rid)


def satisfying_example(ctx: Context, rid: str) -> Example | None:
    def trig(n: int) -> list[z3.BoolRef]:
        return [ctx.ok_lit(rid, n), ctx.fired_lit(rid, n)]

    def plain(n: int) -> list[z3.BoolRef]:
        return [ctx.ok_lit(rid, n)]

    return (
        _example_for(ctx, rid, trig, [], "it is triggered and satisfied", greedy=False)
        or _example_for(ctx, rid, plain, [], "it is satisfied", greedy=False)
        or _example_for(ctx, rid, trig, [], "it is triggered and satisfied")
        or _example_for(ctx, rid, plain, [], "it is satisfied")
    )


def violating_example(ctx: Context, rid: str) -> Example | None:
    return _example_for(ctx, rid, lambda n: [ctx.viol_lit(rid, n)], [rid], "it is violated")


def _example_for(
    ctx: Context,
    rid: str,
    base: Callable[[int], list[z3.BoolRef]],
    viol: list[str],
    what: str,
    greedy: bool = True,
) -> Example | None:
    """The shortest trace meeting ``base`` and every other requirement and range;
    if there is none, the shortest meeting ``base``, keeping greedily as many of
    the others as possible (assumptions and ranges first) and naming the rest."""
    others = [i for i in ctx.assumption_items() + ctx.all_items() if i != rid]
    others = list(dict.fromkeys(others))
    for n in range(1, ctx.k + 1):
        lits = [*base(n), *(ctx.ok_lit(i, n) for i in others)]
        if ctx.check(lits) == z3.sat:
            trace = readable_trace(ctx, lits, n, _shown(ctx, [rid]))
            ctx.assert_agrees(trace, others, viol)
            note = f"a {n}-tick trace where {what} and every other requirement holds"
            return _example(ctx, trace, [rid], note)
    for n in range(1, ctx.k + 1 if greedy else 1):
        if ctx.check(base(n)) != z3.sat:
            continue
        kept: list[str] = []
        for i in others:
            if ctx.check([*base(n), *(ctx.ok_lit(j, n) for j in [*kept, i])]) == z3.sat:
                kept.append(i)
        lits = [*base(n), *(ctx.ok_lit(j, n) for j in kept)]
        assert ctx.check(lits) == z3.sat
        broken = [i for i in others if i not in kept]
        trace = readable_trace(ctx, lits, n, _shown(ctx, [rid, *broken]))
        ctx.assert_agrees(trace, kept, viol)
        note = f"a {n}-tick trace where {what}; only possible by also breaking {and_list(broken)}"
        return _example(ctx, trace, [rid, *(b for b in broken if b in ctx.reqs)], note)
    return None


def _shown(ctx: Context, ids: list[str]) -> list[str]:
    """The variables an example's table shows (``Context.columns``)."""
    return list(
        dict.fromkeys(v for i in ids if i in ctx.reqs for v in variables(ctx.reqs[i].formula))
    )


def _example(ctx: Context, trace: Trace, ids: list[str], note: str) -> Example:
    return Example(ctx.columns(trace, ids), note, ctx.recheck(trace, ids))
