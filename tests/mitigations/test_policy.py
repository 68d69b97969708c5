"""Mitigation policies, tick-precise, on the runtime core: debounce, cooldown,
latch and operator reset, reset after mitigation (zero blind window), reset after
a time, escalation and confirmation.

The policies are a pure state machine (mitigations/policy.py), so these tests
step them with the reference interpreter as the monitor (the shipped double
supervisor.daemon.testing.InterpretedMonitor, no compiler); one test
runs the same scenarios through a real gcc-built monitor and asks for the same
effects, tick for tick."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from mitigations.policy import Note, RequirementPolicy
from mitigations.settings import Confirm, Escalation, PolicyConfig
from mitigations.supervision import Supervision
from monitors.backends.load import compile_spec
from monitors.ir.formula import parse_formula
from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl
from supervisor.daemon.runtime import InputSpec, Monitor, Runtime, StepResult
from supervisor.daemon.testing import InterpretedMonitor

MS = 1_000_000
PERIOD = 10 * MS


@dataclass
class Recorder:
    """A Sink that keeps every effect with the tick it happened at."""

    now_ms: int = 0  # set by drive(): effects are stamped with it
    events: list[tuple[Any, ...]] = field(default_factory=list)

    def report(self, index: int, result: StepResult, policy_state: dict[str, Any]) -> None:
        self.events.append(("report", result.tick, policy_state.get("cooldown")))

    def act(self, index: int, actions: tuple[str, ...], stage: str, t_ns: int) -> None:
        assert t_ns == self.now_ms * MS
        self.events.append(("act", self.now_ms, stage, actions))

    def reset(self, index: int, reason: str) -> None:
        self.events.append(("reset", self.now_ms, reason))

    def note(self, index: int, note: Note, t_ns: int) -> None:
        self.events.append(("note", self.now_ms, note.what))

    def of(self, kind: str) -> list[tuple[Any, ...]]:
        return [e for e in self.events if e[0] == kind]


# Two requirements over inputs p (bool) and halt (bool):
# 0: H p           (past-time always: latches once p was false)
# 1: halt          (a plain invariant)
SPEC = MonitorSpec(
    component="T",
    inputs=[VarDecl("p", "bool"), VarDecl("halt", "bool")],
    requirements=[
        RequirementSpec("always_p", parse_formula("H p")),
        RequirementSpec("halted", parse_formula("halt")),
    ],
)


@pytest.fixture
def monitor() -> Monitor:
    return InterpretedMonitor(SPEC)


def rig(
    monitor: Any, policy: PolicyConfig, repeatable: tuple[str, ...] = ()
) -> tuple[Supervision, Runtime, Recorder]:
    monitor.reset()
    rt = Runtime(
        [InputSpec("p", "bool"), InputSpec("halt", "bool")],
        monitor,
        policy="periodic",
        period_ns=PERIOD,
    )
    rec = Recorder()
    pol = RequirementPolicy(policy, ("stop",), repeatable)
    idle = RequirementPolicy(PolicyConfig(), ("noop",))
    return Supervision(rt, [pol, idle], rec), rt, rec


def drive(sup: Supervision, rt: Runtime, ps: list[bool], halt: bool | list[bool] = True) -> None:
    """One periodic tick per entry of ``ps`` at t = tick * 10 ms; the policy
    clock runs just before each step, as in the daemon's loop.  Reports carry
    the tick, other effects the time in ms."""
    rec = sup.sink
    assert isinstance(rec, Recorder)
    for k, p in enumerate(ps):
        t = rt.tick * PERIOD
        rec.now_ms = t // MS
        h = halt[k] if isinstance(halt, list) else halt
        rt.on_message("p", p, t)
        rt.on_message("halt", h, t)
        sup.on_time(t)
        sup.after_step(rt.on_timer(t))


def test_default_policy_reports_a_latched_always_once(monitor: Any) -> None:
    sup, rt, rec = rig(monitor, PolicyConfig())
    drive(sup, rt, [True, False, True, True, True])
    assert rec.of("report") == [("report", 1, "ok")]  # H p stays false: one episode
    assert rec.of("act") == [("act", 10, "violation", ("stop",))]
    assert rec.of("reset") == []


def test_reset_after_mitigation_zero_blind_window(monitor: Any) -> None:
    """The thesis relaunched the node (1.5 s blind).  Here the monitor is reset
    between two ticks: a violation on the very next tick is reported."""
    sup, rt, rec = rig(monitor, PolicyConfig(reset="after_mitigation"))
    drive(sup, rt, [True, False, False, True, False])
    assert [e[1] for e in rec.of("report")] == [1, 2, 4]
    assert [e[1] for e in rec.of("reset")] == [10, 20, 40]
    # Without the reset, tick 4's violation would be hidden in the latched H p.
    # Ticks are contiguous: nothing was skipped.
    assert [r["tick"] for r in rt.recent] == [0, 1, 2, 3, 4]


def test_debounce_steps(monitor: Any) -> None:
    sup, rt, rec = rig(monitor, PolicyConfig(debounce_steps=3, reset="after_mitigation"))
    drive(sup, rt, [True, False, False, True, False, False, False])
    # H p latches from tick 1: reported after 3 flagged steps; the reset then
    # clears it (p true at tick 3... judged afresh from tick 4), and the
    # debounce counts afresh: ticks 4, 5, 6.
    assert [e[1] for e in rec.of("report")] == [3, 6]
    sup2, rt2, rec2 = rig(monitor, PolicyConfig(debounce_steps=3))
    drive(sup2, rt2, [True, False, True])
    assert rec2.of("report") == []  # flagged on ticks 1, 2 only
    drive(sup2, rt2, [True])
    assert rec2.of("report") == [("report", 3, "ok")]


def test_debounce_ms_fires_on_time(monitor: Any) -> None:
    sup, rt, rec = rig(monitor, PolicyConfig(debounce_ms=25))
    drive(sup, rt, [True, False, True, True, True, True])
    # flagged from tick 1 (10 ms): 25 ms later is 35 ms -> the step at tick 4 (40 ms)
    assert rec.of("report") == [("report", 4, "ok")]


def test_cooldown(monitor: Any) -> None:
    sup, rt, rec = rig(monitor, PolicyConfig(cooldown_ms=30, reset="after_mitigation"))
    drive(sup, rt, [True, False, True, False, True, False, True, True, False])
    reports = rec.of("report")
    assert [(t, c) for _, t, c in reports] == [
        (1, "ok"),
        (3, "suppressed"),
        (5, "ok"),
        (8, "ok"),  # 30 ms after the action at 50 ms
    ]
    assert [e[1] for e in rec.of("act")] == [10, 50, 80]


def test_escalation_when_the_violation_persists(monitor: Any) -> None:
    esc = PolicyConfig(
        reset="after_mitigation", cooldown_ms=1000, escalate=Escalation(35, ("power_off",))
    )
    sup, rt, rec = rig(monitor, esc)
    drive(sup, rt, [True] + [False] * 6)
    acts = rec.of("act")
    assert acts[0] == ("act", 10, "violation", ("stop",))
    # first action at 10 ms; 35 ms later = 45 ms: escalated at the 50 ms tick
    assert acts[1] == ("act", 50, "escalation", ("power_off",))
    assert len(acts) == 2


def test_no_escalation_when_the_robot_recovers(monitor: Any) -> None:
    esc = PolicyConfig(reset="after_mitigation", escalate=Escalation(35, ("power_off",)))
    sup, rt, rec = rig(monitor, esc)
    drive(sup, rt, [True, False, False, True, True, True, True, True])
    assert [a[2] for a in rec.of("act")] == ["violation", "violation"]


def test_escalation_timer_without_steps(monitor: Any) -> None:
    """On-trigger robots may stop stepping; escalation still happens on time."""
    esc = PolicyConfig(escalate=Escalation(100, ("power_off",)))
    sup, rt, rec = rig(monitor, esc)
    drive(sup, rt, [True, False])
    deadline = sup.next_deadline()
    assert deadline == 10 * MS + 100 * MS
    rec.now_ms = 109
    sup.on_time(deadline - 1)
    assert len(rec.of("act")) == 1
    rec.now_ms = 110
    sup.on_time(deadline)
    assert rec.of("act")[-1][2:] == ("escalation", ("power_off",))


def test_confirm_ok_and_failed(monitor: Any) -> None:
    conf = Confirm("halt", True, 25)
    sup, rt, rec = rig(
        monitor, PolicyConfig(confirm=conf, escalate=Escalation(1000, ("power_off",)))
    )
    drive(sup, rt, [True, False, False], halt=[False, False, True])
    assert rec.of("note") == [("note", 20, "confirmed")]
    sup, rt, rec = rig(
        monitor, PolicyConfig(confirm=conf, escalate=Escalation(1000, ("power_off",)))
    )
    drive(sup, rt, [True, False, False, False, False], halt=False)
    # acted at 10 ms, not confirmed by 35 ms: failed at the 40 ms tick, escalated at once
    assert rec.of("note") == [("note", 40, "confirm_failed")]
    assert rec.of("act")[-1] == ("act", 40, "confirm_failed", ("power_off",))


def test_latch_repeats_and_operator_reset_only_when_holding(monitor: Any) -> None:
    sup, rt, rec = rig(
        monitor,
        PolicyConfig(latch=True, reset="after_mitigation", repeat_ms=20),
        repeatable=("stop",),
    )
    drive(sup, rt, [True, False, False, False])
    # Latched: later episodes are reported but not re-acted; the halt is
    # repeated every 20 ms instead.
    assert [a[:3] for a in rec.of("act")] == [("act", 10, "violation"), ("act", 30, "repeat")]
    assert [r[2] for r in rec.of("report")] == ["ok", "latched", "latched"]
    assert sup.latched() == [0]
    refused = sup.operator_reset()
    assert refused == [(0, "still violated at the last tick")]
    drive(sup, rt, [True])  # the requirement holds again (judged afresh after its reset)
    assert sup.operator_reset() == []
    assert sup.latched() == []
    n = len(rec.of("act"))
    drive(sup, rt, [True, True, True, True])
    assert len(rec.of("act")) == n  # no more repeats
    assert ("reset", 40, "operator reset: latch released") in rec.events


def test_reset_after_ms(monitor: Any) -> None:
    sup, rt, rec = rig(monitor, PolicyConfig(reset="after_ms", reset_after_ms=30))
    drive(sup, rt, [True, False, True, True, True, True, True])
    # violated at 10 ms, monitor reset at 40 ms; p holds since tick 2 -> clean afterwards
    assert rec.of("reset") == [("reset", 40, "after_ms:30")]
    assert [e[1] for e in rec.of("report")] == [1]


def test_policy_is_pure_state(monitor: Any) -> None:
    """Idle requirements are not visited (the 20k msg/s fast path)."""
    sup, rt, rec = rig(monitor, PolicyConfig())
    drive(sup, rt, [True, True, True])
    assert sup.active == set() and rec.events == []


# (policy, repeatable actions, p per tick, halt per tick or for all ticks): scenarios
# that reset requirements every way a policy can, for the end-to-end test below.
SCENARIOS: list[tuple[PolicyConfig, tuple[str, ...], list[bool], bool | list[bool]]] = [
    (PolicyConfig(), (), [True, False, True, True, True], True),
    (PolicyConfig(reset="after_mitigation"), (), [True, False, False, True, False], True),
    (
        PolicyConfig(debounce_steps=3, reset="after_mitigation"),
        (),
        [True, False, False, True, False, False, False],
        True,
    ),
    (PolicyConfig(cooldown_ms=30, reset="after_mitigation"), (), [True, False] * 4, True),
    (PolicyConfig(reset="after_ms", reset_after_ms=30), (), [True, False, True, True, True], True),
    (
        PolicyConfig(latch=True, reset="after_mitigation", repeat_ms=20),
        ("stop",),
        [True, False, False, False, True, False],
        True,
    ),
    (
        PolicyConfig(confirm=Confirm("halt", True, 25), escalate=Escalation(1000, ("power_off",))),
        (),
        [True, False, False, True],
        [False, False, True, False],
    ),
]


def _play(monitor: Any, scenario: tuple[Any, ...]) -> tuple[list[Any], list[int], list[int]]:
    """Effects, the ticks stepped and the latched requirements after an operator reset."""
    policy, repeatable, ps, halt = scenario
    sup, rt, rec = rig(monitor, policy, repeatable)
    drive(sup, rt, ps, halt)
    sup.operator_reset()
    drive(sup, rt, [True, True])
    return rec.events, [r["tick"] for r in rt.recent], sup.latched()


def test_a_compiled_monitor_gives_the_same_effects(tmp_path: Path) -> None:
    """End to end through gcc: the interpreted monitor above stands in for the
    compiled one only while both give the same effects on every scenario."""
    compiled = compile_spec(SPEC, tmp_path)
    for scenario in SCENARIOS:
        got = _play(compiled, scenario)
        assert got[0], scenario  # each scenario acts
        assert got == _play(InterpretedMonitor(SPEC), scenario), scenario


POLICY_CONFIG = """component: T
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  halt: {type: bool, topic: /halt, msg: std_msgs/msg/Bool}
requirements:
  - id: r
    text: T shall always satisfy p
    on_violation: [stop]
    policy: POLICY
