"""``analyse``: every analysis of a requirement set, in order, on one solver context."""

from __future__ import annotations

import time
from collections.abc import Sequence
from functools import partial

from monitors.verify.analysis.consistency import consistency
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.examples import examples
from monitors.verify.analysis.realizability import realizability
from monitors.verify.analysis.redundancy import redundancy
from monitors.verify.analysis.requirements import Req, VarInfo, default_k
from monitors.verify.analysis.results import SEVERITIES, Analysis, Finding
from monitors.verify.analysis.vacuity import vacuity

DEFAULT_TIMEOUT_S = 10.0


def analyse(
    reqs: Sequence[Req],
    vars_: dict[str, VarInfo] | Sequence[VarInfo],
    *,
    k: int | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> Analysis:
    """Run every analysis on traces of ``k`` ticks (default: ``default_k``)."""
    if not isinstance(vars_, dict):
        vars_ = {v.name: v for v in vars_}
    k = k or default_k(reqs)
    if k < 1:
        raise ValueError("k must be at least 1")
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    ctx = Context(reqs, vars_, k, timeout_s)
    findings: list[Finding] = []
    for rid, why in ctx.unsupported.items():
        findings.append(
            Finding(
                "not-analysed",
                "warning",
                (rid,),
                f"{rid} is left out of the analyses: {why}",
                "nothing to change for the monitor; the analyses just cannot reason about it",
            )
        )
    for r in reqs:
        if not r.monotone and r.id in ctx.reqs:
            findings.append(
                Finding(
                    "non-monotone",
                    "warning",
                    (r.id,),
                    r.note or f"{r.id} is non-monotone (false until something happens)",
                    "if a per-tick obligation was meant, use a timing such as 'always', "
                    "'within N ticks' or 'immediately'; the analyses judge it at the end of "
                    "each trace",
                )
            )
    seconds["encode"] = time.perf_counter() - t0
    t = time.perf_counter()
    consistent, consistency_text = consistency(ctx, findings)
    seconds["consistency"] = time.perf_counter() - t
    t = time.perf_counter()
    realizability_text = (
        realizability(ctx, findings) if consistent else "not checked (inconsistent)"
    )
    seconds["realizability"] = time.perf_counter() - t
    t = time.perf_counter()
    vacuous = vacuity(ctx, findings, consistent)
    seconds["vacuity"] = time.perf_counter() - t
    t = time.perf_counter()
    if consistent:
        redundancy(ctx, findings, vacuous)
    seconds["redundancy"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    order = {s: i for i, s in enumerate(SEVERITIES)}
    findings.sort(key=lambda f: order[f.severity])
    return Analysis(
        k,
        list(reqs),
        dict(vars_),
        findings,
        consistent,
        consistency_text,
        realizability_text,
        seconds,
        partial(examples, ctx),
    )
