"""Vacuity: requirements whose scope/condition can never become true, or never
in a trace that satisfies the other requirements."""

from __future__ import annotations

from monitors.ir.formula import TRUE
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.results import Finding
from monitors.verify.analysis.wording import and_list


def vacuity(ctx: Context, findings: list[Finding], consistent: bool) -> set[str]:
    """The ids of the vacuous and unreachable requirements (each also a finding)."""
    k = ctx.k
    vacuous: set[str] = set()
    base = ctx.assumption_items()
    for rid, r in ctx.reqs.items():
        if r.activation == TRUE:
            continue
        core = ctx.minimal_core(base, k, [ctx.fired_lit(rid, k)])
        if core is not None:
            vacuous.add(rid)
            why = f"allowed by {and_list(core)}" if core else "at all"
            findings.append(
                Finding(
                    "vacuous",
                    "warning",
                    (rid, *(c for c in core if not c.startswith("range:"))),
                    f"{rid} can never be triggered: no trace of {k} ticks {why} makes "
                    f"its scope/condition `{r.activation}` true, so it constrains nothing",
                    f"correct the scope or condition of {rid} (values the assumptions "
                    "and ranges allow), or remove it",
                )
            )
            continue
        if not consistent:
            continue
        core = ctx.minimal_core(ctx.all_items(), k, [ctx.fired_lit(rid, k)])
        if core is not None:
            vacuous.add(rid)
            findings.append(
                Finding(
                    "unreachable",
                    "warning",
                    (rid, *(c for c in core if not c.startswith("range:") and c != rid)),
                    f"{rid} is never triggered in a trace that satisfies the requirements: "
                    f"{and_list(core)} together keep its scope/condition `{r.activation}` "
                    f"false (traces of {k} ticks)",
                    f"check whether {rid}'s scope/condition can really happen, or whether "
                    "the other requirements are too strong",
                )
            )
    return vacuous
