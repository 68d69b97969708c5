"""The processes ``safety-supervisor bench`` runs besides the daemon.

``python -m supervisor.tools.bench.procs ROLE --spec JSON ...``; every role talks to
the bench on stdout, one JSON object per line, and stops on SIGTERM:

- ``publisher``: publishes ``--rate`` msg/s, spread evenly over the spec's
  topics (the trigger last in each round), once every publisher has
  ``--receivers`` matched subscriptions and the bench wrote ``go`` on stdin;
  then relays the daemon's per-input message counts from ``/diagnostics``.
- ``waitset``: the fastest plain rclpy subscriber (issue 3): one rclpy wait set
  over every subscription, drained with ``take_message``; counts per topic.
- ``executor``: the naive baseline, rclpy's ``SingleThreadedExecutor`` with one
  callback per subscription; counts per topic.
- ``echo``: the bare-DDS latency baseline: keeps the latest value of every
  topic (wait-set loop) and, when the trigger arrives in the violating state,
  publishes the halt the daemon would publish.
- ``driver``: the latency experiment's robot: nominal state, violating state,
  time from the trigger's publication to the halt's reception, per trial.
- ``exec -- ARGV``: dies with the bench (``PR_SET_PDEATHSIG``), then execs
  ``ARGV`` (the daemon), so the daemon keeps its pid for /proc CPU readings.

The wait-set loops use the same private rclpy API as the daemon's receive loop
(``supervisor/node.py``) but are written out here on purpose: a baseline that
imported the daemon's code would not be a baseline.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

PR_SET_PDEATHSIG = 1
REPORT_EVERY_NS = 100_000_000  # receivers print their counts this often
SPIN_BELOW_NS = 20_000  # the publisher busy-waits only for the last 20 us of a slot
DEPTH = 1000  # every bench subscription and publisher: reliable, volatile, depth 1000

_stop = threading.Event()


def die_with_parent() -> None:
    """SIGTERM when the bench process dies, even by SIGKILL: no orphans."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() == 1:  # the bench died before prctl took effect
        raise SystemExit(1)


def emit(**obj: Any) -> None:
    try:
        print(json.dumps(obj), flush=True)
    except (BrokenPipeError, ValueError):
        _stop.set()  # the bench is gone


def _on_term(_signum: int, _frame: Any) -> None:
    _stop.set()


# ------------------------------------------------------------------ topics


@dataclass
class Topic:
    name: str  # the config's variable name
    topic: str
    msg: str  # package/msg/Name
    field: str  # dotted path of the value
    klass: type
    leaf: str  # ROS type of the field

    def message(self, value: Any) -> Any:
        """A message whose ``field`` holds ``value`` (other fields default)."""
        from mitigations.rosmsg import build_message

        if self.leaf == "boolean":
            value = bool(value)
        elif "float" in self.leaf or self.leaf == "double":
            value = float(value)
        else:
            value = int(value)
        nested: Any = value
        for part in reversed(self.field.split(".")):
            nested = {part: nested}
        return build_message(self.klass, nested, f"bench value of {self.name}")


def load_topics(spec: str) -> list[Topic]:
    from mitigations.rosmsg import field_type, message_class

    out = []
    for t in json.loads(spec):
        klass = message_class(t["msg"])
        out.append(
            Topic(t["name"], t["topic"], t["msg"], t["field"], klass, field_type(klass, t["field"]))
        )
    return out


def reliable(durability: str = "volatile", depth: int = DEPTH) -> Any:
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


@contextlib.contextmanager
def ros_node(name: str) -> Iterator[Any]:
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = Node(name, context=ctx)
    try:
        yield node
    finally:
        with contextlib.suppress(Exception):
            node.destroy_node()
        with contextlib.suppress(Exception):
            rclpy.shutdown(context=ctx)


def _never(*_args: Any) -> None:
    """Callback of subscriptions served by a wait-set loop (never called)."""


