"""The shipped robot-side heartbeat guard (supervisor/data/examples/heartbeat_guard.py)
over real DDS with the real daemon.

The guard runs as its own process, as on a robot.  While the daemon's heartbeat
flows, no stop is published; the daemon killed with SIGKILL, the guard publishes a
zero Twist within its timeout (plus discovery and scheduling margin), and the time
from the kill to the stop is printed.  Then beats from this process: the guard
re-arms after increasing beats and stops at once when the counter goes back.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from supervisor.data import example

GUARD = example("heartbeat_guard.py")
TIMEOUT_S = 0.5  # 3 heartbeat periods and a margin for a loaded test machine
STOP_TOPIC = "/test_guard/cmd_vel"


class Guard:
    """The example as a process of its own on the test run's ROS domain."""

    def __init__(self, tmp: Path) -> None:
        from rosutil import DOMAIN_ID

        from supervisor.tools.children import ros_env

        self.stderr_path = tmp / "guard.stderr"
        self.stderr = self.stderr_path.open("w")
        argv = [sys.executable, str(GUARD), "--stop-topic", STOP_TOPIC,
                "--timeout", str(TIMEOUT_S)]  # fmt: skip
        self.proc = subprocess.Popen(
            argv, env={**os.environ, **ros_env(DOMAIN_ID)}, stderr=self.stderr,
            stdin=subprocess.DEVNULL, start_new_session=True,
        )  # fmt: skip

    def lines(self) -> list[str]:
        return self.stderr_path.read_text().splitlines()

    def said(self, text: str, after: int = 0) -> bool:
        return any(text in line for line in self.lines()[after:])

    def close(self) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.stderr.close()
        return self.proc.returncode


def test_bad_arguments_are_one_line() -> None:
    for args in (["--timeout", "x"], ["--timeout", "nan"], ["--rearm", "0"], ["--check", "-1"]):
        r = subprocess.run(
            [sys.executable, str(GUARD), *args], capture_output=True, text=True, timeout=60
        )
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, (args, r.stderr)
        assert r.stderr.startswith("heartbeat_guard: ") and "Traceback" not in r.stderr


def test_the_decision_takes_only_its_clock_and_the_counter() -> None:
    from supervisor.data.examples.heartbeat_guard import Watch

    w = Watch(timeout_s=0.35, rearm=3)
    assert not w.live(0.0)  # stopped until the heartbeat is live
    for i, t in enumerate((0.0, 0.1, 0.2), start=1):
        assert w.beat(i, t) is None
    assert w.live(0.3) and w.live(0.54) and not w.live(0.56)
    assert w.beat(3, 0.6) is not None and not w.live(0.6)  # repeated: restart or forgery
    assert w.beat(1, 0.7) is not None  # back to 1: a restarted supervisor
    assert [w.beat(i, 0.7 + i / 10) for i in (2, 3)] == [None, None] and not w.live(1.0)
    assert w.beat(4, 1.1) is None and w.live(1.1)  # three increasing beats: re-armed


@pytest.mark.ros
@pytest.mark.slow
def test_the_guard_stops_the_base_when_the_supervisor_dies(tmp_path: Path, robot_node: Any) -> None:
    from geometry_msgs.msg import Twist
    from rosutil import Daemon, spin_once, spin_until, variant, wait_until
    from std_msgs.msg import UInt64

    stops: list[tuple[float, Any]] = []
    robot_node.create_subscription(
        Twist, STOP_TOPIC, lambda m: stops.append((time.monotonic(), m)), 100
    )
    guard = Guard(tmp_path)
    d: Daemon | None = None
    try:
        # stopped until the heartbeat is live; its stops reaching us also say that
        # DDS discovery is done, so a later stop can be timed
        spin_until(robot_node, "the guard's stops before any heartbeat", lambda: stops, 20)
        d = Daemon(tmp_path, variant(tmp_path))
        d.wait_notify("READY=1", timeout=60)
        wait_until("the guard armed by the heartbeat", lambda: guard.said("live (counter"), 30,
                   lambda: "\n".join(guard.lines()) + (d.explain() if d else ""))  # fmt: skip
        # the stops sent before it armed arrive (queued while the daemon started)
        for _ in range(20):
            before, drain = len(stops), time.monotonic() + 0.5
            while time.monotonic() < drain:
                spin_once(robot_node)
            if len(stops) == before:
                break
        # heartbeat flowing: no stop
        stops.clear()
        quiet_until = time.monotonic() + 3.0
        while time.monotonic() < quiet_until:
            spin_once(robot_node)
        assert stops == [], guard.lines()
        assert not guard.said("stopping", after=1), guard.lines()

        # the supervisor dies: the stop comes within the timeout and a margin
        seen = len(guard.lines())
        t_kill = time.monotonic()  # kill() returns once reaped: take the time first
        d.child.kill()
        spin_until(robot_node, "the guard's stop", lambda: stops, TIMEOUT_S + 5)
        latency = stops[0][0] - t_kill
        m = stops[0][1]
        assert (m.linear.x, m.linear.y, m.linear.z, m.angular.x, m.angular.y, m.angular.z) == (
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        )
        assert guard.said("stopping: no heartbeat for", after=seen), guard.lines()
        print(f"\nheartbeat guard: stop {1000 * latency:.0f} ms after the supervisor's SIGKILL "
              f"(timeout {1000 * TIMEOUT_S:.0f} ms)")  # fmt: skip
        # and keeps the base stopped
        n = len(stops)
        spin_until(robot_node, "repeated stops", lambda: len(stops) >= n + 3, 5)

        # beats from this process (a restarted supervisor, or a forger): the guard
        # re-arms after increasing beats, and stops when the counter goes back
        beats = robot_node.create_publisher(UInt64, "/safety_supervisor/heartbeat", 1)
        wait_until("the guard's subscription", lambda: beats.get_subscription_count() > 0, 15)
        counter = 0

        def beat_for(seconds: float, until: Any = None) -> None:
            """Beats every 100 ms, spinning our node in between."""
            nonlocal counter
            end = time.monotonic() + seconds
            next_beat = time.monotonic()
            while time.monotonic() < end and not (until and until()):
                if time.monotonic() >= next_beat:
                    counter += 1
                    beats.publish(UInt64(data=counter))
                    next_beat = time.monotonic() + 0.1
                spin_once(robot_node, timeout=max(0.0, next_beat - time.monotonic()))

        seen = len(guard.lines())
        beat_for(15, lambda: guard.said("live (counter", after=seen))
        assert guard.said("live (counter", after=seen), guard.lines()
        beat_for(0.5)  # the stops sent before it re-armed arrive
        stops.clear()
        beat_for(1.0)
        assert stops == [], guard.lines()  # anyone's beats keep it live: not a forgery guard
        t_back = time.monotonic()
        beats.publish(UInt64(data=counter - 1))
        spin_until(robot_node, "the stop on a decreasing counter", lambda: stops, 5)
        assert guard.said(f"counter went from {counter} to {counter - 1}"), guard.lines()
        print(f"heartbeat guard: stop {1000 * (stops[0][0] - t_back):.0f} ms after a "
              "decreasing counter")  # fmt: skip
        assert guard.close() == 0, guard.lines()
        assert guard.said("leaving: stop published"), guard.lines()
    finally:
        guard.close()
        if d is not None:
            d.close()
