"""The monitoring core (supervisor/daemon/core.py): logical time.

Every timer runs at its own deadline, so what the core decides is a function of
the messages and their receive times only, not of when the loop got round to
its timed work.  That is what makes replay equal to the daemon (the same Core
over the same messages).  The monitor is real compiled C; the log is a recorder
of the calls (the writer itself is tested in test_log.py).
"""

from __future__ import annotations

import random
import textwrap
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from projects import project_of

from mitigations.violationlog.testing import MemoryLog
from monitors.backends.load import compile_spec
from supervisor.daemon.core import Core
from supervisor.daemon.session import build_session

MS = 1_000_000

CONFIG = """\
component: rover
step: {policy: periodic, period_ms: 10, stale_after_ms: 50}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
requirements:
  - id: limit
    text: rover shall always satisfy speed <= 2.0
    on_violation: [stop]
    policy: {debounce_steps: 2, cooldown_ms: 30, reset: after_mitigation,
             escalate: {after_ms: 40, actions: [note]}}
  - id: halt_follows
    text: rover shall always satisfy speed > 3.0 -> halted
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: held
    text: rover shall always satisfy speed < 2.5 | halted
    on_violation: [note]
    policy: {latch: true, repeat_ms: 25, reset: after_mitigation}
on_stale: [stop]
mitigations:
  stop: {log: {message: stop}}
  note: {log: {message: note}}
"""


def _call(r: dict[str, Any]) -> tuple[Any, ...]:
    """The fields of a log record the comparisons judge."""
    if r["event"] == "violation":
        return ("violation", r["requirement"], r["tick"], tuple(sorted(r["inputs"].items())))
    if r["event"] == "mitigation":
        return ("mitigation", r["requirement"], r["action"], r["ok"])
    if r["event"] == "reset":
        return ("reset", r["requirement"], r["reason"], r.get("tick"))
    return ("supervisor", r["what"], r.get("input"), r.get("detail"))


class Calls:
    """The core's log (a MemoryLog) and action outputs, in order, times included."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []
        self.log = MemoryLog(lambda r: self.calls.append(_call(r)))

    def submit(self, request: Any) -> None:
        self.calls.append(("act", request.requirement, request.actions, request.stage,
                           request.detected_ns))  # fmt: skip


@pytest.fixture(scope="module")
def project(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return project_of(tmp_path_factory.mktemp("core"), CONFIG)


def new_core(project: Any) -> tuple[Core, Calls]:
    p, d = project
    # A private copy of the monitor for each core: each has its own C state.
    monitor = compile_spec(p.spec(), Path(d) / "build")
    calls = Calls()
    session = build_session(p, monitor)
    core = Core(session, calls.log, calls.submit, warn=lambda _text: None)
    return core, calls


def drive(project: Any, messages: list[tuple[int, str, Any]], wakes: list[int], end: int) -> Calls:
    """Feed ``messages`` in order; the loop also wakes at ``wakes`` (its timed
    work); finally time reaches ``end``."""
    core, calls = new_core(project)
    core.start(0)
    pending = sorted(wakes)
    for t, name, value in messages:
        while pending and pending[0] <= t:
            core.advance(pending.pop(0))
        core.message(name, value, t)
    for w in pending:
        core.advance(w)
    core.advance(end)
    return calls


def schedule(seed: int, n: int) -> list[tuple[int, str, Any]]:
    rng = random.Random(seed)
    t, out = 0, []
    for _ in range(n):
        t += rng.choice([1, 2, 3, 7, 15]) * MS // 2 + rng.randint(0, 999)
        if rng.random() < 0.03:
            t += 80 * MS  # a silence: inputs go stale
        name = rng.choice(["speed", "halted"])
        value = round(rng.uniform(0.0, 4.0), 2) if name == "speed" else rng.random() < 0.5
        out.append((t, name, value))
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), wake_seed=st.integers(0, 10_000))
def test_decisions_do_not_depend_on_when_the_loop_wakes(project, seed, wake_seed):
    messages = schedule(seed, 150)
    end = messages[-1][0] + 200 * MS
    rng = random.Random(wake_seed)
    wakes = sorted(rng.randint(0, end) for _ in range(rng.randint(0, 300)))
    lazy = drive(project, messages, [], end)  # timers only when a message comes
    busy = drive(project, messages, wakes, end)
    assert busy.calls == lazy.calls
    kinds = {c[0] for c in lazy.calls}
    assert "violation" in kinds  # the schedule exercises the policies


@pytest.fixture(scope="module")
def event_project(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """CONFIG stepped on every message: its only timers are the stale inputs' and the
    policies' (with a periodic step, the next tick is nearly always the earliest)."""
    d = tmp_path_factory.mktemp("core_event")
    text = textwrap.dedent(CONFIG).replace(
        "step: {policy: periodic, period_ms: 10, stale_after_ms: 50}",
        "step: {policy: on_message, stale_after_ms: 50}",
    )
    return project_of(d, text)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), reset_seed=st.integers(0, 10_000), periodic=st.booleans())
