"""What the demo knows: the state read from the robot's JSON lines, the
supervisor's violation log records (the record of truth) and its ``STATUS=``
notifications; the events it shows, and the counts of its summary."""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from supervisor.tools.demo.base import EXPLAIN as BASE_EXPLAIN
from supervisor.tools.demo.robot import OUTPUTS, op_state, zone_of

CLASS_WORDS = {0: "nobody", 1: "trained worker", 2: "untrained person"}


@dataclass
class Event:
    t: float  # seconds since the walk started
    text: str
    requirement: str | None = None
    actions: list[str] = field(default_factory=list)
    latency_ms: float | None = None
    shown: bool = False  # printed (line mode)

    def render(self) -> str:
        text = self.text
        if self.actions:
            text += f" -> {', '.join(self.actions)}"
            if self.latency_ms is not None:
                text += f" ({self.latency_ms:.0f} ms)"
        return f"{self.t:6.1f} s  * {text}"


@dataclass
class ActionStats:
    ok: int = 0
    failed: int = 0
    latencies: list[float] = field(default_factory=list)


@dataclass
class DemoState:
    duration: float
    fault_rate: float
    seed: int
    domain: int
    log: Path
    example: str = "srobot"
    requirements: tuple[str, ...] = ()  # the config's, for the summary
    walk_wall: float | None = None  # time.time() when the walk started
    walk_mono: float | None = None
    # the person and the robot (last controller cycle)
    walk: int = 0
    walk_classes: Counter = field(default_factory=Counter)
    cycle: dict[str, Any] = field(default_factory=dict)
    state_changes: int = 0
    faults: int = 0
    faults_fixed: int = 0  # the supervisor's uv_off cut a stuck UV light
    # the mobile base (its JSON lines, supervisor/tools/demo/base.py)
    phase: dict[str, Any] = field(default_factory=dict)  # the scripted phase now
    phases: int = 0
    base: dict[str, Any] = field(default_factory=dict)  # the base's last state line
    estops: int = 0
    base_halts: Counter = field(default_factory=Counter)  # who halted it: estop, supervisor
    last_violation: dict[str, Event] = field(default_factory=dict)
    # the supervisor
    ready: bool = False
    ticks: int = 0
    status: str = ""
    violations: Counter = field(default_factory=Counter)
    actions: dict[str, ActionStats] = field(default_factory=dict)
    supervisor_events: Counter = field(default_factory=Counter)
    stop_record: dict[str, Any] | None = None
    events: deque[Event] = field(default_factory=lambda: deque(maxlen=200))
    open_violation: dict[str, Event] = field(default_factory=dict)

    def elapsed(self) -> float:
        return 0.0 if self.walk_mono is None else time.monotonic() - self.walk_mono

    def at(self, ts: str | float | None) -> float:
        """A log record's ``ts`` (ISO 8601) or a robot line's ``t`` (epoch
        seconds) as seconds since the walk started."""
        if ts is None or self.walk_wall is None:
            return self.elapsed()
        try:
            wall = datetime.fromisoformat(ts).timestamp() if isinstance(ts, str) else float(ts)
        except (TypeError, ValueError):
            return self.elapsed()
        return wall - self.walk_wall

    def timeline(self) -> list[Event]:
        """Events in time order (log records and robot lines arrive separately)."""
        return sorted(self.events, key=lambda e: e.t)

    def add(self, text: str, t: float | None = None, requirement: str | None = None) -> Event:
        ev = Event(self.elapsed() if t is None else t, text, requirement)
        self.events.append(ev)
        return ev

    # ---------------------------------------------------------- robot lines

    def on_robot(self, ev: dict[str, Any]) -> None:
        kind = ev.get("ev")
        t = self.at(ev.get("t"))
        if kind == "walk":
            self.walk = int(ev.get("n", 0))
            cls = int(ev.get("cls", 0))
            self.walk_classes[cls] += 1
            who = {1: "a trained worker", 2: "an untrained person"}.get(cls, str(cls))
            self.add(f"walk {self.walk}: {who} comes closer", t)
        elif kind == "cycle":
            self.cycle = ev
        elif kind == "state":
            self.state_changes += 1
        elif kind == "fault":
            self.faults += 1
            self.add("fault injected: the UV light stays on in state 3", t)
        elif kind == "uv_off" and ev.get("fixed"):
            self.faults_fixed += 1
            self.add("robot: UV light cut by the supervisor's uv_off", t)
        elif kind == "phase":
            self.phase = ev
            self.phases += 1
            breaks = ev.get("breaks")
            self.add(
                f"phase {ev.get('name')}: {ev.get('says')}"
                + (f" (breaks {breaks})" if breaks else ""),
                t,
            )
        elif kind == "base":
            self.base = ev
        elif kind == "estop":
            self.estops += 1
            self.add("base: estop pressed", t)
        elif kind == "halted":
            by = str(ev.get("by") or "?")
            self.base_halts[by] += 1
            self.add(f"base: halted ({'its own estop path' if by == 'estop' else by})", t)
        elif kind == "nav" and ev.get("state") in ("accepted", "succeeded", "aborted"):
            self.add(f"base: navigation goal {ev.get('state')}", t)

    # ---------------------------------------------------------- log records

    def on_record(self, rec: dict[str, Any]) -> None:
        event = rec.get("event")
        t = self.at(rec.get("ts"))
        req = rec.get("requirement")
        if event == "violation" and isinstance(req, str):
            self.violations[req] += 1
            inputs = rec.get("inputs") or {}
            ev = self.add(f"violation {req}: {explain(req, inputs)}", t, req)
            if (rec.get("policy_state") or {}).get("cooldown") == "suppressed":
                ev.text += " (actions suppressed: cooldown)"
            self.open_violation[req] = ev
            self.last_violation[req] = ev
        elif event == "mitigation" and isinstance(req, str):
            action = str(rec.get("action"))
            st = self.actions.setdefault(action, ActionStats())
            ok = bool(rec.get("ok"))
            if ok:
                st.ok += 1
            else:
                st.failed += 1
            latency = rec.get("latency_ms")
            if isinstance(latency, int | float):
                st.latencies.append(float(latency))
            stage = rec.get("stage", "violation")
            label = action if ok else f"{action} FAILED"
            target = self.open_violation.get(req)
            if stage == "violation" and target is not None:
                target.actions.append(label)
                if isinstance(latency, int | float):
                    target.latency_ms = max(target.latency_ms or 0.0, float(latency))
            else:
                what = {
                    "escalation": f"escalation {req}",
                    "stale": f"{req.replace('on_stale:', 'input ')} stale",
                }.get(str(stage), f"{stage} {req}")
                ev = self.add(what, t, req)
                ev.actions.append(label)
                if isinstance(latency, int | float):
                    ev.latency_ms = float(latency)
                if action == "power_off" and ok:
                    ev.text += " (simulated: marker file, no SSH)"
        elif event == "reset" and req == "*":
            self.add("operator reset", t)
        elif event == "supervisor":
            what = str(rec.get("what"))
            self.supervisor_events[what] += 1
            if what == "ready":
                self.ready = True
            elif what == "stop":
                self.stop_record = rec
            elif what in ("input_stale", "input_recovered", "input_problem"):
                self.add(f"supervisor: {what.replace('_', ' ')} {rec.get('input')}", t)

    def on_status(self, status: str) -> None:
        self.status = status
        for word in status.split():
            if word.startswith("ticks="):
                try:
                    self.ticks = int(word[6:])
                except ValueError:
                    pass


