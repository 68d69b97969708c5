"""Consistency: can every requirement and range hold on one trace, and if not,
which independent minimal sets conflict."""

from __future__ import annotations

import z3

from monitors.verify.analysis.conflicts import report_conflict
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.results import Finding


def consistency(ctx: Context, findings: list[Finding]) -> tuple[bool | None, str]:
    """(consistent, summary), consistent None when z3 could not decide; each
    conflict found becomes a finding."""
    items = ctx.all_items()
    k = ctx.k
    lits = [ctx.ok_lit(i, k) for i in items]
    r = ctx.check(lits)
    if r == z3.sat:
        return True, f"consistent: a {k}-tick trace satisfies all {len(ctx.reqs)} requirements"
    if r != z3.unsat:
        return None, f"unknown: {ctx.stop_text()}"
    active = list(items)
    for _ in range(5):  # report independent conflicts, not only the first
        core = ctx.minimal_core(active, k)
        if core is None:
            break
        report_conflict(ctx, core, findings)
        drop = {i for i in core if not i.startswith("range:")} or set(core)
        active = [i for i in active if i not in drop]
    return False, "inconsistent: no trace satisfies all requirements (see conflicts)"