class WaitLoop:
    """Subscriptions (and at most one service and one client) served by one rclpy
    wait set, as the daemon's loop does."""

    def __init__(
        self, node: Any, subs: list[tuple[Any, type]], *, service: Any = None, client: Any = None
    ) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        self.node = node
        self.subs = subs
        self.service, self.client = service, client
        self._stack = contextlib.ExitStack()
        ctx = node.context
        for sub, _klass in subs:
            self._stack.enter_context(sub.handle)
        for extra in (service, client):
            if extra is not None:
                self._stack.enter_context(extra.handle)
        self._stack.enter_context(ctx.handle)
        self.by_ptr = {sub.handle.pointer: i for i, (sub, _k) in enumerate(subs)}
        self.ws = _rclpy.WaitSet(
            len(subs), 0, 0, int(client is not None), int(service is not None), 0, ctx.handle
        )
        self.service_ready = self.client_ready = False

    def wait(self, timeout_ns: int) -> list[int]:
        """Indices of the subscriptions with messages (after at most ``timeout_ns``);
        ``service_ready`` / ``client_ready`` say whether a request / response came."""
        ws = self.ws
        ws.clear_entities()
        for sub, _klass in self.subs:
            ws.add_subscription(sub.handle)
        if self.service is not None:
            ws.add_service(self.service.handle)
        if self.client is not None:
            ws.add_client(self.client.handle)
        ws.wait(max(0, timeout_ns))
        self.service_ready = bool(self.service and ws.get_ready_entities("service"))
        self.client_ready = bool(self.client and ws.get_ready_entities("client"))
        return [self.by_ptr[p] for p in ws.get_ready_entities("subscription")]

    def take(self, i: int) -> Any:
        """The next message of subscription ``i``, or None."""
        sub, klass = self.subs[i]
        info = sub.handle.take_message(klass, False)
        return None if info is None else info[0]

    def close(self) -> None:
        self._stack.close()


def _publishers_seen(node: Any, topics: list[Topic], publisher_node: str) -> bool:
    """Every topic has a publisher of node ``publisher_node`` in this node's graph."""
    for t in topics:
        infos = node.get_publishers_info_by_topic(t.topic)
        if not any(i.node_name == publisher_node for i in infos):
            return False
    return True


# ------------------------------------------------------------------ receivers


def run_waitset(topics: list[Topic], publisher_node: str) -> None:
    with ros_node("bench_baseline_waitset") as node:
        subs = [(node.create_subscription(t.klass, t.topic, _never, reliable()), t.klass) for t in topics]  # fmt: skip
        loop = WaitLoop(node, subs)
        counts = [0] * len(topics)
        takes = [s.handle.take_message for s, _k in subs]
        klasses = [k for _s, k in subs]
        matched = False
        next_report = 0
        try:
            while not _stop.is_set():
                for i in loop.wait(next_report - time.monotonic_ns()):
                    take, klass = takes[i], klasses[i]
                    n = 0
                    while take(klass, False) is not None:
                        n += 1
                    counts[i] += n
                now = time.monotonic_ns()
                if now >= next_report:
                    next_report = now + REPORT_EVERY_NS
                    if not matched and _publishers_seen(node, topics, publisher_node):
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
            while not _stop.is_set():
                ex.spin_once(timeout_sec=0.05)
                now = time.monotonic_ns()
                if now >= next_report:
                    next_report = now + REPORT_EVERY_NS
                    if not matched and _publishers_seen(node, topics, publisher_node):
                        matched = True
                        emit(event="matched")
                    emit(event="counts", counts=dict(counts))
        finally:
            ex.shutdown()
        emit(event="final", counts=dict(counts))


# ------------------------------------------------------------------ publisher


def _wait_matched(pubs: list[Any], n: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not _stop.is_set():
        if all(p.get_subscription_count() >= n for p in pubs):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)  # polling interval of the discovery check
    return False