def explain(req: str, inputs: dict[str, Any]) -> str:
    """What was wrong, in words: 'UV on in state 3'."""
    if req in BASE_EXPLAIN:
        return BASE_EXPLAIN[req](inputs)
    state = inputs.get("OpState")
    if req.startswith("operationalstate_") and state in OUTPUTS:
        words = {
            "turnoffUVC": ("UV off", "UV on"),
            "halt": ("halted", "not halted"),
            "alert": ("alert on", "alert off"),
            "slowdown": ("slowing down", "not slowing down"),
        }
        wrong = [
            words[name][0] if inputs.get(name) else words[name][1]
            for name, want in OUTPUTS[state].items()
            if name in inputs and bool(inputs[name]) != want
        ]
        if wrong:
            return f"{', '.join(wrong)} in state {state}"
    cls, dist = inputs.get("classifier"), inputs.get("distance_to_target")
    if req.startswith("state_req") and cls in (0, 1, 2) and isinstance(dist, int):
        who = CLASS_WORDS[cls] if cls == 0 else f"{CLASS_WORDS[cls]} at {dist} m ({zone_of(dist)})"
        return f"{who} but OpState {state}, expected {op_state(cls, dist)}"
    shown = ", ".join(f"{k}={v}" for k, v in inputs.items())
    return shown or "requirement violated"
