"""Test doubles for the daemon's runtime and core, shipped with the package (as
``structlog.testing`` is) so that users' tests need not write their own.

:class:`RecordingMonitor` stands where the runtime expects a compiled monitor
(:class:`supervisor.daemon.runtime.Monitor`): the step policies, stale inputs,
ages, rates and events can be driven tick by tick without gcc, and the values
the monitor would have been stepped with are kept.  Which requirements a step
flags is the test's to say (``flags``); by default none.
:class:`InterpretedMonitor` judges a :class:`monitors.ir.spec.MonitorSpec`'s
requirements with the reference interpreter, so that policies can be tested on
real formulas without gcc.  The violation log's double is
:class:`mitigations.violationlog.testing.MemoryLog`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from monitors.ir.spec import MonitorSpec
from monitors.verify.interpret import Value, verdicts


class RecordingMonitor:
    """A monitor of ``requirements`` requirements that keeps every tick's values
    (``ticks``) and every reset (``resets``: None for all, else the index).
    ``flags(values)`` gives each requirement's flag (1 = violated) for a tick."""

    def __init__(
        self,
        requirements: int,
        flags: Callable[[Sequence[Any]], Sequence[int]] | None = None,
    ) -> None:
        self.requirements = requirements
        self.ticks: list[list[Any]] = []
        self.resets: list[int | None] = []
        self._flags = flags

    def tick(self, values: Sequence[Any]) -> Sequence[int]:
        self.ticks.append(list(values))
        if self._flags is None:
            return [0] * self.requirements
        out = list(self._flags(values))
        if len(out) != self.requirements:
            raise ValueError(f"flags gave {len(out)} flags for {self.requirements} requirements")
        return out

    def reset(self) -> None:
        self.resets.append(None)

    def reset_requirement(self, index: int) -> None:
        self.resets.append(index)


class InterpretedMonitor:
    """The runtime's monitor by the reference interpreter (monitors/verify/interpret.py):
    each requirement is judged on the trace since its own last reset, which is what a
    reset means for the compiled monitor (a fresh requirement is at tick 0 again).
    Slow (each tick re-judges the trace): for tests of a few hundred ticks."""

    def __init__(self, spec: MonitorSpec) -> None:
        self.spec = spec
        self._traces: list[list[dict[str, Value]]] = [[] for _ in spec.requirements]

    def tick(self, values: Sequence[Any]) -> bytes:
        row = dict(zip((v.name for v in self.spec.inputs), values, strict=True))
        flags = []
        for req, trace in zip(self.spec.requirements, self._traces, strict=True):
            trace.append(row)
            flags.append(0 if verdicts(req.formula, trace)[-1] else 1)
        return bytes(flags)

    def reset(self) -> None:
        for trace in self._traces:
            trace.clear()

    def reset_requirement(self, index: int) -> None:
        self._traces[index].clear()
