"""One computed injection: the trace to publish and what the supervisor should log."""

from __future__ import annotations

from dataclasses import dataclass, field

from monitors.verify.interpret import Value

Trace = list[dict[str, Value]]


@dataclass
class Injection:
    req: str
    text: str
    k: int
    trace: Trace  # the k ticks, topic variables only
    broken: list[str]  # other monitored requirements that must break too
    broken_ranges: list[str]  # variables whose declared range must break
    early: bool  # REQ holds before its last tick (else it is already violated earlier)
    tick_violations: list[list[str]]  # per tick: requirements false there (interpreter)
    expected: list[str]  # what the supervisor should log: REQ and the broken ones
    notes: list[str] = field(default_factory=list)
