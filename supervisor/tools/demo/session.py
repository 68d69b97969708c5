"""The demo's processes and main loop.

Children (:mod:`supervisor.tools.children`: own process groups, one private ROS
domain, localhost-only discovery): the simulated robot's processes that the
example names (:data:`supervisor.tools.demo.config.EXAMPLES`: the sRobot's
perception feed and safety controller, or the mobile base), and the supervisor
(``safety-supervisor run``) on the demo's copy of the example's shipped config.

The scenario starts once the supervisor has sent ``READY=1`` (on a notify socket
bound here) and every robot process reports its DDS endpoints matched.
Counts and events are read from the supervisor's violation log and from the
robot processes' JSON lines; supervisor ticks from its ``STATUS=``
notifications.  Stopping: the supervisor first (so the robot going quiet is
not reported as stale inputs), then the robot, then every process group is
killed.
"""

from __future__ import annotations

import argparse
import os
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mitigations.violationlog.reader import records_since
from supervisor.tools.children import Child, NotifySocket, daemon_argv
from supervisor.tools.demo.config import EXAMPLES, Example
from supervisor.tools.demo.errors import DemoError
from supervisor.tools.demo.state import DemoState

READY_TIMEOUT_S = 60.0  # compiling the monitor and importing rclpy; slow CI machines
MATCH_TIMEOUT_S = 30.0  # DDS discovery takes ~3 s on localhost
STOP_TIMEOUT_S = 5.0
REFRESH_S = 0.25  # live view, ~4 Hz


def pick_domain() -> int:
    """ROS_DOMAIN_ID if set, else a random private domain."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return random.SystemRandom().randint(1, 200)  # not 0: stay off a real robot's domain
    try:
        domain = int(text)
    except ValueError as e:
        raise DemoError(f"ROS_DOMAIN_ID={text!r} is not a number") from e
    if not 0 <= domain <= 232:
        raise DemoError(f"ROS_DOMAIN_ID={domain} is out of range (0-232)")
    return domain


class LogTail:
    """The violation log's new records since the demo started."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = path.stat().st_size if path.exists() else 0  # --log may append

    def read(self) -> list[dict[str, Any]]:
        records, self.offset = records_since(self.path, self.offset)
        return records


class Notify:
    """The supervisor's notify socket (what systemd would read)."""

    def __init__(self, path: Path) -> None:
        self.socket = NotifySocket(path)
        self.path = path
        self.seen: set[str] = set()

    def poll(self, on_status: Callable[[str], None]) -> None:
        while (data := self.socket.recv(0)) is not None:
            for line in data.splitlines():
                key, _, value = line.partition("=")
                self.seen.add(line if key != "STATUS" else "STATUS")
                if key == "STATUS":
                    on_status(value)

    def close(self) -> None:
        self.socket.close()


@dataclass
class Run:
    args: argparse.Namespace
    workdir: Path
    st: DemoState
    notify: Notify
    tail: LogTail
    out: IO[str]
    live: bool
    example: Example = EXAMPLES["srobot"]
    children: list[Child] = field(default_factory=list)
    matched: set[str] = field(default_factory=set)  # robot processes whose DDS endpoints matched

    def child(self, name: str) -> Child:
        return next(c for c in self.children if c.name == name)

    def pump(self) -> None:
        """Everything that arrived: notifications, log records, robot lines."""
        self.notify.poll(self.st.on_status)
        for rec in self.tail.read():
            self.st.on_record(rec)
        for c in self.children:
            for ev in c.take():
                if ev.get("ev") == "matched":
                    self.matched.add(c.name)
                else:
                    self.st.on_robot(ev)

    def check_alive(self) -> None:
        for c in self.children:
            if not c.alive():
                why = c.last_stderr(skip_warnings=True) or f"exit status {c.returncode}"
                raise DemoError(f"the {c.name} process stopped: {why}")

    def wait(self, what: str, done: Callable[[], bool], timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not done():
            self.pump()
            self.check_alive()
            if time.monotonic() > deadline:
                raise DemoError(f"timed out after {timeout:g} s waiting for {what}")
            time.sleep(0.02)  # polling interval

    def record_args(self) -> list[str]:
        """``run --record DIR`` when the demo records (``demo --record``)."""
        record = getattr(self.args, "record", None)
        return ["--record", str(Path(record).resolve())] if record else []

    def start(self, config: Path, env: dict[str, str]) -> None:
        w = self.workdir
        self.children.append(
            Child(
                "supervisor",
                daemon_argv(config, self.st.log, w / "build", *self.record_args()),
                env={**env, **self.notify.socket.env()},
                cwd=w,
                stderr=w / "supervisor.stderr",
            )
        )
        for name, argv in self.example.processes(self.args, self.st).items():
            self.children.append(
                Child(
                    name,
                    argv,
                    env=env,
                    cwd=w,
                    stderr=w / f"{name}.stderr",
                    stdin=True,
                    json_stdout=True,
                )
            )
        self.say(
            f"starting the supervisor on {self.example.config.name} and {self.example.robot} "
            f"(ROS domain {self.st.domain}){self.example.note}"
        )
        self.wait(
            "the supervisor's READY=1", lambda: "READY=1" in self.notify.seen, READY_TIMEOUT_S
        )
        self.wait(
            "DDS discovery between the robot and the supervisor",
            lambda: all(c.name in self.matched for c in self.children[1:]),
            MATCH_TIMEOUT_S,
        )
        self.st.walk_wall, self.st.walk_mono = time.time(), time.monotonic()
        self.child(self.example.go).send("go")
        self.say(f"supervisor ready, robot matched: {self.example.started}")

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
            self.out.write("\x1b[H\x1b[2J" + self.example.screen(self.st, False) + "\n")
            self.out.flush()
            return
        self.print_events()
        line = self.example.status_line(self.st)
        if line:  # nothing to say before the robot's first cycle
            print(line, file=self.out, flush=True)

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
        self.pump()
