"""The new input kinds end to end: the daemon as a subprocess over real DDS,
fed by publishers, a service server and an action server in this process
(supervisor/inputs/: element paths and paths across arrays, stamps' age,
receive rates, service introspection events, action goal states)."""

from __future__ import annotations

import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import Daemon, wait_matched, wait_until  # noqa: E402

PERIOD_MS = 20


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def start(tmp_path: Path, text: str) -> Daemon:
    d = Daemon(tmp_path, write(tmp_path, text))
    try:
        d.wait_notify("READY=1", timeout=30)
    except BaseException:
        d.close()
        raise
    return d


def violations(d: Daemon, requirement: str | None = None) -> list[dict[str, Any]]:
    return [
        r
        for r in d.records()
        if r["event"] == "violation" and (requirement is None or r["requirement"] == requirement)
    ]


def supervisor_records(d: Daemon, what: str) -> list[dict[str, Any]]:
    return [r for r in d.records() if r["event"] == "supervisor" and r.get("what") == what]


def status(d: Daemon) -> dict[str, str] | None:
    """The fields of the daemon's latest ``STATUS=`` line (ticks=, received=, ...)."""
    for _, datagram in reversed(d.notifications):
        for line in datagram.splitlines():
            if line.startswith("STATUS=") and "ticks=" in line:
                return dict(
                    part.split("=", 1) for part in line[len("STATUS=") :].split() if "=" in part
                )
    return None


def wait_status(
    d: Daemon, predicate: Callable[[dict[str, str]], bool], what: str, timeout: float = 10
) -> dict[str, str]:
    """Until a new ``STATUS=`` line (sent once a second) satisfies ``predicate``."""
    deadline = time.monotonic() + timeout
    while True:
        seen = len(d.notifications)
        d.recv(0.2)
        if len(d.notifications) > seen:
            st = status(d)
            if st is not None and predicate(st):
                return st
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}\n{d.explain()}")


def stepping(st: dict[str, str]) -> bool:
    """Every input has a value and the monitor has stepped."""
    return "waiting_for" not in st and int(st.get("ticks", "0")) > 0


def received(d: Daemon) -> int:
    st = status(d)
    return int(st["received"]) if st is not None else 0


class Streamer:
    """Publishes ``make()`` on ``pub`` at ``hz`` from a thread until stopped;
    ``make`` and ``hz`` may be changed while it runs (0 Hz: silent)."""

    def __init__(self, pub: Any, make: Callable[[], Any], hz: float) -> None:
        self.pub, self.make, self.hz = pub, make, hz
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            hz = self.hz
            if hz <= 0:
                self._stop.wait(0.01)
                next_t = time.monotonic()
                continue
            self.pub.publish(self.make())
            self.sent += 1
            next_t += 1.0 / hz
            self._stop.wait(max(0.0, next_t - time.monotonic()))  # the sensor's period

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@contextmanager
def spinning(node: Any) -> Iterator[Any]:
    """``node``'s callbacks (service and action servers, clients' futures) run
    by a multi-threaded executor in a thread, for the length of the block."""
    from rclpy.executors import MultiThreadedExecutor

    ex = MultiThreadedExecutor(num_threads=4, context=node.context)
    ex.add_node(node)
    thread = threading.Thread(target=ex.spin, daemon=True)
    thread.start()
    try:
        yield ex
    finally:
        ex.shutdown(timeout_sec=5)
        thread.join(timeout=5)


def wait_subscribed(node: Any, topic: str, timeout: float = 15) -> None:
    """Until the daemon's subscription to ``topic`` is in the graph (for
    publishers this process has no handle of: introspection, action status)."""
    wait_until(f"a subscription to {topic}", lambda: node.count_subscribers(topic) > 0, timeout)


def wait_future(future: Any, what: str, timeout: float = 10) -> Any:
    wait_until(what, future.done, timeout)
    return future.result()


