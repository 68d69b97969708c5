"""``analyse``: every analysis of a requirement set, in order, on one solver context,
within a total time budget (docs/reference/faults.md)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial

import z3

from monitors.verify.analysis.consistency import consistency
from monitors.verify.analysis.context import Context, TooLarge
from monitors.verify.analysis.examples import examples
from monitors.verify.analysis.realizability import realizability
from monitors.verify.analysis.redundancy import redundancy
from monitors.verify.analysis.requirements import (
    DEFAULT_TIMEOUT_S,
    Req,
    VarInfo,
    default_k,
    range_formula,
)
from monitors.verify.analysis.results import SEVERITIES, Analysis, Finding, Limit, Skip
from monitors.verify.analysis.solvers import is_memout
from monitors.verify.analysis.vacuity import vacuity
from monitors.verify.bmc import OutOfTime, encoding_cells

# The analyses in the order they run (and are reported as skipped).
ANALYSES = ("consistency", "realizability", "vacuity", "redundancy")
# Terms the encoder builds per second (measured: 100k-300k on one core of a laptop,
# tools/bench/analysis.py); an unrolling estimated to need more than the whole
# budget at this rate is not started.
CELLS_PER_S = 200_000
BUDGET, MEMORY = Limit.TIME_BUDGET, Limit.MEMORY


def analyse(
    reqs: Sequence[Req],
    vars_: dict[str, VarInfo] | Sequence[VarInfo],
    *,
    k: int | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    budget_s: float | None = None,
    memory_mb: int | None = None,
) -> Analysis:
    """Run every analysis on traces of ``k`` ticks (default: ``default_k``), each solver
    call within ``timeout_s`` and all of them within ``budget_s`` (None: no budget),
    z3 within ``memory_mb`` MB (None: no limit).  What the budget or the memory limit
    cut short is in ``Analysis.skipped``, with the reason."""
    if not isinstance(vars_, dict):
        vars_ = {v.name: v for v in vars_}
    k = k or default_k(reqs)
    if k < 1:
        raise ValueError("k must be at least 1")
    deadline = None if budget_s is None else time.monotonic() + budget_s
    seconds: dict[str, float] = {}
    skipped: dict[str, Skip] = {}
    t0 = time.perf_counter()

    def give_up(why: Skip) -> Analysis:
        skipped.update({name: why for name in (*ANALYSES, "examples") if name not in skipped})
        seconds["total"] = time.perf_counter() - t0
        return Analysis(
            k, list(reqs), dict(vars_), [], None, "skipped", "skipped", seconds, None, skipped
        )

    if budget_s is not None:
        formulas = [f for r in reqs for f in (r.formula, r.activation)]
        formulas += [f for v in vars_.values() if (f := range_formula(v)) is not None]
        cells = encoding_cells(formulas, k)
        if cells > budget_s * CELLS_PER_S:
            return give_up(
                Skip(
                    f"unrolling traces of k = {k} ticks builds about {cells:.2g} solver terms, "
                    f"about {cells / CELLS_PER_S:.2g} s against a time budget of {budget_s:g} s",
                    BUDGET,
                    (Limit.TRACE_LENGTH,),
                )
            )
    try:
        ctx = Context(reqs, vars_, k, timeout_s, deadline, memory_mb)
    except OutOfTime:
        return give_up(
            Skip(
                f"the time budget of {budget_s:g} s ran out while unrolling traces of k = {k} ticks",
                BUDGET,
            )
        )
    except TooLarge as e:
        return give_up(Skip(f"{e} (traces of k = {k} ticks)", BUDGET, (Limit.TRACE_LENGTH, BUDGET)))
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
    reached = f"z3 reached its memory limit of {memory_mb} MB"
    memout = False  # once z3 reached its memory limit, its context is not asked again

    def step(name: str, run: Callable[[], object], default: object) -> object:
        """One analysis, timed; ``default`` when the budget or z3's memory is gone
        before or during it (findings it made before that stay: each was checked on
        its own)."""
        nonlocal memout
        t = time.perf_counter()
        if memout:
            skipped[name] = Skip(f"{reached} before it", MEMORY)
            return default
        if deadline is not None and time.monotonic() >= deadline:
            skipped[name] = Skip(f"the time budget of {budget_s:g} s ran out before it", BUDGET)
            return default
        try:
            return run()
        except OutOfTime:
            skipped[name] = Skip(
                f"stopped: the time budget of {budget_s:g} s ran out during it", BUDGET
            )
            return default
        except z3.Z3Exception as e:
            if not is_memout(e):
                raise
            memout = True
            skipped[name] = Skip(f"stopped: {reached}", MEMORY)
            return default
        finally:
            seconds[name] = time.perf_counter() - t

    consistent_text = step("consistency", lambda: consistency(ctx, findings), None)
    consistent, consistency_text = (
        consistent_text if isinstance(consistent_text, tuple) else (None, "skipped")
    )
    realizability_text = (
        str(step("realizability", lambda: realizability(ctx, findings), "skipped"))
        if consistent
        else "not checked (inconsistent)"
        if consistent is False
        else "skipped"
    )
    vacuous = step("vacuity", lambda: vacuity(ctx, findings, bool(consistent)), set())
    if consistent:
        step("redundancy", lambda: redundancy(ctx, findings, vacuous), None)
    # z3 giving up within its time per call is reported against the budget too: a
    # larger one gives the later analyses the time to try again.
    undecided = skipped.get("consistency") or Skip(
        f"consistency was not decided: the time budget of {budget_s:g} s ran out during it"
        if deadline is not None and time.monotonic() >= deadline
        else "consistency was not decided (z3 gave up)",
        BUDGET,
    )
    if consistent is None and "redundancy" not in skipped:
        skipped["redundancy"] = undecided
    if consistent is None and "realizability" not in skipped:
        skipped["realizability"] = undecided
    if memout:  # explain's example traces would ask the same solver
        skipped["examples"] = Skip(reached, MEMORY)
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
        None if memout else partial(examples, ctx),
        skipped,
    )
