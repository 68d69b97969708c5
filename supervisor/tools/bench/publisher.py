"""The throughput experiment's publisher: the offered rate spread evenly over the
spec's topics (the trigger last in each round), started by ``go`` on stdin once every
receiver matched; then it relays the daemon's per-input counts from /diagnostics.

With ``--burst N`` it sends N rounds back to back, as fast as it can, then waits
so that the average is the offered rate: the thesis's controller publishes its 7
topics as one burst per cycle (N = 1), a robot catching up sends many cycles at once.

With ``--scan JSON`` (``bench --scan``) it also publishes a LaserScan at its own rate
between those slots, header.stamp set to the wall clock at each publication, counted
in ``sent`` under the scan's variable name."""

from __future__ import annotations

import argparse
import json
import select
import sys
import time
from typing import Any

from supervisor.names import DIAGNOSTICS_TOPIC
from supervisor.tools.bench.helper import (
    Topic,
    WaitLoop,
    emit,
    never,
    reliable,
    ros_node,
    stop_requested,
)

SPIN_BELOW_NS = 20_000  # the publisher busy-waits only for the last 20 us of a slot


def _wait_matched(pubs: list[Any], n: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not stop_requested.is_set():
        if all(p.get_subscription_count() >= n for p in pubs):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)  # polling interval of the discovery check
    return False


def _read_go(timeout: float) -> bool:
    """Until the bench writes a line on stdin (it snapshots CPU times first)."""
    deadline = time.monotonic() + timeout
    while not stop_requested.is_set() and time.monotonic() < deadline:
        r, _, _ = select.select([sys.stdin], [], [], 0.1)
        if r:
            return bool(sys.stdin.readline())
    return False


def scan_message(spec: dict[str, Any]) -> Any:
    """The LaserScan of ``bench --scan`` (plan.ScanPlan.scan), built by rclpy; its
    stamp is zero (set at publication)."""
    from array import array

    from mitigations.rosmsg import message_class
    from supervisor.tools.bench.plan import scan_ranges

    msg = message_class(spec["msg"])()
    msg.header.frame_id = "laser"
    n = int(spec["readings"])
    msg.angle_min, msg.angle_max = -3.14159265, 3.14159265
    msg.angle_increment = (msg.angle_max - msg.angle_min) / n
    msg.range_min, msg.range_max = float(spec["range_min"]), float(spec["range_max"])
    msg.ranges = array("f", scan_ranges(n))
    return msg


class ScanStream:
    """The LaserScan of ``bench --scan``: one message built once, its stamp renewed
    at each publication."""

    def __init__(self, node: Any, spec: dict[str, Any]) -> None:
        self.msg = scan_message(spec)
        self.name = spec["name"]
        self.topic = spec["topic"]
        self.period_ns = 1e9 / float(spec["hz"])
        self.pub = node.create_publisher(type(self.msg), spec["topic"], reliable())
        self.sent = 0

    def publish(self) -> None:
        ns = time.time_ns()
        stamp = self.msg.header.stamp
        stamp.sec, stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        self.pub.publish(self.msg)
        self.sent += 1


def run_publisher(args: argparse.Namespace, topics: list[Topic], values: dict[str, Any]) -> None:
    with ros_node(args.node_name) as node:
        pubs = [node.create_publisher(t.klass, t.topic, reliable()) for t in topics]
        msgs = [t.message(values[t.name]) for t in topics]
        scan = ScanStream(node, json.loads(args.scan)) if args.scan else None
        diag: list[Any] = []
        if args.diagnostics:
            from diagnostic_msgs.msg import DiagnosticArray

            # depth 1: only the newest report matters
            diag_sub = node.create_subscription(
                DiagnosticArray, DIAGNOSTICS_TOPIC, never, reliable(depth=1)
            )
            diag = [(diag_sub, DiagnosticArray)]
        emit(event="started")
        every = pubs + ([scan.pub] if scan is not None else [])
        if not _wait_matched(every, args.receivers, args.match_timeout):
            counts = {
                t.topic: p.get_subscription_count() for t, p in zip(topics, pubs, strict=True)
            }
            if scan is not None:
                counts[scan.topic] = scan.pub.get_subscription_count()
            emit(event="error", error=f"receivers not discovered: subscriptions {counts}")
            return
        emit(event="matched")
        if not _read_go(args.match_timeout):
            return
        k = len(topics)
        total = max(1, round(args.rate * args.seconds / k)) * k  # whole rounds: trigger last
        period = 1e9 / args.rate
        # Slot i is due at t0 + i * period; in burst mode a whole burst shares
        # its first message's slot.
        chunk = k * args.burst if args.burst else 1
        publish = [p.publish for p in pubs]
        perf = time.perf_counter_ns
        sleep = time.sleep
        t0 = perf()
        # The scan's next slot (never without one): between the stream's slots.
        scan_due = t0 if scan is not None else float("inf")
        i = 0
        while i < total:
            now = perf()
            if now >= scan_due:
                assert scan is not None
                scan.publish()
                scan_due = t0 + int(scan.sent * scan.period_ns)
                continue
            due = t0 + int((i // chunk) * chunk * period)
            if due > now:
                left = min(due, scan_due) - now
                if left > SPIN_BELOW_NS:
                    sleep((left - SPIN_BELOW_NS) / 1e9)
                continue
            # Catch up on every slot already due (a sleep overshoots by ~60 us).
            while i < total and t0 + int((i // chunk) * chunk * period) <= now:
                publish[i % k](msgs[i % k])
                i += 1
            if stop_requested.is_set():
                break
        elapsed = (perf() - t0) / 1e9
        sent = {t.name: i // k + (1 if j < i % k else 0) for j, t in enumerate(topics)}
        if scan is not None:
            sent[scan.name] = scan.sent
        emit(event="done", sent=sent, seconds=elapsed, achieved=i / elapsed, wall=time.time())
        if diag:
            names = [t.name for t in topics] + ([scan.name] if scan is not None else [])
            _relay_diagnostics(node, diag, args.daemon_node, names)


def _relay_diagnostics(node: Any, diag: list[Any], daemon: str, inputs: list[str]) -> None:
    """Emit the daemon's per-input counts from each /diagnostics report: messages
    taken (accepted or rejected) and counted lost."""
    loop = WaitLoop(node, diag)
    names = {f"{daemon}: input {name}": name for name in inputs}
    try:
        while not stop_requested.is_set():
            if not loop.wait(100_000_000):
                continue
            while (msg := loop.take(0)) is not None:
                counts, lost = {}, {}
                for st in msg.status:
                    name = names.get(st.name)
                    if name is not None:
                        kv = {v.key: v.value for v in st.values}
                        counts[name] = int(kv.get("messages", 0)) + int(kv.get("rejected", 0))
                        lost[name] = int(kv.get("lost", 0))
                stamp = msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9
                if counts:
                    emit(event="diag", counts=counts, lost=lost, stamp=stamp)
    finally:
        loop.close()