def scan(ranges: list[float], stamp: Any = None) -> Any:
    from sensor_msgs.msg import LaserScan

    msg = LaserScan()
    msg.range_min, msg.range_max = 0.1, 30.0
    msg.ranges = ranges
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


# ------------------------------------------------------------------ ages

AGE = f"""\
component: base
step: {{policy: periodic, period_ms: {PERIOD_MS}}}
variables:
  front:       {{type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}}
  scan_age_ms: {{type: double, age_of: front}}
requirements:
  - id: fresh_scan
    text: base shall always satisfy scan_age_ms < 300
  - id: front_clear
    text: base shall always satisfy front > 0.2
"""


def test_a_frozen_stamp_is_caught_by_its_age(tmp_path: Path, robot_node: Any) -> None:
    """Scans stamped now are fresh; the same stream with its stamp frozen ages
    until fresh_scan is violated once (reset: never), its record showing the age;
    a stamp 5 s ahead of the receipt is said as input_future_stamp."""
    from rclpy.duration import Duration
    from sensor_msgs.msg import LaserScan

    d = start(tmp_path, AGE)
    streamer = None
    try:
        pub = robot_node.create_publisher(LaserScan, "/scan", 10)
        wait_matched([pub])
        clock = robot_node.get_clock()

        def now() -> Any:
            return clock.now().to_msg()

        streamer = Streamer(pub, lambda: scan([2.0], now()), 20)
        wait_status(d, stepping, "the monitor stepping on fresh scans")
        d.collect(1.0)  # 50 ticks of fresh scans
        assert violations(d) == [], d.explain()
        frozen = now()
        streamer.make = lambda: scan([2.0], frozen)  # alive, but its data no longer new
        t_frozen = time.monotonic()
        v = d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "fresh_scan",
            "the fresh_scan violation",
            timeout=5,
        )
        # the first tick at which the frozen stamp is 300 ms old (a tick is 20 ms)
        assert 300 <= v["inputs"]["scan_age_ms"] < 300 + 3 * PERIOD_MS, v
        assert time.monotonic() - t_frozen >= 0.3 - PERIOD_MS / 1000  # not before its age
        d.collect(0.5)
        assert [r["requirement"] for r in violations(d)] == ["fresh_scan"], d.explain()
        assert supervisor_records(d, "input_future_stamp") == []
        # a sender whose clock is 5 s ahead of this machine's
        streamer.make = lambda: scan([2.0], (clock.now() + Duration(seconds=5)).to_msg())
        rec = d.wait_record(
            lambda r: r["event"] == "supervisor" and r.get("what") == "input_future_stamp",
            "the input_future_stamp record",
            timeout=5,
        )
        assert rec["input"] == "scan_age_ms", rec
        ahead_ms = float(rec["detail"].split("stamp ")[1].split(" ms")[0])
        assert 4900 < ahead_ms <= 5000, rec
        assert [r["requirement"] for r in violations(d)] == ["fresh_scan"], d.explain()
        streamer.stop()
        d.terminate()
    finally:
        if streamer is not None:
            streamer.stop()
        d.close()


# ------------------------------------------------------------------ rates

RATE = f"""\
component: base
step: {{policy: periodic, period_ms: {PERIOD_MS}}}
variables:
  front:   {{type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}}
  scan_hz: {{type: double, rate_of: front, window_ms: 500}}
requirements:
  - id: scan_rate
    text: base shall always satisfy scan_hz >= 10
  - id: front_clear
    text: base shall always satisfy front > 0.2
"""


