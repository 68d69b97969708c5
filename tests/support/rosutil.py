"""Real-DDS test helpers: the daemon as a subprocess with its own notify
socket, and an rclpy node in the test process, both isolated by one random
ROS_DOMAIN_ID per test run and localhost-only discovery."""

from __future__ import annotations

import json
import os
import random
import re
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from std_msgs.msg import Bool, Int64

from supervisor import data
from supervisor.tools.children import Child, NotifySocket, daemon_argv, ros_env, ros_vars

ROOT = Path(__file__).resolve().parents[2]
# pytest-xdist's workers (gw0, gw1, ...) of one run never share a domain: worker i of
# n draws from the ids i + 1, i + 1 + n, ... (without xdist: any of 1..200).
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
DOMAIN_ID = random.randrange(1 + _WORKER % _WORKERS, 201, _WORKERS)
ROS_ENV = ros_vars(DOMAIN_ID)
SROBOT = data.example("srobot.yaml")
# Daemons started and not closed yet.  A test that fails between starting one and
# closing it must not leave it running: it would hold the domain's control socket,
# and every later daemon test of this worker would fail to start (conftest.py
# closes what is left after each test).
_OPEN: set[Daemon] = set()


def close_leftovers() -> int:
    """Close the daemons the finished test left running; how many there were."""
    left = list(_OPEN)
    for d in left:
        d.close()
    return len(left)


def wait_until(
    what: str, predicate: Callable[[], Any], timeout: float, explain: Callable[[], str] = lambda: ""
) -> Any:
    """Poll ``predicate`` until it returns something truthy (no fixed sleeps)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}\n{explain()}")
        time.sleep(0.02)  # polling interval, not synchronisation


class Daemon:
    """``safety-supervisor run CONFIG`` started as the tools start it
    (:mod:`supervisor.tools.children`), with NOTIFY_SOCKET bound here."""

    def __init__(
        self,
        tmp: Path,
        config: Path = SROBOT,
        *,
        env: dict[str, str] | None = None,
        args: list[str] | None = None,
    ) -> None:
        self.log = tmp / "v.jsonl"
        self.notify = NotifySocket(tmp / "notify.sock")
        self.spawn(
            tmp,
            daemon_argv(config, self.log, tmp / "build", *(args or [])),
            {**ros_env(DOMAIN_ID), **self.notify.env(), **(env or {})},
            cwd=ROOT,
        )

    def spawn(self, tmp: Path, argv: list[str], env: dict[str, str], *, cwd: Path) -> None:
        self.stderr = tmp / "daemon.stderr"
        self.child = Child("daemon", argv, env=env, cwd=cwd, stderr=self.stderr)
        self.proc = self.child.proc
        _OPEN.add(self)
        # (monotonic time received, datagram)
        self.notifications: list[tuple[float, str]] = []

    def explain(self) -> str:
        return (
            f"notifications: {[n for _, n in self.notifications][-20:]}\n"
            f"log: {self.records()[-20:]}\nstderr:\n{self.stderr.read_text()}"
        )

    def wait_notify(self, key: str, timeout: float) -> float:
        """Seconds until a datagram with the line ``key`` (e.g. READY=1) arrives."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {key} within {timeout} s\n{self.explain()}")
            if self.proc.poll() is not None and key != "STOPPING=1":
                raise AssertionError(
                    f"daemon exited ({self.proc.returncode}) before {key}\n{self.explain()}"
                )
            data = self.recv(min(left, 0.5))
            if data is not None and key in data.splitlines():
                return time.monotonic() - t0

    def recv(self, timeout: float) -> str | None:
        datagram = self.notify.recv(timeout)
        if datagram is not None:
            self.notifications.append((time.monotonic(), datagram))
        return datagram

    def collect(self, seconds: float) -> list[tuple[float, str]]:
        """All datagrams received during the next ``seconds``."""
        start = len(self.notifications)
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.recv(left)
        return self.notifications[start:]

    def records(self) -> list[dict[str, Any]]:
        if not self.log.exists():
            return []
        lines = self.log.read_text().splitlines()
        return [json.loads(line) for line in lines if line.endswith("}")]

    def wait_record(
        self, predicate: Callable[[dict[str, Any]], bool], what: str, timeout: float = 10
    ) -> dict[str, Any]:
        return wait_until(
            what,
            lambda: next((r for r in self.records() if predicate(r)), None),
            timeout,
            self.explain,
        )

    def terminate(self, budget: float = 2.0) -> None:
        """SIGTERM: STOPPING=1, exit 0, within ``budget`` seconds."""
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        self.wait_notify("STOPPING=1", timeout=budget)
        self.proc.wait(timeout=max(0.1, budget - (time.monotonic() - t0)))
        assert time.monotonic() - t0 < budget
        assert self.proc.returncode == 0, self.explain()

    def close(self) -> None:
        self.child.kill()
        self.notify.close()
        _OPEN.discard(self)


