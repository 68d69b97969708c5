"""The throughput experiment's baselines: plain rclpy subscribers counting messages
per topic, ``waitset`` (the fastest: one wait set drained with ``take_message``) and
``executor`` (the naive one: rclpy's ``SingleThreadedExecutor``, a callback each)."""

from __future__ import annotations

import time
from collections.abc import Callable
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


class _Progress:
    """Once per REPORT_EVERY_NS: a ``matched`` event the first time the publisher is
    seen, then the counts so far (the bench reads both from stdout)."""

    def __init__(self, node: Any, topics: list[Topic], publisher_node: str) -> None:
        self.node, self.topics, self.publisher_node = node, topics, publisher_node
        self.matched = False
        self.next_report = 0

    def tick(self, counts: Callable[[], dict[str, int]]) -> None:
        # counts is called only when reporting: the baselines' loops stay as lean as before
        now = time.monotonic_ns()
        if now < self.next_report:
            return
        self.next_report = now + REPORT_EVERY_NS
        if not self.matched and publishers_seen(self.node, self.topics, self.publisher_node):
            self.matched = True
            emit(event="matched")
        emit(event="counts", counts=counts())


def run_waitset(topics: list[Topic], publisher_node: str) -> None:
    with ros_node("bench_baseline_waitset") as node:
        subs = [(node.create_subscription(t.klass, t.topic, never, reliable()), t.klass) for t in topics]  # fmt: skip
        loop = WaitLoop(node, subs)
        counts = [0] * len(topics)
        takes = [s.handle.take_message for s, _k in subs]
        klasses = [k for _s, k in subs]
        progress = _Progress(node, topics, publisher_node)
        try:
            while not stop_requested.is_set():
                for i in loop.wait(progress.next_report - time.monotonic_ns()):
                    take, klass = takes[i], klasses[i]
                    n = 0
                    while take(klass, False) is not None:
                        n += 1
                    counts[i] += n
                progress.tick(lambda: {t.name: c for t, c in zip(topics, counts, strict=True)})
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
        progress = _Progress(node, topics, publisher_node)
        try:
            while not stop_requested.is_set():
                ex.spin_once(timeout_sec=0.05)
                progress.tick(lambda: dict(counts))
        finally:
            ex.shutdown()
        emit(event="final", counts=dict(counts))
