"""The halt path (Core._halt_first, docs/reference/log.md#the-halt-path): when every
violation of a step is armed, the core writes their records and submits their
actions before the policies run.  Against the same core without it (a log that
has no ``violation_row``), on random schedules with a real compiled monitor and a
real log file: the same actions in the same order at the same times, the same
records byte for byte apart from the order inside a step (the step's violations
and their actions come first), and the path is taken."""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from projects import project_of

import mitigations.violationlog.writer as writer
from mitigations.violationlog.writer import ViolationLog
from monitors.backends.load import compile_spec
from supervisor.daemon.core import Core
from supervisor.daemon.session import build_session

MS = 1_000_000

CONFIG = """\
component: rover
step: {policy: on_trigger, trigger: beat, stale_after_ms: 50}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
  beat: {type: bool, topic: /beat, msg: std_msgs/msg/Bool}
requirements:
  - id: fast
    text: rover shall always satisfy speed <= 2.0
    on_violation: [stop, note]
    policy: {cooldown_ms: 30, reset: after_mitigation, escalate: {after_ms: 40, actions: [note]}}
  - id: halt_follows
    text: rover shall always satisfy speed > 3.0 -> halted
    on_violation: [stop]
    policy: {reset: after_mitigation}
  - id: held
    text: rover shall always satisfy speed < 2.5 | halted
    on_violation: [note]
    policy: {latch: true, repeat_ms: 25, reset: after_mitigation}
  - id: debounced
    text: rover shall always satisfy speed < 3.5
    on_violation: [stop]
    policy: {debounce_steps: 2, reset: after_mitigation}
on_stale: [stop]
mitigations:
  stop: {log: {message: stop}}
  note: {log: {message: note}}
"""


class Plain:
    """The same log without the halt path's entry (Core then never takes it)."""

    def __init__(self, log: ViolationLog) -> None:
        self._log = log

    def __getattr__(self, name: str) -> Any:
        if name == "violation_row":
            raise AttributeError(name)
        return getattr(self._log, name)


@pytest.fixture(scope="module")
def project(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return project_of(tmp_path_factory.mktemp("halt"), CONFIG)


def schedule(seed: int, n: int) -> list[tuple[int, str, Any]]:
    rng = random.Random(seed)
    t, out = 0, []
    for _ in range(n):
        t += rng.choice([1, 2, 3, 7, 15]) * MS // 2 + rng.randint(0, 999)
        if rng.random() < 0.02:
            t += 80 * MS  # a silence: inputs go stale
        name = rng.choice(["speed", "halted", "beat", "beat", "reset"])
        value: Any = rng.random() < 0.5
        if name == "speed":  # mostly within the limits, now and then over them
            value = 1.0 if rng.random() < 0.7 else round(rng.uniform(2.0, 4.0), 2)
        out.append((t, name, value))
    return out


def run(project: Any, path: Path, messages: list[tuple[int, str, Any]], halt_path: bool) -> Any:
    p, d = project
    monitor = compile_spec(p.spec(), Path(d) / f"build-{halt_path}")
    times = iter(range(10**6))
    writer._now = lambda: f"2026-11-28T03:00:00.{next(times):06d}Z"  # the same stamps
    log = ViolationLog(path, "rover", "c0" * 32, echo=False)
    acts: list[tuple[Any, ...]] = []
    taken = []
    if halt_path:
        row = log.violation_row

        def counted(*args: Any, **kw: Any) -> Any:
            taken.append(1)
            return row(*args, **kw)

        log.violation_row = counted  # type: ignore[method-assign]

    def submit(r: Any) -> None:
        acts.append((r.requirement, r.actions, r.stage, r.detected_ns))

    session = build_session(p, monitor)
    core = Core(session, log if halt_path else Plain(log), submit, warn=lambda _t: None)
    core.start(0)
    for t, name, value in messages:
        if name == "reset":  # an operator lifts the latches of those that hold
            core.operator_reset(t)
        else:
            core.message(name, value, t)
        log.flush()  # as the daemon's loop does after each message (receive.py)
    core.advance(messages[-1][0] + 200 * MS)
    log.close()
    return acts, len(taken)


def records(path: Path) -> list[dict[str, Any]]:
    out = []
    for line in path.read_text().splitlines():
        r = json.loads(line)
        for k in ("ts", "prev_sha256", "line_sha256", "seq"):
            r.pop(k)
        out.append(r)
    return out


def by_step(recs: list[dict[str, Any]]) -> list[list[str]]:
    """The records cut where a violation follows a record that is not one: the
    records of one step's violations, then what else happened until the next."""
    groups: list[list[str]] = []
    for r in recs:
        text = json.dumps(r, sort_keys=True)
        if r["event"] == "violation" and (not groups or groups[-1][-1][0] != "v"):
            groups.append([])
        if not groups:
            groups.append([])
        groups[-1].append(("v" if r["event"] == "violation" else "o") + text)
    return groups


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_the_halt_path_changes_nothing_but_the_order_inside_a_step(
    project: Any, tmp_path_factory: pytest.TempPathFactory, seed: int
) -> None:
    d = tmp_path_factory.mktemp("run")
    messages = schedule(seed, 300)
    plain_acts, _ = run(project, d / "plain.jsonl", messages, halt_path=False)
    fast_acts, taken = run(project, d / "fast.jsonl", messages, halt_path=True)
    assert fast_acts == plain_acts
    plain, fast = records(d / "plain.jsonl"), records(d / "fast.jsonl")
    assert sorted(map(str, fast)) == sorted(map(str, plain))
    # per requirement, its own records in the same order
    for req in ("fast", "halt_follows", "held", "debounced"):
        assert [r for r in fast if r.get("requirement") == req] == [
            r for r in plain if r.get("requirement") == req
        ]
    violations = sum(r["event"] == "violation" for r in plain)
    assert violations > 0 and taken > 0, (violations, taken)
    # a step's violations come before the rest of that step (its resets, escalations)
    for group in by_step(fast):
        kinds = [g[0] for g in group]
        assert kinds == sorted(kinds, key="vo".index)
