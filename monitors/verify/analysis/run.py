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
    DEFAULT_RLIMIT,
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
# A stage's name and, once it has ended, its seconds (None when it starts).
Progress = Callable[[str, float | None], None]


def _silent(name: str, seconds: float | None) -> None:
    """No progress to show."""


def analyse(
    reqs: Sequence[Req],
    vars_: dict[str, VarInfo] | Sequence[VarInfo],
    *,
    k: int | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    budget_s: float | None = None,
    memory_mb: int | None = None,
    rlimit: int = DEFAULT_RLIMIT,
    progress: Progress | None = None,
) -> Analysis:
    """Run every analysis on traces of ``k`` ticks (default: ``default_k``), each solver
    call within ``rlimit`` of z3's resource units (deterministic: the findings do not
    depend on the machine) and, as a safety net, ``timeout_s`` of wall-clock time, all
    of them within ``budget_s`` (None: no budget), z3 within ``memory_mb`` MB (None:
    no limit).  ``progress`` is told when each stage (the unrolling, each analysis)
    starts (seconds None) and how long it took.  What the budget or the memory limit
    cut short is in ``Analysis.skipped``, with the reason."""
    if not isinstance(vars_, dict):
        vars_ = {v.name: v for v in vars_}
    k = k or default_k(reqs)
    if k < 1:
        raise ValueError("k must be at least 1")
    deadline = None if budget_s is None else time.monotonic() + budget_s
    t0 = time.perf_counter()

    def give_up(why: Skip) -> Analysis:
        skipped = {name: why for name in (*ANALYSES, "examples")}
        seconds = {"total": time.perf_counter() - t0}
        return Analysis(
            k, list(reqs), dict(vars_), [], None, "skipped", "skipped", seconds, None, skipped
        )

    if budget_s is not None and (why := _too_large(reqs, vars_, k, budget_s)) is not None:
        return give_up(why)
    tell = progress or _silent
    tell("unroll", None)
    try:
        ctx = Context(reqs, vars_, k, timeout_s, deadline, memory_mb, rlimit)
    except OutOfTime:
        return give_up(
            Skip(
                f"the time budget of {budget_s:g} s ran out while unrolling traces of k = {k} ticks",
                BUDGET,
            )
        )
    except TooLarge as e:
        return give_up(Skip(f"{e} (traces of k = {k} ticks)", BUDGET, (Limit.TRACE_LENGTH, BUDGET)))
    finally:
        tell("unroll", time.perf_counter() - t0)
    findings = _left_out(reqs, ctx)
    steps = _Steps(deadline, budget_s, memory_mb, tell)
    steps.seconds["encode"] = time.perf_counter() - t0
    consistent, consistency_text, realizability_text = _run_analyses(ctx, findings, steps)
    seconds, skipped, memout = steps.seconds, steps.skipped, steps.memout
    seconds["total"] = time.perf_counter() - t0
    order = {s: i for i, s in enumerate(SEVERITIES)}
    max_steps = ctx.max_steps
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
        max_steps,
    )


def _too_large(
    reqs: Sequence[Req], vars_: dict[str, VarInfo], k: int, budget_s: float
) -> Skip | None:
    """Why the unrolling of ``k`` ticks is not started: estimated to need more than the
    whole budget at ``CELLS_PER_S`` (None: it fits)."""
    formulas = [f for r in reqs for f in (r.formula, r.activation)]
    formulas += [f for v in vars_.values() if (f := range_formula(v)) is not None]
    cells = encoding_cells(formulas, k)
    if cells <= budget_s * CELLS_PER_S:
        return None
    return Skip(
        f"unrolling traces of k = {k} ticks builds about {cells:.2g} solver terms, "
        f"about {cells / CELLS_PER_S:.2g} s against a time budget of {budget_s:g} s",
        BUDGET,
        (Limit.TRACE_LENGTH,),
    )


def _left_out(reqs: Sequence[Req], ctx: Context) -> list[Finding]:
    """The warnings known before any solver call: requirements the analyses cannot
    reason about, and non-monotone ones (judged at the end of each trace)."""
    findings = [
        Finding(
            "not-analysed",
            "warning",
            (rid,),
            f"{rid} is left out of the analyses: {why}",
            "nothing to change for the monitor; the analyses just cannot reason about it",
        )
        for rid, why in ctx.unsupported.items()
    ]
    findings += [
        Finding(
            "non-monotone",
            "warning",
            (r.id,),
            r.note or f"{r.id} is non-monotone (false until something happens)",
            "if a per-tick obligation was meant, use a timing such as 'always', "
            "'within N ticks' or 'immediately'; the analyses judge it at the end of "
            "each trace",
        )
        for r in reqs
        if not r.monotone and r.id in ctx.reqs
    ]
    return findings


class _Steps:
    """Runs the analyses one at a time, timed, within the budget and z3's memory:
    what either cut short is recorded in ``skipped`` with the reason."""

    def __init__(
        self,
        deadline: float | None,
        budget_s: float | None,
        memory_mb: int | None,
        progress: Progress = _silent,
    ) -> None:
        self.deadline, self.budget_s = deadline, budget_s
        self.progress = progress
        self.seconds: dict[str, float] = {}
        self.skipped: dict[str, Skip] = {}
        self.reached = f"z3 reached its memory limit of {memory_mb} MB"
        self.memout = False  # once z3 reached its memory limit, its context is not asked again

    def out_of_time(self) -> bool:
        return self.deadline is not None and time.monotonic() >= self.deadline

    def __call__(self, name: str, run: Callable[[], object], default: object) -> object:
        """One analysis, timed; ``default`` when the budget or z3's memory is gone
        before or during it (findings it made before that stay: each was checked on
        its own)."""
        t = time.perf_counter()
        self.progress(name, None)
        if self.memout:
            self.skipped[name] = Skip(f"{self.reached} before it", MEMORY)
            return default
        if self.out_of_time():
            self.skipped[name] = Skip(
                f"the time budget of {self.budget_s:g} s ran out before it", BUDGET
            )
            return default
        try:
            return run()
        except OutOfTime:
            self.skipped[name] = Skip(
                f"stopped: the time budget of {self.budget_s:g} s ran out during it", BUDGET
            )
            return default
        except z3.Z3Exception as e:
            if not is_memout(e):
                raise
            self.memout = True
            self.skipped[name] = Skip(f"stopped: {self.reached}", MEMORY)
            return default
        finally:
            self.seconds[name] = time.perf_counter() - t
            self.progress(name, self.seconds[name])


def _run_analyses(
    ctx: Context, findings: list[Finding], step: _Steps
) -> tuple[bool | None, str, str]:
    """The four analyses in order, each only where the earlier ones allow it; returns
    (consistent, the consistency text, the realizability text)."""
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
    skipped = step.skipped
    # The later analyses need consistency decided: they are skipped for the limit
    # that stopped it.
    undecided = skipped.get("consistency") or (
        Skip(
            f"consistency was not decided: the time budget of {step.budget_s:g} s ran out "
            "during it",
            BUDGET,
        )
        if step.out_of_time()
        else Skip(
            f"consistency was not decided ({ctx.stop_text()})",
            ctx.stopped_by or Limit.SOLVER_RLIMIT,
        )
    )
    if consistent is None and "redundancy" not in skipped:
        skipped["redundancy"] = undecided
    if consistent is None and "realizability" not in skipped:
        skipped["realizability"] = undecided
    if step.memout:  # explain's example traces would ask the same solver
        skipped["examples"] = Skip(step.reached, MEMORY)
    return consistent, consistency_text, realizability_text