def test_the_loops_wake_up_time_is_never_after_a_deadline(
    project, event_project, seed, reset_seed, periodic
):
    """The daemon's loop sleeps until ``next_due`` and ``advance`` returns at once
    before it: both rely on it never being later than the true next deadline,
    whatever the policies, stale inputs and operator resets did meanwhile."""
    project = project if periodic else event_project
    messages = schedule(seed, 150)
    rng = random.Random(reset_seed)
    core, calls = new_core(project)
    core.start(0)
    resets = 0

    def bound_holds(now: int) -> None:
        true_next = core.next_deadline(now)
        due = core.next_due(now)
        assert true_next is None or (due is not None and due <= true_next), (now, due, true_next)

    for t, name, value in messages:
        # the loop as node.py runs it: woken at next_due until the message's time
        while (due := core.next_due(t)) is not None and due <= t:
            core.advance(due)
            bound_holds(due)
        core.message(name, value, t)
        bound_holds(t)
        if rng.random() < 0.05:
            resets += 1
            core.operator_reset(t, via="test")
            bound_holds(t)
    end = messages[-1][0] + 200 * MS
    core.advance(end)
    if not resets:  # and it decides what a loop waking only for messages decides
        assert calls.calls == drive(project, messages, [], end).calls


def test_a_late_loop_catches_up_tick_by_tick(project):
    core, calls = new_core(project)
    core.start(0)
    core.message("speed", 1.0, 1 * MS)
    core.message("halted", False, 2 * MS)
    assert core.session.runtime.tick == 0  # nothing before both inputs had a value
    core.advance(95 * MS)  # the loop was away for 9 periods
    assert core.session.runtime.tick == 9  # steps at 10, 20, ... 90 ms
    stale = [c for c in calls.calls if c[:2] == ("supervisor", "input_stale")]
    assert [c[2] for c in stale] == ["speed", "halted"]
    # silent for more than 50 ms: stale at 51 ms after the last message, not later
    acts = [c for c in calls.calls if c[0] == "act" and c[3] == "stale"]
    assert [c[4] for c in acts] == [51 * MS + 1, 52 * MS + 1]


def test_violation_policy_timers_run_at_their_deadlines(project):
    core, calls = new_core(project)
    core.start(0)
    core.message("halted", True, 1 * MS)
    for k in range(1, 8):  # speed 2.2 (over the limit) every 5 ms: stays fresh
        core.message("speed", 2.2, k * 5 * MS)
    core.advance(40 * MS)
    acts = [c for c in calls.calls if c[0] == "act" and c[1] == "limit"]
    # debounced over 2 steps: the steps at 10 and 20 ms; acted at the second
    assert acts[0][3] == "violation" and acts[0][4] == 20 * MS


def test_operator_reset_is_ordered_by_time(project):
    core, calls = new_core(project)
    core.start(0)
    core.message("halted", False, 1 * MS)
    core.message("speed", 2.6, 2 * MS)  # 'held' breaks at the step at 10 ms: latched
    assert core.operator_reset(11 * MS, via="test") == ["held (still violated at the last tick)"]
    assert core.supervision.latched()
    core.message("speed", 1.0, 12 * MS)
    # The reset at 21 ms follows the step at 20 ms, where 'held' holds again.
    assert core.operator_reset(21 * MS, via="test") == []
    assert not core.supervision.latched()
    assert len([c for c in calls.calls if c[0] == "reset" and c[1] == "*"]) == 2


def test_an_operator_reset_of_one_requirement_leaves_the_others(project):
    core, calls = new_core(project)
    core.start(0)
    core.message("halted", False, 1 * MS)
    core.message("speed", 2.6, 2 * MS)  # 'held' latches at the step at 10 ms
    core.message("speed", 1.0, 12 * MS)
    core.advance(21 * MS)
    assert core.supervision.latched() == [2]
    with pytest.raises(KeyError):
        core.operator_reset(22 * MS, "nope")
    assert core.operator_reset(23 * MS, "limit", via="ui", client="127.0.0.1") == []
    assert core.supervision.latched() == [2]  # only 'limit' was reset
    assert core.operator_reset(24 * MS, "held", via="ui") == []
    assert core.supervision.latched() == []
    resets = [c for c in calls.calls if c[0] == "reset" and c[2] == "operator reset"]
    assert [c[1] for c in resets] == ["limit", "held"]