def _read_go(timeout: float) -> bool:
    """Until the bench writes a line on stdin (it snapshots CPU times first)."""
    deadline = time.monotonic() + timeout
    while not _stop.is_set() and time.monotonic() < deadline:
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
                DiagnosticArray, "/diagnostics", _never, reliable(depth=1)
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
        publish = [p.publish for p in pubs]
        perf = time.perf_counter_ns
        sleep = time.sleep
        t0 = perf()
        i = 0
        while i < total:
            now = perf()
            due = t0 + int(i * period)
            if due > now:
                left = due - now
                if left > SPIN_BELOW_NS:
                    sleep((left - SPIN_BELOW_NS) / 1e9)
                continue
            # Catch up on every slot already due (a sleep overshoots by ~60 us).
            while i < total and t0 + int(i * period) <= now:
                publish[i % k](msgs[i % k])
                i += 1
            if _stop.is_set():
                break
        elapsed = (perf() - t0) / 1e9
        sent = {t.name: i // k + (1 if j < i % k else 0) for j, t in enumerate(topics)}
        emit(event="done", sent=sent, seconds=elapsed, achieved=i / elapsed, wall=time.time())
        if diag:
            _relay_diagnostics(node, diag, args.daemon_node, topics)


def _relay_diagnostics(node: Any, diag: list[Any], daemon: str, topics: list[Topic]) -> None:
    """Emit the daemon's per-input message counts from each /diagnostics report."""
    loop = WaitLoop(node, diag)
    names = {f"{daemon}: input {t.name}": t.name for t in topics}
    try:
        while not _stop.is_set():
            if not loop.wait(100_000_000):
                continue
            while (msg := loop.take(0)) is not None:
                counts = {}
                for st in msg.status:
                    name = names.get(st.name)
                    if name is not None:
                        kv = {v.key: v.value for v in st.values}
                        counts[name] = int(kv.get("messages", 0))
                stamp = msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9
                if counts:
                    emit(event="diag", counts=counts, stamp=stamp)
    finally:
        loop.close()


# ------------------------------------------------------------------ latency


def run_echo(args: argparse.Namespace, topics: list[Topic]) -> None:
    from mitigations.rosmsg import get_field, message_class

    with ros_node("bench_echo") as node:
        halt_class = message_class(args.halt_msg)
        halt = node.create_publisher(
            halt_class, args.halt_topic, reliable("transient_local", depth=1)
        )
        halt_msg = halt_class(data=True)
        subs = [(node.create_subscription(t.klass, t.topic, _never, reliable()), t.klass) for t in topics]  # fmt: skip
        from std_srvs.srv import Trigger

        # The daemon's reset service, as a ping: the driver's handshake (below).
        srv = node.create_service(Trigger, args.sync_service, _never)
        loop = WaitLoop(node, subs, service=srv)
        names = [t.name for t in topics]
        fields = [t.field for t in topics]
        trigger = names.index(args.trigger)
        when_name, when_value = args.when.split("=", 1)
        when = names.index(when_name)
        latest: list[Any] = [None] * len(topics)
        want = int(when_value)
        emit(event="started")
        try:
            while not _stop.is_set():
                for i in loop.wait(100_000_000):
                    while (msg := loop.take(i)) is not None:
                        latest[i] = get_field(msg, fields[i])
                        if i == trigger and latest[when] == want:
                            halt.publish(halt_msg)
                if loop.service_ready:
                    taken = srv.handle.service_take_request(Trigger.Request)
                    if taken is not None and taken[1] is not None:
                        # take gives rmw_service_info_t; the reply wants its request id
                        request_id = getattr(taken[1], "request_id", taken[1])
                        srv.handle.service_send_response(Trigger.Response(success=True), request_id)
        finally:
            loop.close()


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
            halt_class, args.halt_topic, _never, reliable("transient_local", depth=100)
        )
        from std_srvs.srv import Trigger

        client = node.create_client(Trigger, args.sync_service)
        emit(event="started")
        deadline = time.monotonic() + args.match_timeout
        while not (
            all(p.get_subscription_count() >= 1 for p in pubs)
            and halt_sub.get_publisher_count() >= 1
            and client.service_is_ready()
        ):
            if _stop.is_set():
                return
            if time.monotonic() > deadline:
                emit(event="error", error="the responder was not discovered")
                return
            time.sleep(0.01)  # polling interval of the discovery check
        emit(event="matched")
        loop = WaitLoop(node, [(halt_sub, halt_class)], client=client)
        log = _LogTail(args.log, args.requirement) if args.log else None
        timeout_ns = int(args.timeout * 1e9)
        total_halts = sync_timeouts = 0

        def publish(state: list[Any], which: list[int]) -> None:
            for i in which:
                pubs[i].publish(state[i])

        def pump(timeout: int, *, seq: int | None = None) -> tuple[int, bool]:
            """Receive for at most ``timeout`` ns, until the first halt (data true)
            or, with ``seq``, until the response to that request; (halts, answered)."""
            nonlocal total_halts
            end = time.monotonic_ns() + timeout
            n = 0
            answered = False
            while not _stop.is_set():
                if loop.wait(end - time.monotonic_ns()):
                    while (m := loop.take(0)) is not None:
                        n += bool(m.data)
                if loop.client_ready:
                    while True:
                        header, _response = client.handle.take_response(Trigger.Response)
                        if header is None:
                            break
                        answered |= header.request_id.sequence_number == seq
                if answered or (seq is None and n) or time.monotonic_ns() >= end:
                    break
            total_halts += n
            return n, answered

        def sync() -> int:
            """Handshake: a request to the responder's reset service is served by
            its loop after the messages we published before it (same process,
            delivered in order; the loop drains subscriptions before services), so
            the answer means the responder has stepped on them.  The daemon resets
            its monitors (an operator reset), which keeps each trial fresh."""
            nonlocal sync_timeouts
            seq = client.handle.send_request(Trigger.Request())
            n, answered = pump(timeout_ns, seq=seq)
            sync_timeouts += not answered
            return n

        def settle_log() -> None:
            """The daemon acted on every halt we saw: its loop wrote the reset
            record, its worker fsynced the mitigation record.  The next trial must
            queue behind neither, and our halt=false must reach the daemon after
            its own halt (which is queued when the mitigation record is written)."""
            if log is None:
                return
            end = time.monotonic() + args.timeout
            while time.monotonic() < end and (
                log.count("mitigation") < total_halts or log.count("reset") < total_halts
            ):
                time.sleep(0.0002)  # polling the log file, not synchronisation

        def prepare() -> int:
            """The nominal state (halt false: each trial starts from a holding
            state), then the violating values except the trigger.  Each part is
            followed by the handshake: DDS does not order messages of different
            topics, and a trigger overtaking the values it completes would step
            on a half-published state.  Any halt meanwhile is a stray: again."""
            strays = 0
            while not _stop.is_set():
                settle_log()
                publish(nominal, order[:-1])
                extra = sync()
                publish(nominal, order[-1:])
                extra += sync()
                publish(violating, order[:-1])
                extra += sync()
                if not extra:
                    return strays
                strays += extra
            return strays

        latencies: list[int] = []
        walls: list[int] = []
        missed = strays = in_a_row = 0
        try:
            for trial in range(args.warmup + args.trials):
                s = prepare()
                if _stop.is_set():
                    return
                wall = time.time_ns()  # to line up with the daemon's record timestamps
                t0 = time.monotonic_ns()
                pubs[trigger].publish(violating[trigger])
                got, _ = pump(timeout_ns)
                t1 = time.monotonic_ns()
                in_a_row = 0 if got else in_a_row + 1
                if in_a_row >= 10:
                    emit(event="error", error=f"no halt in {in_a_row} trials in a row")
                    return
                if trial >= args.warmup:
                    strays += s
                    if got:
                        latencies.append(t1 - t0)
                        walls.append(wall)
                    else:
                        missed += 1
            settle_log()
        finally:
            loop.close()
        emit(
            event="result",
            latencies_ns=latencies,
            published_wall_ns=walls,
            missed=missed,
            strays=strays,
            sync_timeouts=sync_timeouts,
        )


