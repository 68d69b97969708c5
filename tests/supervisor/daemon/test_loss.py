"""Loss counting and the supervisor's own messages: the sequence-number logic
tick by tick, then the daemon over real DDS under a burst (watchdog pings and
the loss it reports against what was published) and an idle robot whose halt
topic is both an input and a mitigation's output."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from supervisor.config import load_config
from supervisor.daemon.loss import OwnWrites, RecordingPublisher, SequenceStreams

# ------------------------------------------------------------------ sequence streams


def test_one_publisher_gaps_are_counted() -> None:
    s = SequenceStreams()
    # The first message heard is not preceded by loss: earlier ones were sent
    # before the subscription matched.
    assert s.on_sequence(40) == 0
    assert [s.on_sequence(n) for n in (41, 42, 45, 46, 50)] == [0, 0, 2, 0, 3]
    assert s.lost == 5
    assert s.by_publisher() == [{"first": 40, "last": 50, "received": 6, "lost": 5}]


def test_interleaved_publishers_are_told_apart_by_continuity() -> None:
    s = SequenceStreams()
    received = 0
    lost = 0
    # Publisher A far ahead of B; both lose some messages.
    a = [*range(1000, 1010), *range(1015, 1020)]
    b = [*range(1, 5), *range(8, 12)]
    for i in range(max(len(a), len(b))):
        for seq in a[i : i + 1] + b[i : i + 1]:
            lost += s.on_sequence(seq)
            received += 1
    assert lost == 5 + 3
    by = sorted(s.by_publisher(), key=lambda p: p["received"])
    assert by == [
        {"first": 1, "last": 11, "received": 8, "lost": 3},
        {"first": 1000, "last": 1019, "received": 15, "lost": 5},
    ]


def test_equal_rate_publishers_keep_the_total_right() -> None:
    """Two publishers started together have close numbers: the split between
    them may be guessed wrong, the total lost is not."""
    s = SequenceStreams()
    sent = 0
    for n in range(1, 200):
        for _pub in range(2):
            sent += 1
            if n % 10 != 3:  # every tenth message of each is lost
                s.on_sequence(n)
    assert s.lost == 2 * len([n for n in range(1, 200) if n % 10 == 3])


def test_restarted_publisher_starts_a_new_stream() -> None:
    s = SequenceStreams()
    for n in range(1, 101):
        s.on_sequence(n)
    for n in range(1, 11):  # the robot's driver restarted: numbers begin again
        assert s.on_sequence(n) == 0
    assert s.lost == 0 and len(s.by_publisher()) == 2


# ------------------------------------------------------------------ own writes


class _Sink:
    topic_name = "/halt"

    def __init__(self) -> None:
        self.stamps: list[int] = []

    def publish(self, _msg: Any) -> None:
        self.stamps.append(time.time_ns())  # where the middleware stamps the sample


def test_own_writes_are_recognised_by_number_and_time() -> None:
    own = OwnWrites()
    inner = _Sink()
    pub = RecordingPublisher(inner, "/halt", own)
    pub.publish(object())
    pub.publish(object())
    assert own.is_own("/halt", 1, inner.stamps[0])
    assert own.is_own("/halt", 2, inner.stamps[1])
    # The robot's message: the same number but another time, or another topic.
    assert not own.is_own("/halt", 1, inner.stamps[1] + 10_000_000)
    assert not own.is_own("/halt", 3, inner.stamps[1])
    assert not own.is_own("/other", 1, inner.stamps[0])
    assert not own.is_own("/halt", 1, None)
    assert pub.topic_name == "/halt"  # the rest of the publisher is the real one


def test_default_depth_holds_bursts(tmp_path: Path) -> None:
    config = tmp_path / "c.yaml"
    config.write_text(
        "component: R\n"
        "step: {policy: on_message}\n"
        "variables:\n"
        "  a: {type: int64, topic: /a, msg: std_msgs/msg/Int64}\n"
        "  b: {type: int64, topic: /b, msg: std_msgs/msg/Int64, depth: 7}\n"
        "requirements:\n"
        "  - {id: r, text: R shall always satisfy a + b < 10, on_violation: [record]}\n"
        "mitigations:\n"
        "  record: {log: {message: violated}}\n"
    )
    cfg = load_config(config)
    depth = {v.name: v.depth for v in cfg.inputs}
    assert depth == {"a": 1000, "b": 7}


# ------------------------------------------------------------------ over real DDS

BURST_CONFIG = """\
component: R
step: {policy: on_message}
variables:
  a: {type: int64, topic: /burst_a, msg: std_msgs/msg/Int64, qos: reliable, depth: 10}
  b: {type: int64, topic: /burst_b, msg: std_msgs/msg/Int64, qos: reliable}
requirements:
  - {id: r, text: R shall always satisfy a + b >= 0, on_violation: [record]}
mitigations:
  record: {log: {message: violated}}
"""


class _Pings:
    """The daemon's notify datagrams, read on a thread while the test publishes."""

    def __init__(self, daemon: Any) -> None:
        self.daemon = daemon
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            self.daemon.recv(0.05)

    def close(self) -> list[float]:
        self.stop.set()
        self.thread.join()
        return [t for t, n in self.daemon.notifications if "WATCHDOG=1" in n.splitlines()]


