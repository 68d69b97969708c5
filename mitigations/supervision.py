"""Monitor verdicts -> policies -> effects, for one runtime (no rclpy, no threads).

The daemon's loop and offline tests drive the same object: after each step
:meth:`Supervision.after_step`, when :meth:`next_deadline` passes
:meth:`on_time`.  Effects go to a :class:`Sink` in the order the policy
returns them (report before act), and monitor resets are applied here,
between two steps, so no tick goes unjudged.

Only requirements that were flagged or still have live policy state are
visited: at 20k steps/s the common case (nothing violated) costs one check.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

from mitigations.policy import (
    Act,
    Armed,
    Effect,
    Forecast,
    Note,
    Report,
    RequirementPolicy,
    ResetMonitor,
)


class Step(Protocol):
    """One monitor step: which requirements it flagged, and the inputs it saw."""

    @property
    def tick(self) -> int: ...
    @property
    def t_ns(self) -> int: ...
    @property
    def violated(self) -> Sequence[int]: ...  # requirement indices
    @property
    def inputs(self) -> Mapping[str, Any]: ...


class Stepper(Protocol):
    """What supervision needs of the runtime that steps the monitor (the daemon's
    Runtime has it): the latest values, and resetting the monitor's requirements."""

    def snapshot(self) -> dict[str, Any]: ...
    def reset_requirement(self, index: int) -> None: ...
    def reset_all(self) -> None: ...
    def margins(self) -> Sequence[float]: ...  # asked only when a requirement predicts


class Sink(Protocol):
    """Where effects go (the daemon: log, engine, ROS; tests: a list)."""

    # predicted_ms is passed only when the violation followed a prediction
    def report(
        self, index: int, result: Step, policy_state: dict[str, Any], **predicted: float
    ) -> None: ...
    def act(self, index: int, actions: tuple[str, ...], stage: str, t_ns: int) -> None: ...
    def reset(self, index: int, reason: str) -> None: ...
    def note(self, index: int, note: Note, t_ns: int) -> None: ...
    def forecast(self, index: int, forecast: Forecast, result: Step | None, t_ns: int) -> None: ...


class Supervision:
    def __init__(self, runtime: Stepper, policies: Sequence[RequirementPolicy], sink: Sink) -> None:
        self.runtime = runtime
        self.policies = list(policies)
        self.sink = sink
        self.active: set[int] = set()  # requirements whose policy has live state
        # requirements with ``predict:``: their margins are read after every step
        self.predicting = [i for i, p in enumerate(self.policies) if p.trend is not None]
        # Per requirement, what its next violation does first when that is known before
        # the step (RequirementPolicy.armed): kept up to date after each of its effects.
        self.armed: list[Armed | None] = [p.armed() for p in self.policies]

    def halt_plan(self, violated: Sequence[int], t_ns: int) -> list[tuple[int, Armed]] | None:
        """The step's violations in :meth:`after_step`'s order with what each does
        first, when every one is armed and nothing else is visited (no live
        policy state, no prediction): the core then writes their records and runs
        their actions before the rest of the step (docs/reference/log.md#the-halt-path).
        None: the step goes :meth:`after_step`'s way alone."""
        if self.active or self.predicting:
            return None
        plan = []
        for i in set(violated) | self.active:  # after_step's order (active is empty)
            armed = self.armed[i]
            if armed is None or t_ns < armed.from_ns:
                return None
            plan.append((i, armed))
        return plan

    def after_step(self, result: Step | None) -> None:
        if result is None:
            return
        if self.predicting:
            self._predict(result)
        if not (result.violated or self.active):
            return
        violated = set(result.violated)
        for i in violated | self.active:
            effects = self.policies[i].on_step(
                i in violated, result.tick, result.t_ns, result.inputs
            )
            self._apply(i, effects, result, result.t_ns)

    def _predict(self, result: Step) -> None:
        # Before the violations of the same step: a prediction's expiry is decided
        # before a violation after the horizon is reported.
        margins = self.runtime.margins()
        flagged = result.violated
        for i in self.predicting:
            effects = self.policies[i].on_margin(
                float(margins[i]), i in flagged, result.tick, result.t_ns
            )
            self._apply(i, effects, result, result.t_ns)

    def next_deadline(self) -> int | None:
        times = [d for i in self.active if (d := self.policies[i].next_deadline()) is not None]
        return min(times) if times else None

    def on_time(self, now: int) -> None:
        if not self.active:
            return
        values = self.runtime.snapshot()
        for i in list(self.active):
            pol = self.policies[i]
            d = pol.next_deadline()
            if d is not None and d <= now:
                self._apply(i, pol.on_time(now, values), None, now)

    def operator_reset(self, only: int | None = None) -> list[tuple[int, str]]:
        """Reset every requirement's monitor (or requirement ``only``'s) and lift the
        latches of those that hold; returns the refused ones (index, why)."""
        refused = []
        for i, pol in enumerate(self.policies):
            if only is not None and i != only:
                continue
            ok, why = pol.operator_reset()
            if not ok:
                refused.append((i, why))
            elif why == "latch released":
                self.sink.reset(i, "operator reset: latch released")
            if ok:
                self.active.discard(i)
            self.armed[i] = pol.armed()
        if only is None:
            self.runtime.reset_all()
        elif not refused:
            self.runtime.reset_requirement(only)
        return refused

    def latched(self) -> list[int]:
        return sorted(i for i in self.active if self.policies[i].latched)

    def _apply(self, i: int, effects: list[Effect], result: Step | None, t_ns: int) -> None:
        for eff in effects:
            if isinstance(eff, Report):
                assert result is not None
                if eff.predicted_ms is None:
                    self.sink.report(i, result, eff.policy_state)
                else:
                    self.sink.report(i, result, eff.policy_state, predicted_ms=eff.predicted_ms)
            elif isinstance(eff, Act):
                self.sink.act(i, eff.actions, eff.stage, t_ns)
            elif isinstance(eff, ResetMonitor):
                self.runtime.reset_requirement(i)
                self.sink.reset(i, eff.reason)
            elif isinstance(eff, Note):
                self.sink.note(i, eff, t_ns)
            elif isinstance(eff, Forecast):
                self.sink.forecast(i, eff, result, t_ns)
        pol = self.policies[i]
        if pol.active:
            self.active.add(i)
            self.armed[i] = None
        else:
            self.active.discard(i)
            self.armed[i] = pol.armed()
