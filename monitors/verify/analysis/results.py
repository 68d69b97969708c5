"""What the analyses report: findings, example traces, and the whole analysis.

The analyses speak of their own limits (the trace length, z3's resource limit
and the wall-clock cap per solver call, the time budget, z3's memory) as :class:`Limit` values, never by the name a
caller gives them (a config key, a command-line option): the caller words them
(supervisor/analysis_report.py for the supervisor's ``check`` and ``explain``).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field

from monitors.verify.analysis.requirements import Req, VarInfo
from monitors.verify.interpret import Value

Trace = list[dict[str, Value]]
SEVERITIES = ("error", "warning", "info")


class Limit(enum.Enum):
    """A limit the caller sets on the analyses (the arguments of ``analyse``)."""

    TRACE_LENGTH = "k"  # ticks per analysed trace
    SOLVER_RLIMIT = "rlimit"  # z3 resource units per solver call (deterministic)
    SOLVER_TIMEOUT = "timeout_s"  # wall-clock cap per solver call (a safety net)
    TIME_BUDGET = "budget_s"  # seconds for all the analyses together
    MEMORY = "memory_mb"  # what z3 may hold


@dataclass(frozen=True)
class Remedy:
    """A limit that, changed, lets a finding be decided or said with more certainty:
    raise ``limit`` (to ``at_least`` when that value is known)."""

    limit: Limit
    at_least: int | None = None


@dataclass(frozen=True)
class Skip:
    """Why an analysis was skipped or stopped: ``reason`` in the analyses' words,
    the ``limit`` that was reached, and the limits whose change would let it run
    (``remedies``, beyond raising ``limit`` itself)."""

    reason: str
    limit: Limit
    remedies: tuple[Limit, ...] = ()


@dataclass
class Finding:
    kind: str  # conflict | unrealizable | realizability | vacuous | unreachable | redundant
    #            | non-monotone | not-analysed | assumption-reads-outputs | no-outputs
    #            | k-too-small
    severity: str  # error | warning | info
    requirements: tuple[str, ...]
    message: str
    fix: str  # what to change in the requirements ("" when only ``remedy`` helps)
    trace: Trace | None = None
    trace_note: str = ""
    # the interpreter's verdict per tick for each requirement of the finding on its
    # trace (what the report prints next to the values)
    verdicts: dict[str, list[bool]] = field(default_factory=dict)
    # a limit of the analyses to change, said before ``fix`` ("raise it, or ...")
    remedy: Remedy | None = None


@dataclass
class Example:
    trace: Trace
    note: str
    verdicts: dict[str, list[bool]]


ExampleFinder = Callable[[str], tuple[Example | None, Example | None]]


@dataclass
class Analysis:
    k: int
    requirements: list[Req]
    variables: dict[str, VarInfo]
    findings: list[Finding]
    consistent: bool | None
    consistency: str
    realizability: str
    seconds: dict[str, float]
    # answers examples() from the analyses' solver, which stays alive for it
    find_examples: ExampleFinder | None = field(default=None, repr=False)
    # analysis name -> why it was skipped or stopped (the time budget, docs/reference/faults.md)
    skipped: dict[str, Skip] = field(default_factory=dict)
    # the most z3 resource units one query of the analyses took (analysis.rlimit)
    max_steps: int = 0

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "error"]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "warning"]

    def concerning(self, rid: str) -> list[Finding]:
        return [f for f in self.findings if rid in f.requirements]

    def examples(self, rid: str) -> tuple[Example | None, Example | None]:
        """A shortest trace satisfying ``rid`` (triggered, if it can be) and one
        violating it, both re-checked with the interpreter."""
        if self.find_examples is None:
            return None, None
        from monitors.verify.bmc import OutOfTime  # z3: loaded by whoever set find_examples

        try:
            return self.find_examples(rid)
        except OutOfTime:
            self.skipped.setdefault("examples", Skip("the time budget ran out", Limit.TIME_BUDGET))
            return None, None