@pytest.mark.parametrize("then_hz", [0, 2])
def test_a_scan_rate_dropping_is_caught(tmp_path: Path, robot_node: Any, then_hz: float) -> None:
    """20 Hz scans hold scan_hz >= 10 over a 500 ms window; stopped (or slowed
    to 2 Hz) the rate falls under 10 within a window: one violation.  The rate
    is known a whole window after the first scan, so a stream that starts after
    the daemon is not judged on a half-filled window."""
    from sensor_msgs.msg import LaserScan

    d = start(tmp_path, RATE)
    streamer = None
    try:
        pub = robot_node.create_publisher(LaserScan, "/scan", 10)
        wait_matched([pub])
        streamer = Streamer(pub, lambda: scan([2.0]), 20)
        wait_status(d, stepping, "the monitor stepping on 20 Hz scans")
        d.collect(1.0)  # two windows at 20 Hz, 50 ticks
        assert violations(d) == [], d.explain()
        streamer.hz = then_hz
        t_drop = time.monotonic()
        v = d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "scan_rate",
            "the scan_rate violation",
            timeout=5,
        )
        # 20 Hz is 10 messages in the window: under 10 Hz a window after the drop
        assert v["inputs"]["scan_hz"] < 10, v
        assert time.monotonic() - t_drop < 1.5
        d.collect(0.5)
        assert [r["requirement"] for r in violations(d)] == ["scan_rate"], d.explain()
        streamer.stop()
        d.terminate()
    finally:
        if streamer is not None:
            streamer.stop()
        d.close()


# ------------------------------------------------------------------ elements and paths

ELEMENTS = f"""\
component: base
step: {{policy: periodic, period_ms: {PERIOD_MS}}}
variables:
  front: {{type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}}
  worst: {{type: int64, topic: DIAG, msg: diagnostic_msgs/msg/DiagnosticArray, field: "status[].level", reduce: max}}
requirements:
  - id: no_error
    text: base shall always satisfy worst < 2
  - id: front_clear
    text: base shall always satisfy front > 0.2
"""


def diagnostics(*levels: int) -> Any:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    return DiagnosticArray(
        status=[DiagnosticStatus(level=bytes([lv]), name=f"part{i}") for i, lv in enumerate(levels)]
    )


def test_elements_and_paths_across_arrays(tmp_path: Path, robot_node: Any) -> None:
    """``ranges[0]`` and the worst level of a DiagnosticArray (``status[].level``,
    reduce: max) on a robot's own diagnostics topic: OK/WARN hold, an ERROR is one
    violation; a scan without ranges[0] is input_rejected, and the daemon goes on."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import LaserScan

    d = start(tmp_path, ELEMENTS.replace("DIAG", "/robot/diagnostics"))
    try:
        scans = robot_node.create_publisher(LaserScan, "/scan", 10)
        diag = robot_node.create_publisher(DiagnosticArray, "/robot/diagnostics", 10)
        wait_matched([scans, diag])
        scans.publish(scan([2.0, 0.05]))  # the first reading only: 0.05 m is another's
        diag.publish(diagnostics(0, 1, 0))  # OK, WARN, OK: the worst is WARN
        wait_status(d, stepping, "the monitor stepping")  # worst has its value
        d.collect(0.3)
        assert violations(d) == [], d.explain()
        # An empty scan has no ranges[0]: said, and front keeps its last value.
        scans.publish(scan([]))
        rec = d.wait_record(
            lambda r: r["event"] == "supervisor" and r.get("what") == "input_rejected",
            "the input_rejected record of front",
            timeout=5,
        )
        assert rec["input"] == "front" and "ranges[0]" in rec["detail"], rec
        assert "0 elements" in rec["detail"], rec
        d.collect(0.3)
        assert d.proc.poll() is None, d.explain()  # no crash
        assert violations(d) == [], d.explain()
        diag.publish(diagnostics(0, 2, 1))  # an ERROR among them
        v = d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "no_error",
            "the no_error violation",
            timeout=5,
        )
        assert v["inputs"]["worst"] == 2 and v["inputs"]["front"] == pytest.approx(2.0), v
        scans.publish(scan([0.1, 3.0]))  # a reading at 0.1 m in front
        v = d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "front_clear",
            "the front_clear violation",
            timeout=5,
        )
        assert v["inputs"]["front"] == pytest.approx(0.1), v
        d.collect(1.5)
        assert [r["requirement"] for r in violations(d)] == ["no_error", "front_clear"]
        assert len(supervisor_records(d, "input_rejected")) == 1, d.explain()
        d.terminate()
    finally:
        d.close()


def test_the_worst_level_on_slash_diagnostics(tmp_path: Path, robot_node: Any) -> None:
    """On /diagnostics, where a robot's DiagnosticArrays go (REP 107): the robot
    reports only OK and WARN, so worst < 2 holds, also after front_clear is
    violated (which the supervisor reports as ERROR on /diagnostics itself)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import LaserScan

    d = start(tmp_path, ELEMENTS.replace("DIAG", "/diagnostics"))
    streamer = None
    try:
        scans = robot_node.create_publisher(LaserScan, "/scan", 10)
        diag = robot_node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        wait_matched([scans, diag])
        streamer = Streamer(diag, lambda: diagnostics(0, 1), 5)  # only OK and WARN
        scans.publish(scan([2.0]))
        wait_status(d, stepping, "the monitor stepping")
        scans.publish(scan([0.1]))
        d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "front_clear",
            "the front_clear violation",
            timeout=5,
        )
        d.collect(2.5)  # more than two of the supervisor's diagnostics periods
        streamer.stop()
        assert [(r["requirement"], r["inputs"]) for r in violations(d)] == [
            ("front_clear", {"front": pytest.approx(0.1), "worst": 1})
        ]
        d.terminate()
    finally:
        if streamer is not None:
            streamer.stop()
        d.close()


