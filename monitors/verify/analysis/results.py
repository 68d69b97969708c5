"""What the analyses report: findings, example traces, and the whole analysis."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from monitors.verify.analysis.requirements import Req, VarInfo
from monitors.verify.interpret import Value

Trace = list[dict[str, Value]]
SEVERITIES = ("error", "warning", "info")


@dataclass
class Finding:
    kind: str  # conflict | unrealizable | realizability | vacuous | unreachable | redundant
    #            | non-monotone | not-analysed | assumption-reads-outputs | no-outputs
    #            | k-too-small
    severity: str  # error | warning | info
    requirements: tuple[str, ...]
    message: str
    fix: str
    trace: Trace | None = None
    trace_note: str = ""
    # the interpreter's verdict per tick for each requirement of the finding on its
    # trace (what the report prints next to the values)
    verdicts: dict[str, list[bool]] = field(default_factory=dict)


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
    skipped: dict[str, str] = field(default_factory=dict)

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
            self.skipped.setdefault("examples", "the time budget ran out")
            return None, None
