"""The rclpy side of the daemon: subscriptions -> Runtime -> policies -> actions.

Everything ROS-independent (latest values, step policies, stale inputs) lives
in :mod:`supervisor.daemon.runtime`, the per-requirement mitigation policy in
:mod:`mitigations.policy`; this module moves messages in and effects out.

Receiving: rclpy's default executor receives only about 4k msg/s on the
7 srobot topics on the reference machine, a loop over rclpy's wait set with
``take_message`` about 24k msg/s (``safety-supervisor bench``).  :class:`SupervisorNode`
therefore creates its subscriptions with rclpy (so they exist in the graph and
are destroyed with the node) but never spins an executor: :meth:`run` waits on
one ``_rclpy.WaitSet`` holding every subscription, the reset service and a
guard condition, and drains each ready subscription with ``take_message``.
This is the same private API ``rclpy.executors`` uses (rclpy 7.1.6).  All
timed work (periodic steps, synchronized skew, policy deadlines, stale checks,
heartbeat, diagnostics, watchdog) is done in the same loop by computing the
wait timeout from the earliest deadline, so the monitor, its policies and the
runtime are only ever touched by this one thread.

Violations: the policy decides (debounce, cooldown, latch, reset, escalation,
confirmation); a ``violation`` record is written in the loop thread before its
actions are handed to the engine's workers, so a slow action never delays the
next step; it is fsynced before the actions (``logging.durability:
before_action``) or at the loop's ``log.flush()`` once the inline publish is out
(``after_publish``, docs/reference/log.md).  A monitor reset happens between two steps: no
tick is lost.

Reload (SIGHUP): the new config is checked and compiled on a helper thread
while the old monitor keeps running; the swap happens between two loop
iterations.  Inputs keep their latest values, unchanged subscriptions and
mitigation publishers are kept (a latched halt stays latched).
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSCompatibility,
    QoSProfile,
    ReliabilityPolicy,
    qos_check_compatible,
)
from rclpy.serialization import deserialize_message

from mitigations.actions import PublisherKey, build_action
from mitigations.actions.base import Outcome
from mitigations.actions.publish import PublishAction
from mitigations.engine import Engine, Request
from mitigations.rosmsg import message_class
from mitigations.violationlog.format import json_safe
from mitigations.violationlog.writer import ViolationLog
from supervisor.config import Config, Variable
from supervisor.daemon.clock import WallClock
from supervisor.daemon.control import ControlRequest, ControlServer, Refusals, ResetGate
from supervisor.daemon.core import Core
from supervisor.daemon.diagnostics import diagnostic_array, input_status, requirement_status
from supervisor.daemon.loss import OwnWrites, RecordingPublisher, SequenceStreams
from supervisor.daemon.notify import Notifier
from supervisor.daemon.qos import graph_type_name, matching_qos, qos_for
from supervisor.daemon.runtime import Runtime
from supervisor.daemon.session import Session
from supervisor.daemon.status import StatusBoard
from supervisor.inputs.paths import ReadError
from supervisor.inputs.readers import SKIP, arrival_only, make_reader, plain_field
from supervisor.names import (
    DIAGNOSTICS_TOPIC,
    HEARTBEAT_TOPIC,
    RESET_SERVICE,
    STATUS_TOPIC,
    VIOLATIONS_TOPIC,
)

if TYPE_CHECKING:  # rosbags loads only when recording is on
    from supervisor.daemon.recorder import Recorder

MAX_WAIT_NS = 100_000_000  # the loop checks its flags at least this often
STATUS_EVERY_NS = 1_000_000_000
CONTROL_RESTARTS = 3  # a control thread that fails again after this many stays down
# Longest a loop turn spends taking messages before its timed work (watchdog,
# heartbeat, timers) runs: a flood never starves them (docs/reference/ros-interfaces.md).
TURN_BUDGET_NS = 20_000_000


def warn(text: str) -> None:
    try:
        print(f"safety-supervisor: WARNING: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


@dataclass
class _Sub:
    """One subscription: every variable reading a field of its topic is fed from
    each message at the same instant (one message is one event, as replay sees it)."""

    name: str  # the first variable's: names the subscription in graph records
    var: Variable
    msg_type: type
    sub: Any  # rclpy Subscription
    auto_qos: bool
    problem: str | None = None  # last graph problem reported (wrong type, QoS)
    publishers: int | None = None
    streams: SequenceStreams | None = None  # kept when the QoS changes
    vars: list[Variable] = field(default_factory=list)  # all of them, config order
    recorded: int | None = None  # the recorder's input index of this topic
    offered: bool = False  # the recording has this topic's offered QoS from the graph
    # Recording: where each variable's field lies in the serialized message (None:
    # deserialise), and how many first messages still check that against rclpy.
    plans: list[Any] | None = None
    checks: int = 0
    # How each variable reads a message (supervisor/inputs/readers.py), and which
    # of them read a stamp (moved onto the loop's clock on receipt).
    readers: list[Callable[[Any], Any]] = field(default_factory=list)
    ages: list[bool] = field(default_factory=list)
    # Looked up once (each rclpy property access is a call into C): the resolved
    # topic name, and the handle's take, set again whenever the loop is rebuilt.
    topic: str = ""
    take: Callable[..., Any] | None = None


class SupervisorNode:
    """One rclpy node feeding a Session; :meth:`run` is the receive loop."""

    def __init__(
        self,
        session: Session,
        log: ViolationLog,
        *,
        context: Context | None = None,
        notifier: Notifier | None = None,
        watchdog_s: float | None = None,
        control: ControlServer | None = None,
        recorder: Recorder | None = None,
        reload: Callable[[], Session] | None = None,
    ) -> None:
        self.session = session
        self.log = log
        # run --record: every input message as received, the log's records and the
        # core's markers, into rosbag2 bags (docs/reference/config.md, record).
        self.recorder = recorder
        self.notifier = notifier or Notifier()
        self.watchdog_ns = int(watchdog_s * 1e9) if watchdog_s else None
        self._stop = threading.Event()
        self._rebuild = False  # leave the inner loop: subscriptions changed
        self.reloads = 0
        self._done: list[tuple[Request, str, Outcome]] = []  # engine -> loop
        self._done_lock = threading.Lock()
        self._reload_request: Callable[[], Session] | None = None
        self._reload_thread: threading.Thread | None = None
        self._reload_result: Session | Exception | None = None
        # The control socket's reload: how to prepare a session (run's, as for
        # SIGHUP), the requests the next reload answers, and those the running one does.
        self._reload_prepare = reload
        self._reload_waiting: list[ControlRequest] = []
        self._reload_answering: list[ControlRequest] = []
        self._reload_started = 0  # monotonic ns of the running reload's RELOADING=1
        self._reopen_requests = 0  # SIGUSR1s received; counted, so none is lost
        self._reopens_done = 0
        self._retired: list[Any] = []  # subscriptions replaced by a QoS change
        self._unpublished: list[dict[str, Any]] = []  # violation records for the topic
        self._own = OwnWrites()  # what our mitigation publishers wrote
        self._clock = WallClock()  # message stamps onto the loop's clock (age_of)
        self._lost_reported: dict[str, int] = {}  # per input: lost total last logged
        self._lost_at_diag: dict[str, int] = {}  # per input: lost total last on /diagnostics

        cfg = session.config
        # The daemon's own topics and service are named relative to its namespace
        # (ros.namespace): in the default one they are the absolute names, and
        # supervisors of several robots on one graph stay apart.
        self.node = Node(cfg.ros.node_name, namespace=cfg.ros.namespace, context=context)
        self._subs: list[_Sub] = []
        self._make_subscriptions(cfg)
        self.publisher = self.node.create_publisher(
            _msg("std_msgs/msg/String"), own(VIOLATIONS_TOPIC), 10
        )
        self.heartbeat = self.node.create_publisher(
            _msg("std_msgs/msg/UInt64"), own(HEARTBEAT_TOPIC), 1
        )
        # Latched (transient local, depth 1): a page that starts late has the latest.
        self.status_publisher = self.node.create_publisher(
            _msg("std_msgs/msg/String"),
            own(STATUS_TOPIC),
            QoSProfile(
                depth=1,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
            ),
        )
        self.diagnostics = self.node.create_publisher(
            _msg("diagnostic_msgs/msg/DiagnosticArray"), DIAGNOSTICS_TOPIC, 10
        )
        # A config may read /diagnostics (or any of our topics) as an input: our own
        # writes are remembered and never taken for the robot's (loss.py).
        self.publisher, self.heartbeat, self.status_publisher, self.diagnostics = (
            RecordingPublisher(p, p.topic_name, self._own)
            for p in (self.publisher, self.heartbeat, self.status_publisher, self.diagnostics)
        )
        from std_srvs.srv import Trigger

        self._trigger = Trigger
        # Opt-in (ros.reset_service): a Trigger carries no credentials; the
        # control socket is the authenticated way (docs/reference/ros-interfaces.md).
        self.reset_service: Any = None
        self._sync_reset_service(cfg)
        # Operator resets: the socket thread hands requests to this loop.
        self.control = control
        self._reset_gate = ResetGate()
        self._refusals = Refusals()
        self._control_seen = (cfg.control.socket, cfg.control.group)
        self._control_down = False  # its thread failed more than CONTROL_RESTARTS times
        self._wake = self.node.create_guard_condition(_never)
        # Other threads (control socket, reload) wake the loop only through _poke,
        # which close() shuts before the node is destroyed.
        self._wake_lock = threading.Lock()
        self._wake_open = True
        if control is not None:
            control.start(self._poke)
        # Kept across reloads: what a publisher latched stays latched.
        self._publish_actions: dict[PublisherKey, PublishAction] = {}
        self.engine = self._make_engine(cfg)
        # Messages and timers -> records and actions, as replay does it (core.py).
        self.core = Core(
            session,
            log,
            lambda request: self.engine.submit(request),
            published=self._unpublished.append,
            marker=self._marker if recorder is not None else None,
            warn=warn,
        )
        # Each record also goes to the status topic's feed, and to the recording.
        self.status = StatusBoard(cfg.ros.node_name, self.node.get_namespace())
        log.tee = self._tee

    # ------------------------------------------------------------ building

    def _make_subscriptions(self, cfg: Config) -> None:
        """Subscriptions for ``cfg``'s inputs, keeping those that did not change."""
        old = {(s.var.topic, s.var.msg, s.var.qos, s.var.depth): s for s in self._subs}
        subs: list[_Sub] = []
        by_key: dict[tuple[Any, ...], _Sub] = {}
        for var in cfg.inputs:
            assert var.topic is not None and var.msg is not None
            key = (var.topic, var.msg, var.qos, var.depth)
            if key in by_key:  # another field of a topic already subscribed
                by_key[key].vars.append(var)
                continue
            kept = old.pop(key, None)
            if kept is not None:
                kept.name, kept.var, kept.vars = var.name, var, [var]
                subs.append(by_key.setdefault(key, kept))
                continue
            klass = message_class(var.msg)
            qos, warning = qos_for(self.node, var)
            if warning:
                warn(warning)
                self.log.supervisor("input_no_publisher", input=var.name, topic=var.topic)
            sub = self.node.create_subscription(klass, var.topic, _never, qos)
            new = _Sub(
                var.name,
                var,
                klass,
                sub,
                auto_qos=var.qos == "auto",
                streams=SequenceStreams(),
                vars=[var],
            )
            subs.append(by_key.setdefault(key, new))
        for s in old.values():
            self.node.destroy_subscription(s.sub)
        for s in subs:
            s.readers = [make_reader(v) for v in s.vars]
            s.ages = [v.age_of is not None for v in s.vars]
            s.topic = s.sub.topic_name
        self._subs = subs
        if self.recorder is not None:
            index = {(t, m): i for i, (t, m) in enumerate(self.recorder.inputs)}
            plans = _field_plans(subs)
            for s in subs:
                s.plans, s.checks = plans.get(id(s)), RAW_CHECKS
                s.recorded = index.get((s.var.topic or "", s.var.msg or ""))
                if s.recorded is None:  # a topic a reload added: not in this recording
                    warn(f"{s.var.topic} is not recorded: it was added by a reload")
                    self.log.supervisor("record_topic_missing", topic=s.var.topic)
                else:
                    self._offer_qos(s, self._publishers(s))

    def _tee(self, line: str) -> None:
        self.status.record(line)
        if self.recorder is not None:
            self.recorder.record(time.monotonic_ns(), line)

    def _publish_status(self, now: int) -> None:
        doc = self.status.document(
            self.session,
            self.session.policies,
            now_ns=now,
            violations=self.core.violations,
            reloads=self.reloads,
            recording=self.recorder is not None,
            watchdog_s=self.watchdog_ns / 1e9 if self.watchdog_ns else None,
            control_socket=self.control.path if self.control is not None else None,
        )
        # Whether operators can reset: the socket thread's health and counts.
        doc["control"] = self.control.health() if self.control is not None else None
        # A page tells a dead supervisor from a slow one by this (ros-interfaces.md, Status).
        doc["status_period_s"] = self.session.config.ros.status_ms / 1000
        msg = _msg("std_msgs/msg/String")()
        msg.data = json.dumps(doc)
        try:
            self.status_publisher.publish(msg)
        except Exception as e:  # noqa: BLE001 - shutdown race
            warn(f"cannot publish {STATUS_TOPIC}: {e}")

    def _marker(self, what: str, t: int, fields: dict[str, Any]) -> None:
        assert self.recorder is not None
        record = {"event": "marker", "what": what, **fields}
        self.recorder.record(t, json.dumps(json_safe(record), sort_keys=True))

    def _inputs(self) -> list[tuple[_Sub, Variable]]:
        """Each input variable with the subscription that feeds it."""
        return [(s, v) for s in self._subs for v in s.vars]

    def _make_engine(self, cfg: Config) -> Engine:
        actions = {
            name: build_action(m, self.node, self._publish_actions)
            for name, m in cfg.mitigations.items()
        }
        # Remember every write of our publishers, so that a halt published on a
        # topic that is also an input is never taken for the robot's (loss.py).
        for action in self._publish_actions.values():
            if not isinstance(action.publisher, RecordingPublisher):
                topic = getattr(action.publisher, "topic_name", action.topic)
                action.publisher = RecordingPublisher(action.publisher, topic, self._own)
        return Engine(actions, self.log, on_done=self._on_done)

    def _on_done(self, request: Request, action: str, outcome: Outcome) -> None:
        # Engine worker thread: hand the outcome to the loop (policies are the loop's).
        with self._done_lock:
            self._done.append((request, action, outcome))

    # ------------------------------------------------------------ control

    def stop(self) -> None:
        """Ask :meth:`run` to return (safe from a signal handler)."""
        self._stop.set()

    def request_reload(self, prepare: Callable[[], Session]) -> None:
        """Reload with ``prepare()`` (run on a helper thread); safe from a signal handler.
        A request while a reload runs waits for it and then reloads once more."""
        self._reload_request = prepare

    def request_reopen(self) -> None:
        """Reopen the violation log (logrotate); safe from a signal handler."""
        self._reopen_requests += 1

    def _poke(self) -> None:
        """Wake the loop from another thread; a no-op once :meth:`close` began."""
        with self._wake_lock:
            if self._wake_open:
                self._wake.trigger()

    def close(self) -> None:
        """After :meth:`run`: stop the action workers, destroy the node."""
        with self._wake_lock:  # from here no thread but this one enters rcl
            self._wake_open = False
        if self.recorder is not None:
            if self.core.now is not None:  # replay judges up to here, as the loop did
                self._marker("stop", self.core.now, {})
            self.log.tee = None
            stats = self.recorder.close()
            self.log.supervisor(
                "record_closed",
                written=stats.written,
                dropped=stats.dropped,
                skipped=stats.skipped,
                lost=stats.lost,
                bags=stats.bags,
            )
        if self.control is not None:
            self.control.close()  # before the guard condition it wakes is destroyed
        busy = self.engine.close(timeout=1.0)
        if busy:
            warn(f"mitigations still running at exit: {', '.join(busy)}")
        if self.session.cleanup is not None:
            self.session.cleanup()
        self._destroy()

    def _destroy(self) -> None:
        """Destroy the node, so that its DDS participant says goodbye and other nodes
        see the daemon leave at once, not when its lease expires (20 s; see
        docs/reference/faults.md, "Stop").  Only from :meth:`close`: no other thread
        enters rcl any more (the control socket's is joined, the reload thread's wake
        is shut, the engine's workers run no ROS action) and the loop's wait set is
        destroyed (:meth:`_serve`).  The inputs' readers go first, so a robot's flood
        stops arriving; rclpy then destroys the rest and the participant."""
        for s in self._subs:
            self.node.destroy_subscription(s.sub)
        for old in self._retired:
            self.node.destroy_subscription(old)
        self._subs, self._retired = [], []
        self.node.destroy_node()

    # ------------------------------------------------------------ receive loop

    def run(self) -> None:
        """Receive until :meth:`stop`."""
        now = time.monotonic_ns()
        self.core.start(now)
        self._next = {"heartbeat": now, "diagnostics": now, "status": now}
        if self.session.config.ros.status_ms:
            self._next["status_topic"] = now
        if self.watchdog_ns:  # only a real deadline: a stale one would make the wait spin
            self._next["watchdog"] = now
        self._heartbeats = 0
        while not self._stop.is_set() and self.node.context.ok():
            self._rebuild = False
            self._serve()

    def _serve(self) -> None:
        ctx = self.node.context
        # This loop's records are echoed and teed at flush(), after each message's
        # actions, and under after_publish fsynced there: the halt follows the
        # record's write directly (docs/reference/log.md).
        self.log.defer_thread = threading.get_ident()
        by_ptr: dict[int, _Sub] = {}
        with contextlib.ExitStack() as stack:
            for s in self._subs:
                stack.enter_context(s.sub.handle)
                by_ptr[s.sub.handle.pointer] = s
                s.take = s.sub.handle.take_message
            self._sync_reset_service(self.session.config)
            srv = self.reset_service.handle if self.reset_service is not None else None
            if srv is not None:
                stack.enter_context(srv)
            stack.enter_context(self._wake.handle)
            stack.enter_context(ctx.handle)
            wait_set = _rclpy.WaitSet(
                len(self._subs), 1, 0, 0, 0 if srv is None else 1, 0, ctx.handle
            )
            # Finalised before the handles it holds are released, on every way out.
            stack.callback(wait_set.destroy_when_not_in_use)
            # The step trigger is taken last in each round (see _receive).
            trigger = self.session.config.step.trigger
            order = {
                s.sub.handle.pointer: (any(v.name == trigger for v in s.vars), i)
                for i, s in enumerate(self._subs)
            }
            handles = [s.sub.handle for s in self._subs]  # rclpy's property, once
            wake = self._wake.handle
            while not self._stop.is_set() and not self._rebuild and ctx.ok():
                rt = self.session.runtime
                now = time.monotonic_ns()
                wait_set.clear_entities()
                for h in handles:
                    wait_set.add_subscription(h)
                if srv is not None:
                    wait_set.add_service(srv)
                wait_set.add_guard_condition(wake)
                wait_set.wait(max(0, self._deadline(now) - now))
                ready = wait_set.get_ready_entities("subscription")
                if ready:
                    self._receive([by_ptr[p] for p in sorted(ready, key=order.__getitem__)], rt)
                if srv is not None and wait_set.get_ready_entities("service"):
                    self._serve_reset(srv)
                self._timed_work(time.monotonic_ns())
                self.log.flush()  # what this turn logged: to the journal and the copies

    def _deadline(self, now: int) -> int:
        d = min(now + MAX_WAIT_NS, *self._next.values())
        due = self.core.next_due(now)
        return d if due is None else min(d, due)

    def _receive(self, ready: list[_Sub], rt: Runtime) -> None:
        """Take one message from each ready subscription in turn, until all are
        empty or the turn's budget is spent; what is left stays queued in the
        middleware for the next turn, after the timed work. Round by round, a
        backlog of the robot's cycles is replayed cycle by cycle, trigger last."""
        end = time.monotonic_ns() + TURN_BUDGET_NS
        while ready:
            ready = [s for s in ready if self._take(s, rt)]
            if time.monotonic_ns() >= end:
                return

    def _take(self, s: _Sub, rt: Runtime) -> bool:
        """One message of ``s`` into the runtime; False when its queue is empty."""
        raw = self.recorder is not None and s.recorded is not None
        assert s.take is not None
        taken = s.take(s.msg_type, raw)
        if taken is None:
            return False
        msg, info = taken
        t = time.monotonic_ns()
        data = msg
        seq = info.get("publication_sequence_number") if isinstance(info, dict) else None
        if seq:
            if self._own.is_own(s.topic, seq, info.get("source_timestamp")):
                for v in s.vars:
                    rt.count_own(v.name)  # our own mitigation: not the robot's value
                return True
            assert s.streams is not None
            gap = s.streams.on_sequence(seq)
            if gap:
                for v in s.vars:
                    rt.count_lost(v.name, gap)
        values = None
        if raw:
            assert self.recorder is not None and s.recorded is not None
            if not s.offered:  # its publisher is matched, so in the graph, by now
                self._offer_qos(s, self._publishers(s))
            self.recorder.message(s.recorded, t, data)
            values = self._read_raw(s, data)
            if values is None:
                msg = deserialize_message(data, s.msg_type)
        if values is None:
            values = self._read(s, msg, t)
        if values:
            self.core.fields(values, t)
        if self._unpublished:
            self._publish_reports()
        self.log.flush()  # a violation's fsync, echo and copies, after its actions are out
        return True

    def _read(self, s: _Sub, msg: Any, t: int) -> list[tuple[str, Any]]:
        """Each variable's value in ``msg`` (those its message carries)."""
        values = []
        for v, read, age in zip(s.vars, s.readers, s.ages, strict=True):
            try:
                x = read(msg)
            except (ReadError, AttributeError, TypeError, ValueError) as e:
                self.core.reject(v.name, t, str(e))  # e.g. an element past the end
                continue
            if x is SKIP:
                continue
            if age:
                x, step = self._clock.to_monotonic(x, t)
                if step:
                    warn(f"the wall clock stepped by {step / 1e6:+.1f} ms")
                    self.log.supervisor("clock_jump", by_ms=round(step / 1e6, 3))
            values.append((v.name, x))
        return values

    def _read_raw(self, s: _Sub, data: bytes) -> list[tuple[str, Any]] | None:
        """The subscription's fields read from the serialized message where the CDR
        layout places them (supervisor/daemon/cdr.py), without building the message:
        recording then costs the loop less than deserialising would.  None: the
        caller deserialises.  The first messages of each topic are read both ways,
        and a disagreement turns this off for the topic (and is logged)."""
        if s.plans is None:
            return None
        out = []
        for v, plan in zip(s.vars, s.plans, strict=True):
            x = True if arrival_only(v) else plan.read(data) if plan is not None else None
            if x is None:
                return None
            out.append((v.name, x))
        if s.checks:
            s.checks -= 1
            msg = deserialize_message(data, s.msg_type)
            try:
                want = [(v.name, read(msg)) for v, read in zip(s.vars, s.readers, strict=True)]
            except (ReadError, AttributeError, TypeError, ValueError):
                return None
            if any(a != b and a == a for (_, a), (_, b) in zip(want, out, strict=True)):
                s.plans = None
                self.log.supervisor("record_read_fallback", topic=s.var.topic)
                return want
        return out

    def _timed_work(self, now: int) -> None:
        self.core.advance(now)  # steps, stale inputs, policy deadlines: each at its time
        if self._unpublished:
            self._publish_reports()
        if self._done:
            self._outcomes()
        self._control_work(now)
        nxt = self._next
        if now >= nxt["heartbeat"]:
            self._heartbeats += 1
            self.heartbeat.publish(_msg("std_msgs/msg/UInt64")(data=self._heartbeats))
            nxt["heartbeat"] = now + int(self.session.config.ros.heartbeat_ms * 1e6)
        status_ms = self.session.config.ros.status_ms
        if status_ms and now >= nxt.get("status_topic", now):
            self._publish_status(now)
            nxt["status_topic"] = now + int(status_ms * 1e6)
        if now >= nxt["diagnostics"]:
            self._check_graph()
            self._publish_diagnostics(now)
            nxt["diagnostics"] = now + int(self.session.config.ros.diagnostics_ms * 1e6)
        if self.watchdog_ns and now >= nxt.get("watchdog", now):
            if self._ticking(now) and self._control_serving():
                self.notifier.watchdog()
                nxt["watchdog"] = now + self.watchdog_ns
        if now >= nxt["status"]:
            nxt["status"] = now + STATUS_EVERY_NS
            self._report_loss()
            if self.notifier.enabled:
                self.notifier.status(self.status_line())
        self._reload_step()

    def _ticking(self, now: int) -> bool:
        """Ticks flow as configured: a periodic monitor is not behind its timer
        by more than a watchdog interval (event-driven policies step inside
        this loop, so the loop running is the evidence)."""
        due = self.session.runtime.due(now)
        if self.session.config.step.policy != "periodic" or due is None:
            return True
        assert self.watchdog_ns is not None
        return now - due < self.watchdog_ns

    def _report_loss(self) -> None:
        """At most once a second: one ``input_lost`` record per input that lost
        messages since the last one."""
        stats = self.session.runtime.input_stats()
        for s, v in self._inputs():
            total = stats[v.name]["lost"]
            new = total - self._lost_reported.get(v.name, 0)
            if new <= 0:
                continue
            self._lost_reported[v.name] = total
            warn(f"input '{v.name}': {new} messages lost ({total} so far) on {s.var.topic}")
            self.log.supervisor(
                "input_lost",
                input=v.name,
                topic=s.var.topic,
                lost=new,
                total=total,
                by_publisher=s.streams.by_publisher() if s.streams else [],
            )

    def status_line(self) -> str:
        rt = self.session.runtime
        stale = rt.stale_inputs()
        missing = rt.missing_inputs()
        latched = [self.session.requirements[i].id for i in self.core.supervision.latched()]
        parts = [
            f"ticks={rt.tick}",
            f"violations={self.core.violations}",
            f"stale={','.join(stale) if stale else 'none'}",
        ]
        stats = rt.input_stats()
        parts.append(f"received={sum(st['messages'] + st['rejected'] for st in stats.values())}")
        lost = {n: st["lost"] for n, st in stats.items() if st["lost"]}
        parts.append("lost=" + (",".join(f"{n}:{c}" for n, c in lost.items()) or "0"))
        if missing:
            parts.append(f"waiting_for={','.join(missing)}")
        if latched:
            parts.append(f"latched={','.join(sorted(latched))}")
        if not self._control_serving():
            parts.append("control=down")
        return " ".join(parts)

    def stop_stats(self) -> dict[str, dict[str, Any]]:
        """Per input, for the ``stop`` record: the counts, and per publisher stream
        the first and last number heard, received and lost: what a publisher sent
        outside them is not counted as lost, but whoever knows what it sent can
        (docs/reference/ros-interfaces.md#lost-messages)."""
        streams = {v.name: s.streams for s in self._subs for v in s.vars}
        out: dict[str, dict[str, Any]] = {}
        for name, st in self.session.runtime.input_stats().items():
            out[name] = {k: st[k] for k in ("messages", "rejected", "nan", "lost", "own")}
            seqs = streams.get(name)
            out[name]["by_publisher"] = seqs.by_publisher() if seqs else []
        return out

    def _publish_reports(self) -> None:
        records, self._unpublished = self._unpublished, []
        for record in records:
            msg = _msg("std_msgs/msg/String")()
            msg.data = json.dumps(json_safe({"event": "violation", **record}))
            try:
                self.publisher.publish(msg)
            except Exception as e:  # noqa: BLE001 - e.g. the context is shutting down
                warn(f"cannot publish on {VIOLATIONS_TOPIC}: {e}")

    def _outcomes(self) -> None:
        with self._done_lock:
            done, self._done = self._done, []
        for request, action, outcome in done:
            if not outcome.ok:
                warn(f"mitigation {action} for {request.requirement} failed: {outcome.error}")

    # ------------------------------------------------------------ operator reset

    def _sync_reset_service(self, cfg: Config) -> None:
        """The ROS reset service exists iff ``ros.reset_service`` (also after a reload)."""
        if cfg.ros.reset_service and self.reset_service is None:
            self.reset_service = self.node.create_service(self._trigger, own(RESET_SERVICE), _never)
            self.log.supervisor("reset_service", enabled=True, service=RESET_SERVICE)
        elif not cfg.ros.reset_service and self.reset_service is not None:
            self.node.destroy_service(self.reset_service)
            self.reset_service = None
            self.log.supervisor("reset_service", enabled=False, service=RESET_SERVICE)

    def _serve_reset(self, srv: Any) -> None:
        taken = srv.service_take_request(self._trigger.Request)
        if taken is None:
            return
        request, header = taken
        if header is None:
            return
        ok, message, _ = self.operator_reset(via="ros_service", caller=None)
        # take_request gives rmw_service_info_t; the reply wants its request id.
        request_id = getattr(header, "request_id", header)
        try:
            srv.service_send_response(
                self._trigger.Response(success=ok, message=message), request_id
            )
        except Exception as e:  # noqa: BLE001 - the caller went away; the reset stands
            warn(f"cannot answer {RESET_SERVICE}: {e}")

    def _control_serving(self) -> bool:
        """The control socket's thread serves (no socket: nothing to serve).  The
        watchdog pings only while it does: an operator who cannot reset is a
        failure systemd must see (docs/reference/ros-interfaces.md, "Control socket")."""
        return self.control is None or self.control.alive()

    def _control_health(self) -> None:
        """A control thread that ended is recorded and started again, at most
        ``CONTROL_RESTARTS`` times; after that it stays down, the status and
        STATUS= say so and the watchdog stops."""
        control = self.control
        # A thread that runs but is late (the process was stopped, the machine is
        # swamped) is not restarted: the watchdog waits for it (_control_serving).
        if control is None or control.running() or self._control_down:
            return
        error = control.health()["error"] or "it ended"
        warn(f"control socket {control.path}: its thread failed: {error}")
        if control.restarts < CONTROL_RESTARTS and control.revive():
            self.log.supervisor("control_failed", socket=control.path, error=error, restarted=True)
            return
        self._control_down = True
        self.log.supervisor("control_failed", socket=control.path, error=error, restarted=False)

    def _control_work(self, now: int) -> None:
        """Answer the control socket's requests; report refused calls once per interval."""
        cfg = self.session.config.control
        self._control_health()
        if self.control is not None:
            for req in self.control.take():
                if req.refused is not None:
                    self._refusals.add(req.refused, _who(req.caller.record()))
                    req.answer({"ok": False, "refused": req.refused, "message": req.detail})
                    continue
                if req.command == "reload":
                    self._control_reload(req)
                    continue
                ok, message, refused = self.operator_reset(
                    via=req.via or "control_socket",
                    caller=req.caller.record(),
                    now=now,
                    requirement=req.requirement,
                    client=req.client,
                )
                reply: dict[str, Any] = {"ok": ok, "message": message}
                if refused is not None:
                    reply["refused"] = refused
                req.answer(reply)
            seen = (cfg.socket, cfg.group)
            if seen != self._control_seen:  # a reload changed control.socket or group
                self._control_seen = seen
                why = "control.socket and control.group take effect at the next start"
                warn(f"{why}; still serving {self.control.path}")
                self.log.supervisor("control_unchanged", socket=self.control.path, why=why)
        summary = self._refusals.due(now, int(cfg.interval_ms * 1e6))
        if summary is not None:
            counts = ", ".join(f"{n} {why}" for why, n in summary["refused"].items())
            warn(f"operator reset refused: {counts}")
            self.log.supervisor("reset_refused", **summary)

    def _control_reload(self, req: ControlRequest) -> None:
        """A reload asked for on the control socket: answered when the new config
        is in force or refused (:meth:`_reload_step`), as ``systemctl reload``
        needs.  A reload already running read the config before this request:
        the request waits for the next one, which reads the file anew."""
        if self._reload_prepare is None:
            req.answer(
                {"ok": False, "refused": "bad_request", "message": "reload is not available"}
            )
            return
        self._reload_waiting.append(req)
        self.request_reload(self._reload_prepare)

    def operator_reset(
        self,
        *,
        via: str,
        caller: dict[str, Any] | None,
        now: int | None = None,
        requirement: str | None = None,
        client: str | None = None,
    ) -> tuple[bool, str, str | None]:
        """Reset every requirement's monitor (or ``requirement``'s); lift latches of
        requirements that hold.  Returns (accepted, message for the caller, why refused).

        At most ``control.max_resets`` per ``control.interval_ms``: a refused call
        touches nothing and is counted, not logged on its own (:class:`Refusals`)."""
        now = time.monotonic_ns() if now is None else now
        who = _who(caller) if caller is not None else via
        cfg = self.session.config.control
        known = [r.id for r in self.session.requirements]
        if requirement is not None and requirement not in known:
            self._refusals.add("bad_request", who)
            return (
                False,
                f"no requirement '{requirement}' (known: {', '.join(known)})",
                "bad_request",
            )
        if not self._reset_gate.admit(now, cfg.max_resets, int(cfg.interval_ms * 1e6)):
            self._refusals.add("rate", who)
            return (
                False,
                f"not reset: rate limited to {cfg.max_resets} per {cfg.interval_ms:g} ms "
                "(control.max_resets, control.interval_ms); try again",
                "rate",
            )
        extra: dict[str, Any] = {"via": via}
        if caller is not None:
            extra["caller"] = caller
        if client is not None:
            extra["client"] = client
        refused = self.core.operator_reset(now, requirement, **extra)
        if refused:
            self._refusals.add("still_violated", who)
            return False, "not reset: " + ", ".join(refused), "still_violated"
        return True, f"{requirement or 'all requirements'} reset", None

    # ------------------------------------------------------------ graph and diagnostics

    def _check_graph(self) -> None:
        """Publishers that cannot reach us (wrong type, incompatible QoS), topics
        without publishers; auto-QoS subscriptions follow the publishers found."""
        for s in self._subs:
            topic = s.var.topic
            assert topic is not None
            try:
                pubs = self.node.get_publishers_info_by_topic(topic)
            except Exception as e:  # noqa: BLE001 - graph queries fail during shutdown
                warn(f"cannot query publishers of {topic}: {e}")
                return
            # Our own mitigation publishers (a halt on the robot's halt topic)
            # are not the robot: they must not hide a missing robot publisher.
            me = (self.node.get_name(), self.node.get_namespace())
            pubs = [p for p in pubs if (p.node_name, p.node_namespace) != me]
            mine = s.sub.qos_profile if hasattr(s.sub, "qos_profile") else None
            problem = None
            expected = graph_type_name(s.var.msg or "")
            wrong = [p for p in pubs if p.topic_type != expected]
            right = [p for p in pubs if p.topic_type == expected]
            if not pubs:
                problem = f"no publisher on {topic}"
            elif wrong:
                problem = (
                    f"publisher of {wrong[0].topic_type} on {topic} ({wrong[0].node_name}); "
                    f"expected {expected}: its messages cannot reach the supervisor"
                )
            elif mine is not None:
                for p in right:
                    compat, reason = qos_check_compatible(p.qos_profile, mine)
                    if compat == QoSCompatibility.ERROR:
                        if s.auto_qos:
                            self._resubscribe(s, [q.qos_profile for q in right])
                            problem = None
                        else:
                            problem = f"incompatible QoS with {p.node_name} on {topic}: {reason}"
                        break
            if s.publishers is not None and not pubs and s.publishers:
                self.log.supervisor("input_publisher_gone", input=s.name, topic=topic)
            if s.publishers is not None and pubs and not s.publishers:
                self.log.supervisor("input_publisher_found", input=s.name, topic=topic)
            s.publishers = len(right)
            self._offer_qos(s, right)
            if problem != s.problem:
                if problem is not None and (pubs or s.problem is not None):
                    warn(f"input '{s.name}': {problem}")
                    self.log.supervisor("input_problem", input=s.name, detail=problem)
                elif problem is None and s.problem is not None:
                    self.log.supervisor("input_problem_cleared", input=s.name, topic=topic)
                s.problem = problem

    def _publishers(self, s: _Sub) -> list[Any]:
        """The robot's publishers of ``s``'s topic and type now (not ours)."""
        try:
            pubs = self.node.get_publishers_info_by_topic(s.var.topic or "")
        except Exception:  # noqa: BLE001 - graph queries fail during shutdown
            return []
        me = (self.node.get_name(), self.node.get_namespace())
        expected = graph_type_name(s.var.msg or "")
        return [
            p for p in pubs if p.topic_type == expected and (p.node_name, p.node_namespace) != me
        ]

    def _offer_qos(self, s: _Sub, pubs: list[Any]) -> None:
        """The recording writes the QoS the topic's publishers offer, as rosbag2 does,
        so that ``ros2 bag play`` of it keeps latching (docs/reference/config.md, record)."""
        if self.recorder is not None and s.recorded is not None:
            self.recorder.offered_qos(s.recorded, [p.qos_profile for p in pubs])
            s.offered = s.offered or bool(pubs)

    def _resubscribe(self, s: _Sub, offered: list[QoSProfile]) -> None:
        qos = matching_qos(s.var.depth, offered)
        self.log.supervisor(
            "input_qos_changed",
            input=s.name,
            topic=s.var.topic,
            reliability=qos.reliability.name.lower(),
            durability=qos.durability.name.lower(),
        )
        old = s.sub
        s.sub = self.node.create_subscription(s.msg_type, s.var.topic, _never, qos)
        self._rebuild = True  # the wait set must be rebuilt with the new handle
        self._retired.append(old)  # destroyed once the loop no longer holds its handle

    def _publish_diagnostics(self, now: int) -> None:
        for old in self._retired:
            with contextlib.suppress(Exception):
                self.node.destroy_subscription(old)
        self._retired = []
        s = self.session
        cfg = s.config
        name = cfg.ros.node_name
        stats = s.runtime.input_stats()
        statuses = []
        for i, req in enumerate(s.requirements):
            pol = s.policies[i]
            statuses.append(
                requirement_status(name, cfg.component, req.id, pol.state(), not pol.holds)
            )
        for sub, v in self._inputs():
            st = dict(stats[v.name])
            st["problem"], st["publishers"] = sub.problem, sub.publishers
            st["lost_recent"] = st["lost"] - self._lost_at_diag.get(v.name, 0)
            self._lost_at_diag[v.name] = st["lost"]
            st["by_publisher"] = sub.streams.by_publisher() if sub.streams else []
            statuses.append(input_status(name, cfg.component, v.name, sub.var.topic or "", st, now))
        stamp = self.node.get_clock().now().to_msg()
        try:
            self.diagnostics.publish(diagnostic_array(stamp, statuses))
        except Exception as e:  # noqa: BLE001 - shutdown race
            warn(f"cannot publish /diagnostics: {e}")

    # ------------------------------------------------------------ reload

    def _reload_step(self) -> None:
        # Reopen first: a reload never delays the switch to the new log file.
        requested = self._reopen_requests
        if requested != self._reopens_done:
            self._reopens_done = requested  # a signal after this line is served next turn
            self.log.reopen()  # logrotate's create mode: a fresh file after rename
        if self._reload_request is not None and self._reload_thread is None:
            # A SIGHUP during a reload stays in _reload_request until this one ends:
            # the newest config is then read once more (requests coalesce, none is lost).
            prepare, self._reload_request = self._reload_request, None
            # An old logrotate snippet sends SIGHUP: follow a rotated path all the same.
            self.log.reopen(only_if_moved=True)
            self._reload_answering, self._reload_waiting = self._reload_waiting, []
            self._reload_started = time.monotonic_ns()
            self.notifier.reloading(status="reloading configuration")

            def work() -> None:
                try:
                    self._reload_result = prepare()
                except Exception as e:  # noqa: BLE001 - reported by the loop
                    self._reload_result = e
                self._poke()

            self._reload_thread = threading.Thread(target=work, name="reload", daemon=True)
            self._reload_thread.start()
        if self._reload_thread is not None and not self._reload_thread.is_alive():
            self._reload_thread = None
            result, self._reload_result = self._reload_result, None
            requests, self._reload_answering = self._reload_answering, []
            how = self._reload_how(requests)
            if isinstance(result, Session):
                self._swap(result, how)
                sha = result.config.sha256
                n = len(result.requirements)
                reply: dict[str, Any] = {
                    "ok": True,
                    "message": f"reloaded: monitoring {n} requirements, config sha256 {sha}",
                    "config_sha256": sha,
                }
            else:
                why = " ".join(str(result).splitlines())  # one line, wherever it came from
                warn(f"reload rejected, still running the previous config: {why}")
                self.log.supervisor("reload", ok=False, why=why, **how)
                self.notifier.ready(status=f"reload rejected: {why} | {self.status_line()}")
                reply = {
                    "ok": False,
                    "refused": "config",
                    "message": f"reload rejected, still running the previous config: {why}",
                    "config_sha256": self.session.config.sha256,
                }
            # After the record and READY=1: whoever waits sees the outcome everywhere.
            for req in requests:
                req.answer(reply)

    def _reload_how(self, requests: list[ControlRequest]) -> dict[str, Any]:
        """The reload record's ``via`` (``signal`` or ``control_socket``), the
        callers who asked on the socket, and how long the reload took."""
        took = round((time.monotonic_ns() - self._reload_started) / 1e6, 3)
        if not requests:
            return {"via": "signal", "duration_ms": took}
        callers = [r.caller.record() for r in requests]
        return {"via": "control_socket", "callers": callers, "duration_ms": took}

    def _swap(self, new: Session, how: dict[str, Any]) -> None:
        old = self.session
        rt_old, rt_new = old.runtime, new.runtime
        rt_new.adopt(rt_old)
        self._make_subscriptions(new.config)
        old_engine = self.engine
        kept = _keep_policies(old, new)
        self.session = new
        self.engine = self._make_engine(new.config)
        self.core.swap(new)  # kept policies go on where they were: latches stay
        self.log.config_sha256 = new.config.sha256
        self.log.retry_buffer = new.config.log_retry_buffer
        self.log.durability = new.config.log_durability
        self.reloads += 1
        self._rebuild = True
        threading.Thread(target=old_engine.close, name="old-engine", daemon=True).start()
        if old.cleanup is not None:
            old.cleanup()
        n = len(new.requirements)
        self.log.supervisor(
            "reload",
            ok=True,
            config=new.config.path,
            kept_state=kept,
            requirements=n,
            inputs=len(new.config.inputs),
            policy=new.config.step.policy,
            tick=new.runtime.tick,  # the first tick judged by the new monitor
            **how,
        )
        if new.config.ros.status_ms:  # the status topic names the new config at once
            self._publish_status(time.monotonic_ns())
        self.notifier.ready(status=f"reloaded: monitoring {n} requirements | {self.status_line()}")


