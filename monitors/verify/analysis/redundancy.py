"""Redundancy: requirements implied by the others (or by nothing: they always hold)."""

from __future__ import annotations

from monitors.ir.formula import max_bound
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.results import Finding, Limit, Remedy
from monitors.verify.analysis.wording import and_list
from monitors.verify.bmc import pure_invariant


def redundancy(ctx: Context, findings: list[Finding], skip: set[str]) -> None:
    """A finding per guarantee (not in ``skip``) that no trace can violate while the
    others hold; too short traces are reported as such instead."""
    k = ctx.k
    for rid, r in ctx.reqs.items():
        if r.assumption or rid in skip:
            continue  # an assumption implied by the ranges still documents them
        others = ctx.all_items(exclude=[rid])
        core = ctx.minimal_core(others, k, [ctx.viol_lit(rid, k)])
        if core is None:
            continue
        if core == [] and max_bound(r.formula) + 1 >= k:
            findings.append(
                Finding(
                    "k-too-small",
                    "info",
                    (rid,),
                    f"{rid} cannot be violated on traces of {k} ticks (its time bound is "
                    f"{max_bound(r.formula)}), so the analyses say little about it",
                    "",
                    remedy=Remedy(Limit.TRACE_LENGTH, at_least=max_bound(r.formula) + 2),
                )
            )
            continue
        pure = pure_invariant(r.formula) is not None and all(
            i.startswith("range:") or pure_invariant(ctx.reqs[i].formula) is not None for i in core
        )
        horizon = "at every tick, for all time" if pure else f"on every trace of {k} ticks"
        by = and_list(core) if core else "nothing (it always holds)"
        findings.append(
            Finding(
                "redundant",
                "warning",
                (rid, *(c for c in core if not c.startswith("range:"))),
                f"{rid} is implied by {by} {horizon}: its handler can only fire when "
                "another requirement's does",
                f"remove {rid}, or check whether it was meant to say something stronger",
            )
        )