class _LogTail:
    """Counts the daemon's records of one requirement by event, as the log grows."""

    def __init__(self, path: str, requirement: str) -> None:
        self.path = path
        self.requirement = f'"requirement":"{requirement}"'.encode()
        self.offset = 0
        self.partial = b""
        self.counts: dict[str, int] = {}

    def count(self, event: str) -> int:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                data = f.read()
        except OSError:
            data = b""
        self.offset += len(data)
        *lines, self.partial = (self.partial + data).split(b"\n")
        for line in lines:
            if self.requirement in line:
                start = line.find(b'"event":"') + 9
                kind = line[start : line.find(b'"', start)].decode()
                self.counts[kind] = self.counts.get(kind, 0) + 1
        return self.counts.get(event, 0)


# ------------------------------------------------------------------ main


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.bench.procs")
    sub = p.add_subparsers(dest="role", required=True)
    for role in ("publisher", "waitset", "executor", "echo", "driver"):
        r = sub.add_parser(role)
        r.add_argument("--spec", required=True, help="JSON list of {name, topic, msg, field}")
        r.add_argument("--publisher-node", default="bench_publisher")
        r.add_argument("--match-timeout", type=float, default=60.0)
    pub = sub.choices["publisher"]
    pub.add_argument("--values", required=True, help="JSON {name: value}")
    pub.add_argument("--rate", type=float, required=True)
    pub.add_argument("--seconds", type=float, required=True)
    pub.add_argument("--receivers", type=int, required=True)
    pub.add_argument("--node-name", default="bench_publisher")
    pub.add_argument("--diagnostics", action="store_true")
    pub.add_argument("--daemon-node", default="safety_supervisor")
    for role in ("echo", "driver"):
        r = sub.choices[role]
        r.add_argument("--sync-service", default="/safety_supervisor/reset")
        r.add_argument("--trigger", required=True)
        r.add_argument("--halt-topic", required=True)
        r.add_argument("--halt-msg", default="std_msgs/msg/Bool")
    sub.choices["echo"].add_argument("--when", required=True, help="NAME=INT: violating state")
    drv = sub.choices["driver"]
    drv.add_argument("--nominal", required=True)
    drv.add_argument("--violating", required=True)
    drv.add_argument("--trials", type=int, default=1000)
    drv.add_argument("--warmup", type=int, default=10)
    drv.add_argument("--timeout", type=float, default=1.0)
    drv.add_argument("--log", default=None, help="the daemon's violation log")
    drv.add_argument("--requirement", default="state_req103", help="whose records --log counts")
    ex = sub.add_parser("exec")
    ex.add_argument("argv", nargs=argparse.REMAINDER)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    die_with_parent()
    if args.role == "exec":
        cmd = args.argv[1:] if args.argv[:1] == ["--"] else args.argv
        os.execvp(cmd[0], cmd)
    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the bench decides when we stop
    try:
        topics = load_topics(args.spec)
        if args.role == "publisher":
            run_publisher(args, topics, json.loads(args.values))
        elif args.role == "waitset":
            run_waitset(topics, args.publisher_node)
        elif args.role == "executor":
            run_executor(topics, args.publisher_node)
        elif args.role == "echo":
            run_echo(args, topics)
        else:
            run_driver(args, topics)
    except Exception as e:  # noqa: BLE001 - one line for the bench, never a traceback
        emit(event="error", error=f"{args.role}: {type(e).__name__}: {e}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