mitigations:
  stop: {publish: {topic: /halt, msg: std_msgs/msg/Bool, value: {data: true}}}
  power_off: {log: {message: off}}
step: {policy: on_message}
"""


@pytest.mark.parametrize(
    ("policy", "expected"),
    [
        ("{latch: true}", "reset='after_mitigation'"),
        ("{reset: {after_ms: 250}}", "reset_after_ms=250.0"),
        ("{escalate: {after_ms: 500, actions: [power_off]}}", "actions=('power_off',)"),
        ("{confirm: {variable: halt, equals: true, within_ms: 200}}", "equals=True"),
        (
            "{latch: true, reset: never}",
            "9: policy of 'r': latch with reset: never cannot be released",
        ),
        ("{debounce_steps: 0}", "9: policy of 'r': debounce_steps must be a whole number >= 1"),
        ("{escalate: {after_ms: 5, actions: [power_of]}}", "undefined mitigation 'power_of'"),
        ("{confirm: {variable: hlt, equals: true, within_ms: 1}}", "'hlt' is not a topic variable"),
        ("{confirm: {variable: halt, equals: maybe, within_ms: 1}}", "'maybe' is not a bool"),
        ("{reset: sometimes}", "reset must be never, after_mitigation or {after_ms: N}"),
    ],
)
def test_policy_config(tmp_path: Path, policy: str, expected: str) -> None:
    from monitors.errors import UserError
    from supervisor.config import load_config

    path = tmp_path / "c.yaml"
    path.write_text(POLICY_CONFIG.replace("POLICY", policy))
    try:
        got = repr(load_config(path).requirements[0].policy_config)
    except UserError as e:
        got = str(e)
    assert expected in got
