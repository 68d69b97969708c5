"""``safety-supervisor demo``: the thesis's field test (sec. 5.3.2) on this machine.

Three processes, each in its own process group, on a private ROS domain with
localhost-only discovery:

* the perception feed and the safety controller of :mod:`supervisor.tools.demo.robot`;
* the supervisor (``safety-supervisor run``) on a copy of ``config/srobot.yaml``
  written to a temp dir at start, so the shipped config stays the single
  source of truth.  The only changes: the violation log path, and
  ``power_off`` runs a local marker program instead of SSH to a robot PC
  that does not exist here (said on screen).

The walk starts once the supervisor has sent ``READY=1`` (on a notify socket
bound here) and both robot processes report their DDS endpoints matched.
Counts and events are read from the supervisor's violation log (the record
of truth) and from the robot processes' JSON lines; supervisor ticks from its
``STATUS=`` notifications.  On the end of ``--duration``, Ctrl-C, SIGTERM or
an error: the supervisor is stopped first (so the robot going quiet is not
reported as stale inputs), then the robot, then every process group is
killed; then the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import IO, Any

from supervisor import data
from supervisor.tools.demo.robot import OUTPUTS, op_state, zone_of

ROOT = Path(__file__).resolve().parents[3]
SHIPPED_CONFIG = data.example("srobot.yaml")
DEFAULT_FAULT_RATE = 0.01  # the thesis's 1 % (sec. 5.3.2)
READY_TIMEOUT_S = 60.0  # compiling the monitor and importing rclpy; slow CI machines
MATCH_TIMEOUT_S = 30.0  # DDS discovery takes ~3 s on localhost
STOP_TIMEOUT_S = 5.0
REFRESH_S = 0.25  # live view, ~4 Hz
EVENTS_SHOWN = 8

STATE_WORDS = {0: "normal", 1: "alert", 2: "alert + slow down", 3: "stop + UV off"}
CLASS_WORDS = {0: "nobody", 1: "trained worker", 2: "untrained person"}


class DemoError(Exception):
    """A one-line reason the demo cannot go on."""


def _err(text: str) -> None:
    print(f"safety-supervisor demo: {text}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ config


def demo_config(shipped: Path, workdir: Path, log: Path) -> Path:
    """The shipped config with the demo's log and a local stand-in for ``power_off``."""
    import yaml

    try:
        data = yaml.safe_load(shipped.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise DemoError(f"cannot read {shipped}: {e}") from e
    if not isinstance(data, dict):
        raise DemoError(f"{shipped}: not a configuration mapping")
    mitigations = data.setdefault("mitigations", {})
    if "power_off" in mitigations:
        mitigations["power_off"] = {
            "command": {
                "argv": [
                    sys.executable,
                    "-m",
                    "supervisor.tools.demo.robot",
                    "poweroff-marker",
                    str(workdir),
                ],
                "timeout_s": 10,
                "env": {"PYTHONPATH": str(ROOT)},
            }
        }
    data.setdefault("logging", {})["violations"] = str(log)
    path = workdir / "srobot-demo.yaml"
    header = (
        f"# Written by 'safety-supervisor demo' from {shipped}:\n"
        "# the violation log is the demo's, and power_off runs a local marker program\n"
        "# instead of SSH to the robot PC (there is none in the demo).\n"
    )
    path.write_text(header + yaml.safe_dump(data, sort_keys=False, width=100))
    return path


# ------------------------------------------------------------------ processes


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the demo dies, even by SIGKILL."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001, S110 - best effort; process groups are killed anyway
        pass


class Child:
    """A process in its own group; stdout JSON lines to a queue, stderr to a file."""

    def __init__(
        self,
        name: str,
        argv: list[str],
        env: dict[str, str],
        stderr: Path,
        *,
        events: bool,
    ) -> None:
        self.name = name
        self.stderr_path = stderr
        with stderr.open("w") as err:
            self.proc = subprocess.Popen(
                argv,
                cwd=ROOT,
                env=env,
                stdin=subprocess.PIPE if events else subprocess.DEVNULL,
                stdout=subprocess.PIPE if events else subprocess.DEVNULL,
                stderr=err,
                start_new_session=True,  # Ctrl-C reaches the demo only; it stops them in order
                preexec_fn=_die_with_parent,  # noqa: PLW1509 - no threads are running yet
            )
        self.events: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
        self.reader: threading.Thread | None = None
        self.matched = False  # the process reported its DDS endpoints matched

    def start_reader(self) -> None:
        if self.proc.stdout is None:
            return
        self.reader = threading.Thread(target=self._read, name=f"{self.name}-out", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            try:
                ev = json.loads(raw)
            except ValueError:
                continue
            if isinstance(ev, dict):
                self.events.put(ev)

    def send(self, line: str) -> None:
        if self.proc.stdin is not None:
            try:
                self.proc.stdin.write(line.encode() + b"\n")
                self.proc.stdin.flush()
            except (BrokenPipeError, ValueError):
                pass

    def alive(self) -> bool:
        return self.proc.poll() is None

    def last_error(self) -> str:
        try:
            lines = [ln.strip() for ln in self.stderr_path.read_text().splitlines() if ln.strip()]
        except OSError:
            return ""
        for ln in reversed(lines):  # the daemon's FILE:LINE error, not a warning before it
            if "WARNING" not in ln:
                return ln
        return lines[-1] if lines else ""

    def terminate(self) -> None:
        if self.alive():
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass

    def kill(self) -> None:
        """The whole group (with anything it started), then reap."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass


def ros_env(workdir: Path) -> tuple[dict[str, str], int]:
    """The environment of all three processes: one private domain, localhost only."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if text:
        try:
            domain = int(text)
        except ValueError as e:
            raise DemoError(f"ROS_DOMAIN_ID={text!r} is not a number") from e
        if not 0 <= domain <= 232:
            raise DemoError(f"ROS_DOMAIN_ID={domain} is out of range (0-232)")
    else:
        domain = random.SystemRandom().randint(1, 200)  # not 0: stay off a real robot's domain
    env = dict(os.environ)
    for key in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
        env.pop(key, None)
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_LOG_DIR=str(workdir / "ros-log"),  # not ~/.ros
        PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p),
    )
    return env, domain