def _stop_record(d: Any) -> dict[str, Any]:
    return [r for r in d.records() if r.get("what") == "stop"][-1]


@pytest.mark.ros
def test_burst_never_starves_the_watchdog_and_loss_is_counted(
    tmp_path: Path, robot_node: Any
) -> None:
    """20,000 messages as fast as one publisher process can send them, with
    WATCHDOG_USEC=1 s: the pings keep coming, and per input the daemon's
    received + lost equals what was published (a depth of 10 loses some)."""
    pytest.importorskip("rclpy")
    from rosutil import Daemon, wait_matched, wait_until
    from std_msgs.msg import Int64

    config = tmp_path / "burst.yaml"
    config.write_text(BURST_CONFIG)
    d = Daemon(tmp_path, config, env={"WATCHDOG_USEC": "1000000"})
    try:
        d.wait_notify("READY=1", timeout=30)
        pings = _Pings(d)  # from here on, every datagram is read (and timed) there
        try:
            pa = robot_node.create_publisher(Int64, "/burst_a", 1000)
            pb = robot_node.create_publisher(Int64, "/burst_b", 1000)
            wait_matched([pa, pb])
            one = Int64(data=1)
            # One message each first: what a publisher sent before the first
            # message the daemon heard from it is not loss (it may predate the match).
            pa.publish(one)
            pb.publish(one)
            wait_until("the first messages", lambda: _accounted(d) == 2, 15, d.explain)
            t0 = time.monotonic()
            n = 10_000
            for _ in range(n):
                pa.publish(one)
                pb.publish(one)
            t1 = time.monotonic()
            wait_until(
                "every message received or counted lost",
                lambda: _accounted(d) == 2 * (n + 1),
                60,
                d.explain,
            )
        finally:
            times = pings.close()
        d.terminate()
        stop = _stop_record(d)
    finally:
        d.close()
    during = [t for t in times if t0 - 1.0 <= t <= t1 + 1.0]
    gaps = [b - a for a, b in zip(during, during[1:], strict=False)]
    assert len(during) >= 2 and max(gaps) < 1.0, (gaps, t1 - t0)
    for name in ("a", "b"):
        st = stop["inputs"][name]
        assert st["messages"] + st["lost"] == n + 1, (name, st)
        # The stream's ends: the bench compares them with what it sent.
        (pub,) = st["by_publisher"]
        assert (pub["first"], pub["last"], pub["received"]) == (1, n + 1, st["messages"]), st
    assert stop["inputs"]["a"]["lost"] > 0, stop  # depth 10 cannot hold the burst
    lost_records = [r for r in d.records() if r.get("what") == "input_lost"]
    assert sum(r["lost"] for r in lost_records if r["input"] == "a") == stop["inputs"]["a"]["lost"]
    assert all(r["total"] >= r["lost"] > 0 for r in lost_records)


def _accounted(d: Any) -> int | None:
    """received + lost over both inputs, from the latest STATUS line."""
    status = [x for _, x in list(d.notifications) if "STATUS=ticks=" in x]
    if not status:
        return None
    fields = dict(part.split("=", 1) for part in status[-1].split("STATUS=", 1)[1].split())
    lost = sum(int(x.split(":")[1]) for x in fields["lost"].split(",") if ":" in x)
    return int(fields["received"]) + lost


@pytest.mark.ros
def test_idle_robot_does_not_feed_on_its_own_halt(tmp_path: Path, robot_node: Any) -> None:
    """sRobot's halt topic is an input and stop_robot's output. The robot
    publishes once and falls silent: each input goes stale once and on_stale
    halts; the daemon's own halts come back on the halt input and must not
    make it look alive (which made it go stale again, and halt again, twice
    a second for as long as the robot was idle)."""
    pytest.importorskip("rclpy")
    from rosutil import S0, Daemon, Robot, variant, wait_until

    config = variant(tmp_path, ("on_stale: [record]", "on_stale: [stop_robot]"))
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        robot = Robot(robot_node)
        robot.matched()
        robot.publish(S0)

        def halts() -> list[dict[str, Any]]:
            return [
                r
                for r in d.records()
                if r["event"] == "mitigation" and r.get("action") == "stop_robot"
            ]

        def stale() -> list[str]:
            return [r["input"] for r in d.records() if r.get("what") == "input_stale"]

        wait_until("every input stale", lambda: len(stale()) >= len(S0), 10, d.explain)
        wait_until("the halts", lambda: halts(), 5, d.explain)
        # Four stale periods (500 ms each) more: a loop would halt again in each.
        end = time.monotonic() + 2.0
        wait_until("the end of the observation", lambda: time.monotonic() > end, 3)
        assert len(halts()) <= len(S0), halts()  # one per input that fell silent
        assert sorted(stale()) == sorted(S0), stale()  # the halt input did not recover
        assert not [r for r in d.records() if r.get("what") == "input_recovered"]
        d.terminate()
        stop = _stop_record(d)
    finally:
        d.close()
    assert stop["inputs"]["halt"]["own"] >= 1, stop  # they came back, and were known
    assert stop["inputs"]["halt"]["messages"] == 1  # only the robot's one message