@contextmanager
def ros_node(name: str = "test_robot") -> Iterator[Any]:
    """An rclpy node in this process on the test run's domain."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    for k, v in ROS_ENV.items():
        os.environ[k] = v
    ctx = Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID, signal_handler_options=SignalHandlerOptions.NO)
    node = Node(name, context=ctx)
    try:
        yield node
    finally:
        ex = _EXECUTORS.pop(id(node), None)
        if ex is not None:
            ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def wait_matched(pubs: list[Any], timeout: float = 15) -> None:
    """Until every publisher has a subscription (DDS discovery, ~3 s here)."""
    wait_until(
        "the daemon's subscriptions to be discovered",
        lambda: all(p.get_subscription_count() > 0 for p in pubs),
        timeout,
    )


_EXECUTORS: dict[int, Any] = {}


def spin_once(node: Any, timeout: float = 0.05) -> None:
    """Run ``node``'s ready callbacks (an executor on the node's own context)."""
    from rclpy.executors import SingleThreadedExecutor

    ex = _EXECUTORS.get(id(node))
    if ex is None or ex.context is not node.context:
        ex = _EXECUTORS[id(node)] = SingleThreadedExecutor(context=node.context)
        ex.add_node(node)
    ex.spin_once(timeout_sec=timeout)


def spin_until(node: Any, what: str, predicate: Callable[[], Any], timeout: float) -> Any:
    """Spin ``node`` (its subscriptions' callbacks) until ``predicate()``."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        spin_once(node)


class StatusWatch:
    """The daemon's status documents (/safety_supervisor/status, ros.status_ms) as
    this node receives them: ``until`` waits for the daemon to say it has seen
    something (a message counted, a tick reached) instead of sleeping for it."""

    def __init__(self, node: Any, namespace: str = "/") -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        self.node = node
        self.docs: list[dict[str, Any]] = []
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        node.create_subscription(
            String,
            namespace.rstrip("/") + "/safety_supervisor/status",
            lambda m: self.docs.append(json.loads(m.data)),
            latched,
        )

    def until(
        self, what: str, predicate: Callable[[dict[str, Any]], Any], timeout: float = 15
    ) -> dict[str, Any]:
        """The first document (from now on) for which ``predicate`` holds."""
        start = len(self.docs)

        def seen() -> dict[str, Any] | None:
            return next((d for d in self.docs[start:] if predicate(d)), None)

        return spin_until(self.node, what, seen, timeout)


def messages(doc: dict[str, Any], name: str) -> int:
    """How many messages of input ``name`` the status document counts."""
    return next(int(i["messages"]) for i in doc["inputs"] if i["name"] == name)


TOPICS: list[tuple[str, str, type]] = [  # trigger (turnoffUVC) last, as the controller does
    ("classifier", "/sRobotClassifier", Int64),
    ("distance_to_target", "/scan", Int64),
    ("OpState", "/sRobotState", Int64),
    ("alert", "/sRobotAlert", Bool),
    ("slowdown", "/sRobotSlowdown", Bool),
    ("halt", "/sRobotHalt", Bool),
    ("turnoffUVC", "/sRobotTurnoffUVC", Bool),
]
# Consistent states of the thesis's controller (Tables 7, 8): none violates anything.
S0 = dict(classifier=0, distance_to_target=50, OpState=0, alert=False, slowdown=False, halt=False, turnoffUVC=False)  # fmt: skip
# variant() edit: nobody within 3 m while the UV light is on (turnoffUVC false), predicted
UV_DISTANCE = (
    "requirements:\n",
    "requirements:\n"
    "  - id: uv_distance\n"
    "    text: sRobot shall always satisfy classifier = 0 | turnoffUVC | distance_to_target > 3\n"
    "    on_violation: [record]\n"
    "    policy: {reset: after_mitigation}\n"
    "    predict: {horizon_ms: 1500, window_ms: 1000, actions: [slow_down]}\n",
)
# a trained worker walking towards the robot, the UV light on (S0 otherwise)
WALKING = dict(S0, classifier=1, OpState=2, alert=True, slowdown=True)
S1 = dict(classifier=1, distance_to_target=10, OpState=1, alert=True, slowdown=False, halt=False, turnoffUVC=False)  # fmt: skip
S3 = dict(classifier=1, distance_to_target=2, OpState=3, alert=False, slowdown=False, halt=True, turnoffUVC=True)  # fmt: skip
S2 = dict(classifier=2, distance_to_target=10, OpState=2, alert=True, slowdown=True, halt=False, turnoffUVC=False)  # fmt: skip
# A trained worker in the red zone while the controller is in state 2.
VIOLATING = dict(S2, classifier=1, distance_to_target=2)


def variant(tmp: Path, *edits: tuple[str, str], record_only: bool = True) -> Path:
    """config/srobot.yaml edited; ``record_only``: every mitigation just logs,
    so the supervisor's own halts do not change the inputs it watches."""
    text = SROBOT.read_text()
    if record_only:
        text = re.sub(r"on_violation: \[[^\]]*\]", "on_violation: [record]", text)
        text = text.replace("on_stale: [stop_robot]", "on_stale: [record]")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp / "srobot.yaml"
    path.write_text(text)
    return path


class Robot:
    """The 7 srobot topics, published from this process."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.pubs = {name: node.create_publisher(t, topic, 10) for name, topic, t in TOPICS}
        self.types = {name: t for name, _, t in TOPICS}

    def matched(self) -> None:
        wait_matched(list(self.pubs.values()))

    def publish(self, state: dict[str, Any], gap_before_trigger: float = 0.0) -> None:
        for name, pub in self.pubs.items():
            if name == "turnoffUVC" and gap_before_trigger:
                time.sleep(gap_before_trigger)  # the controller's outputs, then its trigger
            pub.publish(self.types[name](data=state[name]))

    def until(
        self,
        state: dict[str, Any],
        daemon: Daemon,
        predicate: Callable[[dict[str, Any]], bool],
        what: str,
        timeout: float = 15,
    ) -> dict[str, Any]:
        """Publish ``state`` at the robot's rate (20 Hz) until a log record
        matches: DDS does not order messages across topics, so one burst may
        reach the supervisor with its trigger before the other values."""
        deadline = time.monotonic() + timeout
        while True:
            self.publish(state, gap_before_trigger=0.005)
            found = next((r for r in daemon.records() if predicate(r)), None)
            if found is not None:
                return found
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"timed out after {timeout} s waiting for {what}\n{daemon.explain()}"
                )
            time.sleep(0.05)  # the robot's publishing period

    def warm_up(self, daemon: Daemon, state: dict[str, Any], timeout: float = 15) -> None:
        """Publish ``state`` at 10 Hz until the daemon's STATUS= says every input
        has a value: the first sample on a freshly matched topic can arrive a
        repair period late, which would shift a synchronized monitor by one."""
        deadline = time.monotonic() + timeout
        while True:
            self.publish(state)
            note = daemon.recv(0.1)
            if note and "STATUS=" in note and "waiting_for=" not in note and "ticks=" in note:
                # one more round after the status, then let the stream settle
                self.publish(state)
                daemon.collect(0.3)
                return
            if time.monotonic() > deadline:
                raise AssertionError(f"inputs never all received\n{daemon.explain()}")

    def violate(
        self, daemon: Daemon, predicate: Callable[[dict[str, Any]], bool], what: str
    ) -> dict[str, Any]:
        """From the nominal state S0, hold VIOLATING (a trained worker in the red
        zone, controller in state 2) until a log record matches."""
        self.matched()
        self.publish(S0)
        return self.until(VIOLATING, daemon, predicate, what)
