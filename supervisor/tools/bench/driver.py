"""The latency experiment's robot: per trial the nominal state, the violating state,
then the trigger; the time from the trigger's publication to the halt's reception."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from mitigations.violationlog.reader import records_since
from supervisor.tools.bench.helper import (
    Topic,
    WaitLoop,
    emit,
    never,
    reliable,
    ros_node,
    stop_requested,
)


def run_driver(args: argparse.Namespace, topics: list[Topic]) -> None:
    from mitigations.rosmsg import message_class

    nominal_values = json.loads(args.nominal)
    violating_values = json.loads(args.violating)
    with ros_node("bench_latency_driver") as node:
        pubs = [node.create_publisher(t.klass, t.topic, reliable()) for t in topics]
        nominal = [t.message(nominal_values[t.name]) for t in topics]
        violating = [t.message(violating_values[t.name]) for t in topics]
        trigger = [t.name for t in topics].index(args.trigger)
        order = [i for i in range(len(topics)) if i != trigger] + [trigger]
        halt_class = message_class(args.halt_msg)
        # Subscribed once, before the first trial.  Transient-local so a halt
        # published while discovery completes is not lost; a replayed (old)
        # halt can only arrive during the warm-up trials, which are not counted.
        halt_sub = node.create_subscription(
            halt_class, args.halt_topic, never, reliable("transient_local", depth=100)
        )
        from std_srvs.srv import Trigger

        client = node.create_client(Trigger, args.sync_service)
        emit(event="started")
        if not _matched(pubs, halt_sub, client, args.match_timeout):
            return
        emit(event="matched")
        loop = WaitLoop(node, [(halt_sub, halt_class)], client=client)
        log = LogCounts(Path(args.log), args.requirement) if args.log else None
        trials = _Trials(args, pubs, nominal, violating, order, loop, client, log)
        try:
            if not trials.run(args.warmup, args.trials):
                return
        finally:
            loop.close()
        emit(
            event="result",
            latencies_ns=trials.latencies,
            published_wall_ns=trials.walls,
            missed=trials.missed,
            strays=trials.strays,
            sync_timeouts=trials.sync_timeouts,
        )


def _matched(pubs: list[Any], halt_sub: Any, client: Any, match_timeout: float) -> bool:
    """Waits until the responder subscribes to every topic, publishes the halt and
    serves the reset; false (an error emitted unless asked to stop) if it does not."""
    deadline = time.monotonic() + match_timeout
    while not (
        all(p.get_subscription_count() >= 1 for p in pubs)
        and halt_sub.get_publisher_count() >= 1
        and client.service_is_ready()
    ):
        if stop_requested.is_set():
            return False
        if time.monotonic() > deadline:
            emit(event="error", error="the responder was not discovered")
            return False
        time.sleep(0.01)  # polling interval of the discovery check
    return True


class _Trials:
    """The trials against a matched responder, and what they measured."""

    def __init__(
        self,
        args: argparse.Namespace,
        pubs: list[Any],
        nominal: list[Any],
        violating: list[Any],
        order: list[int],
        loop: WaitLoop,
        client: Any,
        log: LogCounts | None,
    ) -> None:
        self.args = args
        self.pubs = pubs
        self.nominal = nominal
        self.violating = violating
        self.order = order  # the trigger last
        self.loop = loop
        self.client = client
        self.log = log
        from std_srvs.srv import Trigger

        self.trigger = Trigger  # the reset service's type, for the handshake
        self.timeout_ns = int(args.timeout * 1e9)
        self.total_halts = 0
        self.sync_timeouts = 0
        self.latencies: list[int] = []
        self.walls: list[int] = []
        self.missed = 0
        self.strays = 0

    def run(self, warmup: int, trials: int) -> bool:
        """Every trial, the warm-up ones not counted; false when stopped or when no
        halt came in 10 trials in a row (an error emitted)."""
        trigger = self.order[-1]
        in_a_row = 0
        for trial in range(warmup + trials):
            s = self.prepare()
            if stop_requested.is_set():
                return False
            wall = time.time_ns()  # to line up with the daemon's record timestamps
            t0 = time.monotonic_ns()
            self.pubs[trigger].publish(self.violating[trigger])
            got, _ = self.pump(self.timeout_ns)
            t1 = time.monotonic_ns()
            in_a_row = 0 if got else in_a_row + 1
            if in_a_row >= 10:
                emit(event="error", error=f"no halt in {in_a_row} trials in a row")
                return False
            if trial >= warmup:
                self.strays += s
                if got:
                    self.latencies.append(t1 - t0)
                    self.walls.append(wall)
                else:
                    self.missed += 1
        self.settle_log()
        return True

    def publish(self, state: list[Any], which: list[int]) -> None:
        for i in which:
            self.pubs[i].publish(state[i])

    def pump(self, timeout: int, *, seq: int | None = None) -> tuple[int, bool]:
        """Receive for at most ``timeout`` ns, until the first halt (data true)
        or, with ``seq``, until the response to that request; (halts, answered)."""
        loop = self.loop
        end = time.monotonic_ns() + timeout
        n = 0
        answered = False
        while not stop_requested.is_set():
            if loop.wait(end - time.monotonic_ns()):
                while (m := loop.take(0)) is not None:
                    n += bool(m.data)
            if loop.client_ready:
                while True:
                    header, _response = self.client.handle.take_response(self.trigger.Response)
                    if header is None:
                        break
                    answered |= header.request_id.sequence_number == seq
            if answered or (seq is None and n) or time.monotonic_ns() >= end:
                break
        self.total_halts += n
        return n, answered

    def sync(self) -> int:
        """Handshake: a request to the responder's reset service is served by
        its loop after the messages we published before it (same process,
        delivered in order; the loop drains subscriptions before services), so
        the answer means the responder has stepped on them.  The daemon resets
        its monitors (an operator reset), which keeps each trial fresh."""
        seq = self.client.handle.send_request(self.trigger.Request())
        n, answered = self.pump(self.timeout_ns, seq=seq)
        self.sync_timeouts += not answered
        return n

    def settle_log(self) -> None:
        """The daemon acted on every halt we saw: its loop wrote the reset
        record, its worker fsynced the mitigation record.  The next trial must
        queue behind neither, and our halt=false must reach the daemon after
        its own halt (which is queued when the mitigation record is written)."""
        log = self.log
        if log is None:
            return
        end = time.monotonic() + self.args.timeout
        while time.monotonic() < end and (
            log.count("mitigation") < self.total_halts or log.count("reset") < self.total_halts
        ):
            time.sleep(0.0002)  # polling the log file, not synchronisation

    def prepare(self) -> int:
        """The nominal state (halt false: each trial starts from a holding
        state), then the violating values except the trigger.  Each part is
        followed by the handshake: DDS does not order messages of different
        topics, and a trigger overtaking the values it completes would step
        on a half-published state.  Any halt meanwhile is a stray: again."""
        order = self.order
        strays = 0
        while not stop_requested.is_set():
            self.settle_log()
            self.publish(self.nominal, order[:-1])
            extra = self.sync()
            self.publish(self.nominal, order[-1:])
            extra += self.sync()
            self.publish(self.violating, order[:-1])
            extra += self.sync()
            if not extra:
                return strays
            strays += extra
        return strays


class LogCounts:
    """The daemon's records of one requirement, counted by event as the log grows."""

    def __init__(self, path: Path, requirement: str) -> None:
        self.path = path
        self.requirement = requirement
        self.offset = 0
        self.counts: dict[str, int] = {}

    def count(self, event: str) -> int:
        records, self.offset = records_since(self.path, self.offset)
        for r in records:
            if r.get("requirement") == self.requirement:
                kind = str(r["event"])
                self.counts[kind] = self.counts.get(kind, 0) + 1
        return self.counts.get(event, 0)