# ------------------------------------------------------------------ what we know


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
    walk_wall: float | None = None  # time.time() when the walk started
    walk_mono: float | None = None
    # the person and the robot (last controller cycle)
    walk: int = 0
    walk_classes: Counter = field(default_factory=Counter)
    cycle: dict[str, Any] = field(default_factory=dict)
    cycles: int = 0
    state_changes: int = 0
    faults: int = 0
    faults_fixed: int = 0  # the supervisor's uv_off cut a stuck UV light
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
            self.cycles += 1
        elif kind == "state":
            self.state_changes += 1
        elif kind == "fault":
            self.faults += 1
            self.add("fault injected: the UV light stays on in state 3", t)
        elif kind == "uv_off" and ev.get("fixed"):
            self.faults_fixed += 1
            self.add("robot: UV light cut by the supervisor's uv_off", t)

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


# ------------------------------------------------------------------ views


def _pct(rate: float) -> str:
    return f"{rate * 100:g} %"


def person_line(c: dict[str, Any]) -> str:
    cls = c.get("c")
    if not c:
        return "waiting for the first perception cycle"
    if cls == 0:
        return "nobody in sight"
    d = c.get("d")
    return f"{CLASS_WORDS.get(cls, cls)} at {d} m, {zone_of(int(d or 0))} zone"


def robot_line(c: dict[str, Any]) -> str:
    if not c:
        return "-"
    s = c.get("state")
    flags = [
        f"alert {'ON' if c.get('alert') else 'off'}",
        f"slowdown {'ON' if c.get('slowdown') else 'off'}",
        f"halt {'ON' if c.get('halt') else 'off'}",
        f"UV light {'off' if c.get('turnoffUVC') else 'on'}",
    ]
    fault = "   << UV STUCK ON (fault)" if c.get("fault") else ""
    return f"OpState {s} ({STATE_WORDS.get(s, '?')})   {'  '.join(flags)}{fault}"


def _counts(st: DemoState) -> tuple[str, str]:
    v = ", ".join(f"{k} {n}" for k, n in sorted(st.violations.items())) or "none"
    m = (
        ", ".join(
            f"{a} {s.ok} ok" + (f" {s.failed} failed" if s.failed else "")
            for a, s in sorted(st.actions.items())
        )
        or "none"
    )
    return v, m


def supervisor_line(st: DemoState) -> str:
    """The daemon's STATUS= (``ticks=.. violations=.. stale=..``) in words."""
    if not st.status:
        return "starting" if not st.ready else f"{st.ticks} ticks"
    fields = dict(w.partition("=")[::2] for w in st.status.split() if "=" in w)
    if not fields:
        return st.status
    text = f"{st.ticks} ticks   stale inputs: {fields.get('stale', 'none')}"
    if fields.get("waiting_for"):
        text += f"   waiting for: {fields['waiting_for']}"
    if fields.get("latched"):
        text += f"   latched: {fields['latched']}"
    return text


