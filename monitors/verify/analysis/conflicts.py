"""Explaining one conflict: the shortest trace length where a minimal conflicting
set bites, and a trace where all of it holds but one requirement."""

from __future__ import annotations

from monitors.verify.analysis.context import Context
from monitors.verify.analysis.results import Finding
from monitors.verify.analysis.wording import and_list, first_false


def report_conflict(ctx: Context, core: list[str], findings: list[Finding]) -> None:
    """Append the finding for ``core`` (a minimal unsatisfiable set of items)."""
    n = next(n for n in range(1, ctx.k + 1) if ctx.minimal_core(core, n) is not None)
    reqs = [i for i in core if not i.startswith("range:")]
    trace, vrd, note = None, {}, ""
    for victim in reversed(reqs):  # show the others holding and one of them failing
        rest = [i for i in core if i != victim]
        lits = [ctx.viol_lit(victim, n), *(ctx.ok_lit(i, n) for i in rest)]
        model = ctx.late_violation(lits, victim, n)
        if model is not None:
            full = ctx.model_trace(model, n)
            ctx.assert_agrees(full, rest, [victim])
            vrd = ctx.recheck(full, reqs)
            trace = ctx.columns(full, core)
            t = first_false(vrd[victim]) if ctx.reqs[victim].monotone else n - 1
            note = f"{and_list(rest)} hold; {victim} is violated at tick {t}"
            break
    when = "at tick 0" if n == 1 else f"once the trace has {n} ticks (tick {n - 1})"
    findings.append(
        Finding(
            "conflict",
            "error",
            tuple(reqs),
            f"{and_list(core)} cannot all hold: they conflict {when}",
            "decide which requirement is right in this situation and change the other "
            "(a narrower scope or condition, a different response or timing)",
            trace,
            note,
            vrd,
        )
    )
