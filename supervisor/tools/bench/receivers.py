"""The throughput experiment's baselines: plain rclpy subscribers counting messages
per topic, ``waitset`` (the fastest: one wait set drained with ``take_message``) and
``executor`` (the naive one: rclpy's ``SingleThreadedExecutor``, a callback each)."""

from __future__ import annotations

import time
from typing import Any

from supervisor.tools.bench.helper import (
    REPORT_EVERY_NS,
    Topic,
    WaitLoop,
    emit,
    never,
    publishers_seen,
    reliable,
    ros_node,
    stop_requested,
)


def run_waitset(topics: list[Topic], publisher_node: str) -> None:
    with ros_node("bench_baseline_waitset") as node:
        subs = [(node.create_subscription(t.klass, t.topic, never, reliable()), t.klass) for t in topics]  # fmt: skip
        loop = WaitLoop(node, subs)
        counts = [0] * len(topics)
        takes = [s.handle.take_message for s, _k in subs]
        klasses = [k for _s, k in subs]
        matched = False
        next_report = 0
        try:
            while not stop_requested.is_set():
                for i in loop.wait(next_report - time.monotonic_ns()):
                    take, klass = takes[i], klasses[i]
                    n = 0
                    while take(klass, False) is not None:
                        n += 1
                    counts[i] += n
                now = time.monotonic_ns()
                if now >= next_report:
                    next_report = now + REPORT_EVERY_NS
                    if not matched and publishers_seen(node, topics, publisher_node):
                        matched = True
                        emit(event="matched")
                    emit(
                        event="counts",
                        counts={t.name: c for t, c in zip(topics, counts, strict=True)},
                    )
        finally:
            loop.close()
        emit(event="final", counts={t.name: c for t, c in zip(topics, counts, strict=True)})


def run_executor(topics: list[Topic], publisher_node: str) -> None:
    from rclpy.executors import SingleThreadedExecutor

    with ros_node("bench_baseline_executor") as node:
        counts = dict.fromkeys((t.name for t in topics), 0)

        def counter(name: str) -> Any:
            def cb(_msg: Any) -> None:
                counts[name] += 1

            return cb

        for t in topics:
            node.create_subscription(t.klass, t.topic, counter(t.name), reliable())
        ex = SingleThreadedExecutor(context=node.context)
        ex.add_node(node)
        matched = False
        next_report = 0
        try:
            while not stop_requested.is_set():
                ex.spin_once(timeout_sec=0.05)
                now = time.monotonic_ns()
                if now >= next_report:
                    next_report = now + REPORT_EVERY_NS
                    if not matched and publishers_seen(node, topics, publisher_node):
                        matched = True
                        emit(event="matched")
                    emit(event="counts", counts=dict(counts))
        finally:
            ex.shutdown()
        emit(event="final", counts=dict(counts))