def screen(st: DemoState, final: bool = False) -> str:
    v, m = _counts(st)
    c = st.cycle
    lines = [
        f"safety-supervisor demo   {min(st.elapsed(), st.duration):5.1f} s / {st.duration:g} s   "
        f"ROS domain {st.domain}   fault rate {_pct(st.fault_rate)}   seed {st.seed}",
        "power_off (escalation of operationalstate_3) is simulated here: "
        "a local marker program, no SSH",
        "",
        f"person       walk {st.walk}: {person_line(c)}",
        f"robot        {robot_line(c)}",
        f"supervisor   {supervisor_line(st)}",
        "",
        f"violations   {sum(st.violations.values())}: {v}",
        f"mitigations  {sum(s.ok + s.failed for s in st.actions.values())}: {m}",
        f"faults       {st.faults} injected, {st.faults_fixed} cut by the supervisor",
        "",
        "last events",
    ]
    recent = st.timeline()[-EVENTS_SHOWN:]
    lines += [f"  {e.render()}" for e in recent] or ["  (none yet)"]
    lines += ["", f"violation log: {st.log}"]
    if not final:
        lines.append("Ctrl-C stops the demo")
    return "\n".join(lines)


def status_line(st: DemoState) -> str:
    c = st.cycle
    robot = f"OpState {c.get('state')}" if c else "-"
    if c:
        on = [n for n in ("alert", "slowdown", "halt") if c.get(n)]
        on.append("UV off" if c.get("turnoffUVC") else "UV STUCK ON" if c.get("fault") else "UV on")
        robot += f" ({', '.join(on)})"
    n_mit = sum(s.ok + s.failed for s in st.actions.values())
    return (
        f"{st.elapsed():6.1f} s  walk {st.walk}: {person_line(c)} | {robot} | "
        f"ticks {st.ticks}, violations {sum(st.violations.values())}, mitigations {n_mit}"
    )


def _percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def summary(st: DemoState, elapsed: float, interrupted: bool) -> str:
    classes = ", ".join(
        f"{n} {CLASS_WORDS[c].split()[0]}" for c, n in sorted(st.walk_classes.items())
    )
    ticks = st.stop_record.get("ticks") if st.stop_record else st.ticks
    n_v = sum(st.violations.values())
    n_m = sum(s.ok + s.failed for s in st.actions.values())
    head = "demo interrupted" if interrupted else "demo finished"
    lines = [
        f"{head} after {elapsed:.1f} s (ROS domain {st.domain}, seed {st.seed}, "
        f"fault rate {_pct(st.fault_rate)})",
        f"  walks             {st.walk}" + (f" ({classes})" if classes else ""),
        f"  state changes     {st.state_changes}",
        f"  faults injected   {st.faults} (UV light stuck on in state 3), "
        f"{st.faults_fixed} cut by the supervisor's uv_off",
        f"  supervisor ticks  {ticks}",
        f"  violations        {n_v}",
    ]
    width = max([len(k) for k in st.violations] + [len(k) for k in st.actions] + [16])
    for req, n in sorted(st.violations.items()):
        lines.append(f"    {req:<{width}}  {n}")
    lines.append(f"  mitigations       {n_m}")
    for action, s in sorted(st.actions.items()):
        lat = (
            f"latency p50 {_percentile(s.latencies, 0.5):.1f} ms, max {max(s.latencies):.1f} ms"
            if s.latencies
            else "no latency"
        )
        lines.append(f"    {action:<{width}}  {s.ok} ok, {s.failed} failed, {lat}")
    lines += [
        f"  violation log     {st.log}",
        f"                    (safety-supervisor logs {st.log} --summary)",
    ]
    return "\n".join(lines)


# ------------------------------------------------------------------ the run


class LogTail:
    """New complete JSON lines of the violation log since the demo started."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = path.stat().st_size if path.exists() else 0  # --log may append
        self.partial = b""

    def read(self) -> list[dict[str, Any]]:
        try:
            with self.path.open("rb") as f:
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return []
        self.offset += len(data)
        data = self.partial + data
        *lines, self.partial = data.split(b"\n")
        out = []
        for line in lines:
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict):
                out.append(rec)
        return out


class Notify:
    """The supervisor's notify socket (what systemd would read)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.seen: set[str] = set()

    def poll(self, on_status: Callable[[str], None]) -> None:
        while True:
            try:
                data = self.sock.recv(4096).decode(errors="replace")
            except BlockingIOError:
                return
            for line in data.splitlines():
                key, _, value = line.partition("=")
                self.seen.add(line if key != "STATUS" else "STATUS")
                if key == "STATUS":
                    on_status(value)

    def close(self) -> None:
        self.sock.close()
        self.path.unlink(missing_ok=True)