RAW_CHECKS = 3  # first messages of a topic read both ways when recording (_read_raw)


def _field_plans(subs: list[_Sub]) -> dict[int, list[Any]]:
    """For recording: per subscription (by id), each variable's field plan over the
    message definitions rosbags knows and the installed .msg files."""
    from rosbags.typesys import Stores, get_typestore

    from supervisor.daemon.cdr import field_plan
    from supervisor.inputs.rostypes import load_msg_types

    store = get_typestore(Stores.ROS2_JAZZY)
    out: dict[int, list[Any]] = {}
    for s in subs:
        msgtype = graph_type_name(s.var.msg or "")
        try:
            load_msg_types(store, msgtype)
        except (LookupError, OSError, ValueError):
            continue  # deserialised, as without recording
        out[id(s)] = [
            field_plan(store, msgtype, f) if (f := plain_field(v)) else None for v in s.vars
        ]
    return out


def _who(caller: dict[str, Any]) -> str:
    """A caller as the refusal summary names it."""
    return str(caller.get("user", f"uid {caller.get('uid')}"))


def _keep_policies(old: Session, new: Session) -> list[str]:
    """A requirement whose text, formula, policy and actions did not change keeps its
    policy object (latch, episode, incident) across a reload, so a reload neither
    releases a latch nor reports a violation again; the ids of those kept."""

    def key(s: Session, i: int) -> tuple[Any, ...]:
        p = s.policies[i]
        return (s.formulas[i], p.config, p.on_violation, p.repeatable)

    before = {r.id: i for i, r in enumerate(old.requirements)}
    kept = []
    for i, req in enumerate(new.requirements):
        j = before.get(req.id)
        if j is not None and key(old, j) == key(new, i):
            new.policies[i] = old.policies[j]
            kept.append(req.id)
    return kept


def own(name: str) -> str:
    """One of the daemon's own names, relative to its namespace."""
    return name.lstrip("/")


def _never(*_args: Any) -> None:
    """Callback of entities the wait-set loop serves itself (never called)."""


_MSG_CACHE: dict[str, type] = {}


def _msg(name: str) -> type:
    klass = _MSG_CACHE.get(name)
    if klass is None:
        klass = _MSG_CACHE[name] = message_class(name)
    return klass