# ------------------------------------------------------------------ services

SERVICE = f"""\
component: base
step: {{policy: periodic, period_ms: {PERIOD_MS}}}
variables:
  dock_called: {{type: bool, service: /dock, srv: std_srvs/srv/Trigger, call: request, event: true}}
  docked:      {{type: bool, service: /dock, srv: std_srvs/srv/Trigger, call: response, field: success, initial: false}}
requirements:
  - id: dock_succeeds
    text: upon dock_called base shall within 20 ticks satisfy docked
    policy: {{reset: after_mitigation}}
"""


def test_a_failed_service_call_is_caught(tmp_path: Path, robot_node: Any) -> None:
    """A real Trigger server with introspection (CONTENTS) and a real client: the
    call answered success=false is one violation 20 ticks later, the call
    answered success=true none."""
    from rclpy.qos import QoSProfile
    from rclpy.service_introspection import ServiceIntrospectionState
    from std_srvs.srv import Trigger

    answer = {"success": False}
    calls: list[bool] = []

    def serve(request: Any, response: Any) -> Any:
        response.success = answer["success"]
        response.message = "docked" if response.success else "no dock in sight"
        calls.append(response.success)
        return response

    node = robot_node
    srv = node.create_service(Trigger, "/dock", serve)
    srv.configure_introspection(
        node.get_clock(), QoSProfile(depth=10), ServiceIntrospectionState.CONTENTS
    )
    client = node.create_client(Trigger, "/dock")
    d = start(tmp_path, SERVICE)
    try:
        with spinning(node):
            wait_subscribed(node, "/dock/_service_event")
            assert client.wait_for_service(timeout_sec=10)
            wait_status(d, stepping, "the monitor stepping")
            response = wait_future(client.call_async(Trigger.Request()), "the failed call")
            assert response.success is False
            v = d.wait_record(
                lambda r: r["event"] == "violation" and r["requirement"] == "dock_succeeds",
                "the dock_succeeds violation",
                timeout=5,
            )
            assert v["inputs"]["docked"] is False, v
            d.collect(1.0)  # 50 ticks: the call is one violation
            assert len(violations(d)) == 1, d.explain()
            before = wait_status(d, lambda st: True, "a status line")
            answer["success"] = True
            response = wait_future(client.call_async(Trigger.Request()), "the successful call")
            assert response.success is True
            # its request and response events received, then 30 ticks
            wait_status(
                d,
                lambda st: int(st["received"]) >= int(before["received"]) + 2,
                "the successful call's events",
            )
            d.collect(0.6)
            assert len(violations(d)) == 1, d.explain()
            assert calls == [False, True]
        d.terminate()
    finally:
        d.close()