@dataclass
class Run:
    args: argparse.Namespace
    workdir: Path
    st: DemoState
    notify: Notify
    tail: LogTail
    out: IO[str]
    live: bool
    children: list[Child] = field(default_factory=list)

    def child(self, name: str) -> Child:
        return next(c for c in self.children if c.name == name)

    def pump(self) -> None:
        """Everything that arrived: notifications, log records, robot lines."""
        self.notify.poll(self.st.on_status)
        for rec in self.tail.read():
            self.st.on_record(rec)
        for c in self.children:
            while True:
                try:
                    ev = c.events.get_nowait()
                except queue.Empty:
                    break
                if ev.get("ev") == "matched":
                    c.matched = True
                else:
                    self.st.on_robot(ev)

    def check_alive(self) -> None:
        for c in self.children:
            if not c.alive():
                why = c.last_error() or f"exit status {c.proc.returncode}"
                raise DemoError(f"the {c.name} process stopped: {why}")

    def wait(self, what: str, done: Callable[[], bool], timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not done():
            self.pump()
            self.check_alive()
            if time.monotonic() > deadline:
                raise DemoError(f"timed out after {timeout:g} s waiting for {what}")
            time.sleep(0.02)  # polling interval

    def start(self, config: Path, env: dict[str, str]) -> None:
        py = sys.executable
        self.children.append(
            Child(
                "supervisor",
                [py, "-m", "supervisor", "run", str(config), "--log", str(self.st.log)]
                + ["--build-dir", str(self.workdir / "build")],
                {**env, "NOTIFY_SOCKET": str(self.notify.path)},
                self.workdir / "supervisor.stderr",
                events=False,
            )
        )
        robot = [py, "-m", "supervisor.tools.demo.robot"]
        self.children.append(
            Child(
                "perception",
                [*robot, "perception", "--rate-hz", f"{self.args.rate_hz:g}"]
                + ["--seed", str(self.st.seed)],
                env,
                self.workdir / "perception.stderr",
                events=True,
            )
        )
        self.children.append(
            Child(
                "controller",
                [*robot, "controller", "--fault-rate", repr(self.st.fault_rate)]
                + ["--seed", str(self.st.seed)],
                env,
                self.workdir / "controller.stderr",
                events=True,
            )
        )
        for c in self.children:  # threads only now: preexec_fn ran without any
            c.start_reader()
        self.say(
            f"starting the supervisor on {SHIPPED_CONFIG.name} and the simulated robot "
            f"(ROS domain {self.st.domain}); power_off is simulated: a local marker program, no SSH"
        )
        self.wait(
            "the supervisor's READY=1", lambda: "READY=1" in self.notify.seen, READY_TIMEOUT_S
        )
        self.wait(
            "DDS discovery between the robot and the supervisor",
            lambda: all(c.matched for c in self.children[1:]),
            MATCH_TIMEOUT_S,
        )
        self.st.walk_wall, self.st.walk_mono = time.time(), time.monotonic()
        self.child("perception").send("go")
        self.say("supervisor ready, robot matched: the walk starts")

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)  # the live view clears it at its first redraw

    def loop(self) -> None:
        assert self.st.walk_mono is not None
        end = self.st.walk_mono + self.args.duration
        next_view = time.monotonic()
        while (now := time.monotonic()) < end:
            self.pump()
            self.check_alive()
            if now >= next_view:
                self.view()
                next_view = now + (REFRESH_S if self.live else 1.0)
            time.sleep(min(0.05, max(0.0, end - time.monotonic())))
        self.pump()

    def view(self) -> None:
        if self.live:
            self.out.write("\x1b[H\x1b[2J" + screen(self.st) + "\n")
            self.out.flush()
            return
        self.print_events()
        if self.st.cycle:  # nothing to say before the first perception cycle
            print(status_line(self.st), file=self.out, flush=True)

    def print_events(self, settle: float = 0.5) -> None:
        """Line mode: each event once; a violation once its mitigations are
        logged (a few ms) or ``settle`` s later, so its line says what was done."""
        now = self.st.elapsed()
        for ev in self.st.timeline():
            waiting = ev.requirement is not None and not ev.actions and now - ev.t < settle
            if not ev.shown and not (waiting and settle):
                ev.shown = True
                print(f"{ev.render()}", file=self.out, flush=True)

    def stop(self) -> None:
        """Supervisor first (SIGTERM, STOPPING=1), then the robot, then kill every group."""
        sup = self.children[0] if self.children else None
        if sup is not None and sup.name == "supervisor":
            sup.terminate()
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while sup.alive() and time.monotonic() < deadline:
                self.pump()
                time.sleep(0.02)
        for c in self.children[1:]:
            c.terminate()
            c.send("stop")
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while any(c.alive() for c in self.children) and time.monotonic() < deadline:
            time.sleep(0.02)
        for c in self.children:
            c.kill()
        for c in self.children:
            if c.reader is not None:
                c.reader.join(timeout=1.0)
        self.pump()


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from e
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, not {text}")
    return v


