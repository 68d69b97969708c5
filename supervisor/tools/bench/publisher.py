"""The throughput experiment's publisher: the offered rate spread evenly over the
spec's topics (the trigger last in each round), started by ``go`` on stdin once every
receiver matched; then it relays the daemon's per-input counts from /diagnostics.

With ``--burst N`` it sends N rounds back to back, as fast as it can, then waits
so that the average is the offered rate: the thesis's controller publishes its 7
topics as one burst per cycle (N = 1), a robot catching up sends many cycles at once."""

from __future__ import annotations

import argparse
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


def run_publisher(args: argparse.Namespace, topics: list[Topic], values: dict[str, Any]) -> None:
    with ros_node(args.node_name) as node:
        pubs = [node.create_publisher(t.klass, t.topic, reliable()) for t in topics]
        msgs = [t.message(values[t.name]) for t in topics]
        diag: list[Any] = []
        if args.diagnostics:
            from diagnostic_msgs.msg import DiagnosticArray

            # depth 1: only the newest report matters
            diag_sub = node.create_subscription(
                DiagnosticArray, DIAGNOSTICS_TOPIC, never, reliable(depth=1)
            )
            diag = [(diag_sub, DiagnosticArray)]
        emit(event="started")
        if not _wait_matched(pubs, args.receivers, args.match_timeout):
            counts = {
                t.topic: p.get_subscription_count() for t, p in zip(topics, pubs, strict=True)
            }
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
        i = 0
        while i < total:
            now = perf()
            due = t0 + int((i // chunk) * chunk * period)
            if due > now:
                left = due - now
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
        emit(event="done", sent=sent, seconds=elapsed, achieved=i / elapsed, wall=time.time())
        if diag:
            _relay_diagnostics(node, diag, args.daemon_node, topics)


def _relay_diagnostics(node: Any, diag: list[Any], daemon: str, topics: list[Topic]) -> None:
    """Emit the daemon's per-input counts from each /diagnostics report: messages
    taken (accepted or rejected) and counted lost."""
    loop = WaitLoop(node, diag)
    names = {f"{daemon}: input {t.name}": t.name for t in topics}
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
