"""Watchdog pings come from the monitoring loop itself: when the loop stalls
(here: a monitor step that hangs) the pings stop, and they resume with it.
The node runs in this process on a real DDS domain, with a real compiled
monitor; only the hang is injected, by wrapping the monitor's tick."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import SROBOT, ros_node, wait_matched  # noqa: E402
from std_msgs.msg import Bool, Int64  # noqa: E402

from mitigations.violationlog.writer import ViolationLog  # noqa: E402
from monitors.backends.load import compile_spec  # noqa: E402
from supervisor.daemon.node import SupervisorNode  # noqa: E402
from supervisor.daemon.notify import Notifier  # noqa: E402
from supervisor.daemon.process import init_ros  # noqa: E402
from supervisor.daemon.session import build_session  # noqa: E402
from supervisor.pipeline import project_for  # noqa: E402


class HangingMonitor:
    """A real monitor whose tick blocks while ``hang`` is set."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.hang = threading.Event()
        self.release = threading.Event()
        self.hung = threading.Event()

    def tick(self, values: Any) -> Any:
        if self.hang.is_set():
            self.hung.set()
            self.release.wait(10)
        return self.inner.tick(values)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_watchdog_stops_when_the_loop_stalls(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    monkeypatch.setenv("NOTIFY_SOCKET", str(sock_path))
    project = project_for(SROBOT)
    monitor = HangingMonitor(compile_spec(project.spec(), tmp_path / "build"))
    session = build_session(project, monitor)
    pings: list[float] = []

    def listen(stop: threading.Event) -> None:
        sock.settimeout(0.05)
        while not stop.is_set():
            try:
                data = sock.recv(4096).decode()
            except TimeoutError:
                continue
            if "WATCHDOG=1" in data.splitlines():
                pings.append(time.monotonic())

    with ros_node() as robot, ViolationLog(tmp_path / "v.jsonl", "sRobot", "x") as log:
        ctx = init_ros()
        node = SupervisorNode(session, log, context=ctx, notifier=Notifier(), watchdog_s=0.1)
        stop = threading.Event()
        listener = threading.Thread(target=listen, args=(stop,))
        loop = threading.Thread(target=node.run)
        listener.start()
        loop.start()
        try:
            pubs = {
                topic: robot.create_publisher(t, topic, 10)
                for topic, t in [
                    ("/sRobotClassifier", Int64),
                    ("/scan", Int64),
                    ("/sRobotState", Int64),
                    ("/sRobotAlert", Bool),
                    ("/sRobotSlowdown", Bool),
                    ("/sRobotHalt", Bool),
                    ("/sRobotTurnoffUVC", Bool),
                ]
            }
            wait_matched(list(pubs.values()))
            time.sleep(0.6)  # observation window for the pings, not synchronisation
            assert len(pings) >= 4, pings
            monitor.hang.set()
            for pub in pubs.values():  # a full state, the trigger last: one step
                pub.publish(Int64(data=0) if pub.msg_type is Int64 else Bool(data=False))
            assert monitor.hung.wait(10), "the step never ran"
            t_hang = time.monotonic()
            time.sleep(0.6)  # observation window
            during = [t for t in pings if t > t_hang + 0.15]  # one ping may be in flight
            assert during == [], "pings continued while the loop was stuck in a step"
            monitor.hang.clear()
            monitor.release.set()
            t_release = time.monotonic()
            time.sleep(0.6)  # observation window
            assert len([t for t in pings if t > t_release]) >= 3
        finally:
            monitor.release.set()
            node.stop()
            loop.join(5)
            stop.set()
            listener.join(5)
            node.close()
            from supervisor.daemon.process import _shutdown_ros

            _shutdown_ros(ctx)
            sock.close()