def _rate(text: str) -> float:
    v = _positive(text)
    # The config's stale_after_ms is 500: a slower feed would be reported stale.
    if not 5 <= v <= 100:
        raise argparse.ArgumentTypeError(f"must be between 5 and 100 Hz, not {text}")
    return v


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from e
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, not {text}")
    return v


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "demo",
        help="a simulated sRobot and the supervisor on this machine: violations caught and mitigated",
        description=(
            "Starts a simulated perception feed (a person walking through the red/yellow/"
            "green zones), the sRobot safety controller with the thesis's UV-light fault, "
            "and the supervisor on config/srobot.yaml, each in its own process on a private "
            "ROS domain; shows what happens live and ends with a summary."
        ),
    )
    p.add_argument("--duration", type=_positive, default=30.0, help="seconds (default 30)")
    p.add_argument(
        "--fault-rate",
        type=_fraction,
        default=DEFAULT_FAULT_RATE,
        help="chance per update in state 3 that the UV light sticks on, as in the thesis (default 0.01)",
    )
    p.add_argument(
        "--seed", type=int, default=None, help="the walk and the faults (default: random)"
    )
    p.add_argument("--rate-hz", type=_rate, default=10.0, help="perception rate (default 10)")
    p.add_argument(
        "--log", default=None, metavar="PATH", help="violation log (default: a temp dir)"
    )
    p.add_argument(
        "--no-live", action="store_true", help="one status line per second instead of a live view"
    )


def cmd_demo(args: argparse.Namespace) -> int:
    if not SHIPPED_CONFIG.exists():
        _err(f"{SHIPPED_CONFIG} not found (run from a checkout installed with pip install -e)")
        return 1
    workdir = Path(tempfile.mkdtemp(prefix="safety-supervisor-demo-"))
    log = Path(args.log).resolve() if args.log else workdir / "violations.jsonl"
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(1_000_000)
    out = sys.stdout
    live = out.isatty() and not args.no_live
    interrupted = False
    run: Run | None = None
    failed: str | None = None
    walked = 0.0

    def on_term(_sig: int, _frame: Any) -> None:
        raise KeyboardInterrupt  # SIGTERM: the same orderly stop as Ctrl-C

    old_term = signal.signal(signal.SIGTERM, on_term)
    try:
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            env, domain = ros_env(workdir)
            st = DemoState(args.duration, args.fault_rate, seed, domain, log)
            config = demo_config(SHIPPED_CONFIG, workdir, log)
            run = Run(args, workdir, st, Notify(workdir / "notify.sock"), LogTail(log), out, live)
            run.start(config, env)
            run.loop()
        except KeyboardInterrupt:
            interrupted = True
        except DemoError as e:
            failed = str(e)
        except OSError as e:
            failed = f"{e.strerror or e}" + (f": {e.filename}" if e.filename else "")
        finally:
            # A second Ctrl-C must not leave a process behind half-way through stopping.
            old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            try:
                if run is not None:
                    walked = min(run.st.elapsed(), args.duration)
                    run.stop()
                    run.notify.close()
            finally:
                signal.signal(signal.SIGINT, old_int)
    finally:
        signal.signal(signal.SIGTERM, old_term)
    if run is not None and live:
        out.write("\x1b[H\x1b[2J" + screen(run.st, final=True) + "\n\n")
    elif run is not None:
        run.print_events(settle=0)
    if failed is not None or run is None:
        _err(f"{failed} (process output in {workdir})")
        return 1
    out.write(summary(run.st, walked, interrupted) + "\n")
    out.flush()
    if args.log is not None:  # the log is elsewhere: nothing left worth keeping
        shutil.rmtree(workdir, ignore_errors=True)
    return 130 if interrupted else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m supervisor.tools.demo.run``: the same as ``safety-supervisor demo`` (one error
    handling for every command: the CLI's)."""
    from supervisor.cli import main as cli_main

    return cli_main(["demo", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    raise SystemExit(main())
