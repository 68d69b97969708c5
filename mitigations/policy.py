"""Per-requirement mitigation policy: when a flagged tick becomes an action.

Pure and tick-precise: no threads, no clocks, no rclpy.  The monitoring loop
calls :meth:`RequirementPolicy.on_step` after each monitor step (and
:meth:`on_time` when :meth:`next_deadline` passes without a step) and carries
out the returned effects in order: a :class:`Report` is written (fsynced)
before the :class:`Act` that follows it is submitted, and a
:class:`ResetMonitor` is applied before the next step, so a reset never costs
a tick (the thesis relaunched the node and was blind for 1.5 s).

Vocabulary:
- a *run* is a sequence of consecutive flagged steps;
- an *episode* starts when a run passes the debounce (``debounce_steps`` steps
  and ``debounce_ms``); it is reported once and ends at the next step that
  holds, or when the requirement's monitor is reset (so a violation right
  after a reset is a new report: zero blind window);
- an *incident* starts with the first action and lasts while the requirement
  keeps being violated (every step flagged, across monitor resets); escalation
  and confirmation are timed from its start.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mitigations.prediction import Trend
from mitigations.settings import PolicyConfig

MS = 1_000_000


@dataclass(frozen=True)
class Report:
    """Write a ``violation`` record now (before any action of this step)."""

    tick: int
    policy_state: dict[str, Any]
    # The lead time of the prediction this violation followed, in ms (None: none open)
    predicted_ms: float | None = None


@dataclass(frozen=True)
class Act:
    """Run these mitigations (on the engine's workers)."""

    actions: tuple[str, ...]
    stage: str  # violation | escalation | confirm_failed | repeat | prediction


@dataclass(frozen=True)
class ResetMonitor:
    """Reset this requirement's monitor state before the next step."""

    reason: str


@dataclass(frozen=True)
class Note:
    """Something for the log that is neither a violation nor an action."""

    what: str  # confirmed | confirm_failed
    detail: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Forecast:
    """Write a ``prediction`` record (a violation is expected within the horizon)
    before any action of this step, or a ``prediction_expired`` one (the horizon
    passed without it); docs/reference/prediction.md."""

    what: str  # prediction | prediction_expired
    detail: dict[str, Any] = field(default_factory=dict)


Effect = Report | Act | ResetMonitor | Note | Forecast

# Earlier than any time a step is given (monotonic or recorded nanoseconds).
_ALWAYS = -(1 << 63)


@dataclass(frozen=True)
class Armed:
    """What a requirement's next flagged step does first, at any time from
    ``from_ns`` on: write its violation record with ``policy_state``, then run
    ``actions`` (the halt path; docs/reference/log.md#the-halt-path)."""

    from_ns: int
    policy_state: dict[str, Any]
    actions: tuple[str, ...]


@dataclass
class RequirementPolicy:
    config: PolicyConfig
    on_violation: tuple[str, ...]
    repeatable: tuple[str, ...] = ()  # actions re-run while latched (publish kinds)
    # run / episode
    run_steps: int = 0
    run_since_ns: int | None = None
    in_episode: bool = False
    holds: bool = True  # the last step did not flag
    # incident (first action while the requirement keeps being violated)
    incident_ns: int | None = None
    escalated: bool = False
    confirm_deadline_ns: int | None = None
    last_act_ns: int | None = None
    latched: bool = False
    next_repeat_ns: int | None = None
    reset_due_ns: int | None = None
    # counters (diagnostics)
    violations: int = 0
    last_violation_tick: int | None = None
    # prediction (config.predict; docs/reference/prediction.md)
    trend: Trend | None = None  # built from config.predict
    predicted_ns: int | None = None  # the open prediction's time
    predicted_tick: int | None = None
    predict_run: int = 0  # consecutive steps whose estimate is inside the horizon
    predict_armed: bool = True  # the estimate left the horizon since the last prediction
    last_early_ns: int | None = None  # the early actions' last run (their cooldown)
    predictions: int = 0

    def __post_init__(self) -> None:
        p = self.config.predict
        if p is not None and self.trend is None:
            self.trend = Trend(p.window_ms, p.horizon_ms)

    @property
    def active(self) -> bool:
        """Has state that a non-flagged step or the clock can change."""
        return (
            self.run_steps > 0
            or self.in_episode
            or self.incident_ns is not None
            or self.latched
            or self.reset_due_ns is not None
        )

    def armed(self) -> Armed | None:
        """What :meth:`on_step` would do first if the next step flagged this
        requirement, when that does not depend on the step: the first two effects
        of :meth:`on_step` itself, run on a copy, when they are a :class:`Report`
        and the violation's :class:`Act`.  None with live state (:attr:`active`),
        with a debounce, or with ``predict:`` (the margin's trend decides)."""
        if self.active or self.trend is not None:
            return None
        since = _ALWAYS
        if self.last_act_ns is not None:  # cooling before then (_episode)
            since = self.last_act_ns + math.ceil(self.config.cooldown_ms * MS)
        # A shallow copy: with no trend, on_step changes only the copy's own fields.
        trial = dataclasses.replace(self)
        first = trial.on_step(True, 0, since, {})[:2]
        if (
            len(first) == 2
            and isinstance(first[0], Report)
            and first[0].predicted_ms is None
            and isinstance(first[1], Act)
            and first[1].stage == "violation"
        ):
            return Armed(since, first[0].policy_state, first[1].actions)
        return None

    def state(self) -> dict[str, Any]:
        """The ``policy_state`` of violation records and diagnostics."""
        c = self.config
        return {
            "flagged_steps": self.run_steps,
            "debounce_steps": c.debounce_steps,
            "debounce_ms": c.debounce_ms,
            "reset": c.reset if c.reset != "after_ms" else f"after_ms:{c.reset_after_ms:g}",
            "latched": self.latched,
            "escalated": self.escalated,
            "violations": self.violations,
        }

    # ------------------------------------------------------------ steps

    def on_step(
        self, flagged: bool, tick: int, t_ns: int, values: Mapping[str, Any]
    ) -> list[Effect]:
        c = self.config
        effects: list[Effect] = []
        self.holds = not flagged
        if not flagged:
            self.run_steps, self.run_since_ns, self.in_episode = 0, None, False
            self.incident_ns, self.escalated = None, False  # the robot recovered
        else:
            if self.run_steps == 0:
                self.run_since_ns = t_ns
            self.run_steps += 1
            assert self.run_since_ns is not None
            debounced = (
                self.run_steps >= c.debounce_steps
                and t_ns - self.run_since_ns >= c.debounce_ms * MS
            )
            if debounced and not self.in_episode:
                effects += self._episode(tick, t_ns)
        effects += self.on_time(t_ns, values)
        return effects

    def _episode(self, tick: int, t_ns: int) -> list[Effect]:
        c = self.config
        self.in_episode = True
        self.violations += 1
        self.last_violation_tick = tick
        cooling = self.last_act_ns is not None and t_ns - self.last_act_ns < c.cooldown_ms * MS
        state = self.state()
        state["cooldown"] = "suppressed" if cooling else "ok"
        if self.latched:
            state["cooldown"] = "latched"  # the mitigation is in force, repeated at repeat_ms
        lead = None
        if self.predicted_ns is not None:  # the violation came as predicted
            lead = round((t_ns - self.predicted_ns) / MS, 3)
            state["predicted_tick"] = self.predicted_tick
            self.predicted_ns = self.predicted_tick = None
        effects: list[Effect] = [Report(tick, state, lead)]
        if not cooling and not self.latched:  # else policy_state says why not
            effects.append(Act(self.on_violation, "violation"))
            self.last_act_ns = t_ns
        if self.incident_ns is None:
            self.incident_ns = t_ns
            if c.confirm is not None:
                self.confirm_deadline_ns = t_ns + int(c.confirm.within_ms * MS)
        if c.latch and not self.latched:
            self.latched = True
            self.next_repeat_ns = t_ns + int(c.repeat_ms * MS)
        if c.reset == "after_mitigation":
            effects.append(self._reset("after_mitigation"))
        elif c.reset == "after_ms" and self.reset_due_ns is None:
            assert c.reset_after_ms is not None
            self.reset_due_ns = t_ns + int(c.reset_after_ms * MS)
        return effects

    def _reset(self, reason: str) -> ResetMonitor:
        # The monitor forgets its history: the next step is judged afresh and a
        # flag there is a new episode (reported), but the incident goes on.
        self.run_steps, self.run_since_ns, self.in_episode = 0, None, False
        self.reset_due_ns = None
        if self.trend is not None:  # the margins start again with the monitor
            self.trend.clear()
        return ResetMonitor(reason)

    # ------------------------------------------------------------ prediction

    def on_margin(self, margin: float, flagged: bool, tick: int, t_ns: int) -> list[Effect]:
        """This step's margin (before :meth:`on_step` of the same step).  An estimate
        inside the horizon, confident enough, on ``debounce_steps`` steps in a row
        while the requirement holds, opens a prediction: a :class:`Forecast` record,
        then the early actions unless within ``cooldown_ms`` of their last run or
        latched.  One prediction is open at a time; it ends at the violation (whose
        record carries the lead time) or, expired, at the first step past the
        horizon at which the requirement holds and the estimate is no longer inside
        the horizon.  The next one needs an estimate that left the horizon in
        between: a line fitted across a stop keeps pointing at 0 for up to a window
        after it."""
        p, trend = self.config.predict, self.trend
        if p is None or trend is None:
            return []
        trend.add(t_ns, margin)
        est = trend.estimate()
        inside = not (
            est is None
            or est.ttv_ms is None
            or not est.margin > 0.0
            or est.ttv_ms > p.horizon_ms
            or est.confidence < p.min_confidence
        )
        # An open prediction expires at a step that holds, past the horizon, once the
        # trend no longer points at a violation within it: a violation a step after
        # the horizon (0 is crossed between steps) still counts as predicted.
        expired = [] if flagged or inside else self._expire(t_ns)
        if flagged or self.in_episode or self.latched or self.predicted_ns is not None:
            self.predict_run = 0
            return expired
        if not inside:
            self.predict_run = 0
            self.predict_armed = True
            return expired
        assert est is not None and est.ttv_ms is not None
        if not self.predict_armed:  # still the estimate that made the last prediction
            return expired
        self.predict_run += 1
        if self.predict_run < self.config.debounce_steps:
            return expired
        self.predict_run, self.predict_armed = 0, False
        self.predicted_ns, self.predicted_tick = t_ns, tick
        self.predictions += 1
        c = self.config
        cooling = self.last_early_ns is not None and t_ns - self.last_early_ns < c.cooldown_ms * MS
        run = bool(p.actions) and not cooling
        detail = {
            "tick": tick,
            "margin": est.margin,
            "fitted": est.fitted,
            "slope": est.slope,
            "slope_se": est.slope_se,
            "ttv_ms": est.ttv_ms,
            "ttv_lo_ms": est.ttv_lo_ms,
            "ttv_hi_ms": est.ttv_hi_ms,
            "confidence": est.confidence,
            "samples": est.samples,
            "window_ms": p.window_ms,
            "horizon_ms": p.horizon_ms,
            "min_confidence": p.min_confidence,
            "actions": list(p.actions),
            "cooldown": "suppressed" if p.actions and cooling else "ok",
        }
        effects: list[Effect] = [*expired, Forecast("prediction", detail)]
        if run:
            effects.append(Act(p.actions, "prediction"))
            self.last_early_ns = t_ns
        return effects

    def _expire(self, t_ns: int) -> list[Effect]:
        p = self.config.predict
        if self.predicted_ns is None or p is None:
            return []
        if t_ns <= self.predicted_ns + int(p.horizon_ms * MS):
            return []
        detail = {
            "predicted_tick": self.predicted_tick,
            "horizon_ms": p.horizon_ms,
            "after_ms": round((t_ns - self.predicted_ns) / MS, 3),
        }
        self.predicted_ns = self.predicted_tick = None
        return [Forecast("prediction_expired", detail)]

    # ------------------------------------------------------------ clock

    def next_deadline(self) -> int | None:
        """When :meth:`on_time` has something to do even without a step."""
        times = [self.reset_due_ns, self.confirm_deadline_ns, self.next_repeat_ns]
        c = self.config
        if self.incident_ns is not None and c.escalate is not None and not self.escalated:
            times.append(self.incident_ns + int(c.escalate.after_ms * MS))
        # No debounce_ms deadline: an episode starts at a step (on_step), never in
        # on_time, and a deadline on_time cannot move would hold the core's clock.
        live = [t for t in times if t is not None]
        return min(live) if live else None

    def on_time(self, t_ns: int, values: Mapping[str, Any]) -> list[Effect]:
        c = self.config
        effects: list[Effect] = []
        if self.confirm_deadline_ns is not None and c.confirm is not None:
            if values.get(c.confirm.variable) == c.confirm.equals:
                self.confirm_deadline_ns = None
                effects.append(Note("confirmed", {"variable": c.confirm.variable}))
            elif t_ns >= self.confirm_deadline_ns:
                self.confirm_deadline_ns = None
                effects.append(
                    Note(
                        "confirm_failed",
                        {
                            "variable": c.confirm.variable,
                            "expected": c.confirm.equals,
                            "actual": values.get(c.confirm.variable),
                            "within_ms": c.confirm.within_ms,
                        },
                    )
                )
                if c.escalate is not None and not self.escalated:
                    self.escalated = True
                    effects.append(Act(c.escalate.actions, "confirm_failed"))
        if (
            self.incident_ns is not None
            and c.escalate is not None
            and not self.escalated
            and t_ns >= self.incident_ns + int(c.escalate.after_ms * MS)
        ):
            self.escalated = True
            effects.append(Act(c.escalate.actions, "escalation"))
        if self.reset_due_ns is not None and t_ns >= self.reset_due_ns:
            effects.append(self._reset(f"after_ms:{c.reset_after_ms:g}"))
        if self.latched and self.next_repeat_ns is not None and t_ns >= self.next_repeat_ns:
            self.next_repeat_ns = t_ns + int(c.repeat_ms * MS)
            if self.repeatable:
                effects.append(Act(self.repeatable, "repeat"))
        return effects

    # ------------------------------------------------------------ operator

    def operator_reset(self) -> tuple[bool, str]:
        """An operator asks to lift the mitigation: only if the requirement holds."""
        if self.latched and not self.holds:
            return False, "still violated at the last tick"
        was = self.latched
        self.latched, self.next_repeat_ns = False, None
        self.incident_ns, self.escalated, self.confirm_deadline_ns = None, False, None
        self.run_steps, self.run_since_ns, self.in_episode = 0, None, False
        self.reset_due_ns = None
        if self.trend is not None:  # the operator reset resets the monitor too
            self.trend.clear()
        return True, "latch released" if was else "reset"