# ------------------------------------------------------------------ actions

ACTION = f"""\
component: base
step: {{policy: periodic, period_ms: {PERIOD_MS}}}
variables:
  nav_active:  {{type: bool, action: /navigate, status: [accepted, executing]}}
  nav_aborted: {{type: bool, action: /navigate, status: aborted, event: true}}
  goals:       {{type: int64, action: /navigate, status: executing}}
  halt:        {{type: bool, topic: /halt, msg: std_msgs/msg/Bool}}
requirements:
  - id: no_abort
    text: base shall always satisfy !nav_aborted
  - id: halt_stops_nav
    text: base shall always satisfy !(nav_active & halt)
  - id: halt_stops_execution
    text: base shall always satisfy !(goals >= 1 & halt)
"""


def test_goal_states_of_a_real_action(tmp_path: Path, robot_node: Any) -> None:
    """A real ActionServer and ActionClient (test_msgs Fibonacci): a goal that
    succeeds violates nothing; one the server aborts violates no_abort once;
    one executing while halt is true violates halt_stops_nav."""
    from rclpy.action import ActionClient, ActionServer
    from std_msgs.msg import Bool
    from test_msgs.action import Fibonacci

    release = threading.Event()

    def execute(goal_handle: Any) -> Any:
        order = goal_handle.request.order
        if order == 0:  # held executing until the test releases it
            release.wait(timeout=20)
        result = Fibonacci.Result(sequence=[0, 1][: max(order, 0)])
        if order == 1:
            goal_handle.abort()
        else:
            goal_handle.succeed()
        return result

    node = robot_node
    ActionServer(node, Fibonacci, "/navigate", execute)
    client = ActionClient(node, Fibonacci, "/navigate")
    halt = node.create_publisher(Bool, "/halt", 10)
    d = start(tmp_path, ACTION)
    try:
        with spinning(node):
            wait_matched([halt])
            wait_subscribed(node, "/navigate/_action/status")
            assert client.wait_for_server(timeout_sec=10)
            halt.publish(Bool(data=False))
            wait_status(d, stepping, "the monitor stepping")

            def run(order: int) -> Any:
                goal = wait_future(client.send_goal_async(Fibonacci.Goal(order=order)), "a goal")
                assert goal.accepted
                return goal

            before = received(d)
            goal = run(2)
            assert wait_future(goal.get_result_async(), "the result").status == 4  # succeeded
            wait_status(d, lambda st: int(st["received"]) > before, "the goal's states")
            d.collect(0.3)
            assert violations(d) == [], d.explain()

            goal = run(1)
            assert wait_future(goal.get_result_async(), "the result").status == 6  # aborted
            v = d.wait_record(
                lambda r: r["event"] == "violation" and r["requirement"] == "no_abort",
                "the no_abort violation",
                timeout=5,
            )
            assert v["inputs"]["nav_aborted"] is True, v
            d.collect(0.5)
            assert [r["requirement"] for r in violations(d)] == ["no_abort"], d.explain()

            halt.publish(Bool(data=True))
            goal = run(0)
            v = d.wait_record(
                lambda r: r["event"] == "violation" and r["requirement"] == "halt_stops_nav",
                "the halt_stops_nav violation",
                timeout=5,
            )
            assert v["inputs"]["nav_active"] is True and v["inputs"]["halt"] is True, v
            v = d.wait_record(
                lambda r: r["event"] == "violation" and r["requirement"] == "halt_stops_execution",
                "the halt_stops_execution violation",
                timeout=5,
            )
            assert v["inputs"]["goals"] == 1 and v["inputs"]["nav_active"] is True, v
            release.set()
            assert wait_future(goal.get_result_async(), "the result").status == 4
            d.collect(0.5)
            assert sorted(r["requirement"] for r in violations(d)) == [
                "halt_stops_execution",
                "halt_stops_nav",
                "no_abort",
            ], d.explain()
        d.terminate()
    finally:
        release.set()
        d.close()
