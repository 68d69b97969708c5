"""The rclpy side of the daemon: subscriptions -> Runtime -> violation log.

Everything ROS-independent (latest values, step policies, stale inputs) lives
in :mod:`supervisor.runtime`; this module only moves messages in and
violations out.

Receiving: rclpy's default executor receives only about 4k msg/s on the
7 srobot topics on the reference machine, a loop over rclpy's wait set with
``take_message`` about 24k msg/s (issue 3, "Benchmark").  :class:`SupervisorNode`
therefore creates its subscriptions with rclpy (so they exist in the graph and
are destroyed with the node) but never spins an executor: :meth:`run` waits on
one ``_rclpy.WaitSet`` holding every subscription, the reset service and a
guard condition, and drains each ready subscription with ``take_message``.
This is the same private API ``rclpy.executors`` uses (rclpy 7.1.6); the timer
work (periodic steps, synchronized skew, stale checks) is done in the same loop
by computing the wait timeout from the runtime's next deadline.

Violations: the ``violation`` record is written (fsynced) in the loop thread
before anything else happens with it, then the requirement goes to a worker
thread through a queue, which publishes it as JSON on
``/safety_supervisor/violations`` and runs its mitigations (for now only kind
``log``; the mitigation engine comes with its own issue).

Until per-requirement policies exist, a requirement is reported when its
handler starts firing (rising edge): a past-time ``always`` latches, and a
latched requirement would otherwise write and fsync a record on every tick.
``/safety_supervisor/reset`` (std_srvs/Trigger) resets the whole monitor.
"""

from __future__ import annotations

import contextlib
import json
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from monitors.formula import to_fret

from .config import Config, Variable
from .log import ViolationLog, json_safe
from .pipeline import Project
from .rosmsg import get_field, message_class
from .runtime import InputEvent, Runtime, StepResult

VIOLATIONS_TOPIC = "/safety_supervisor/violations"
RESET_SERVICE = "/safety_supervisor/reset"
MAX_WAIT_NS = 100_000_000  # the loop checks the stop flag at least this often
STALE_CHECK_MAX_NS = 50_000_000
REJECT_REPORT_FIRST = 10  # then every REJECT_REPORT_EVERY-th rejected value per input
REJECT_REPORT_EVERY = 1000


def _warn(text: str) -> None:
    try:
        print(f"safety-supervisor: WARNING: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def qos_for(node: Node, var: Variable) -> tuple[QoSProfile, str | None]:
    """The subscription QoS of ``var`` and, for ``auto``, a warning when the
    topic has no publisher yet (then: reliable, volatile)."""
    depth = var.depth
    if var.qos == "reliable":
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE), None
    if var.qos == "best_effort":
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT), None
    if var.qos == "sensor_data":
        p = QoSProfile(
            depth=depth,
            reliability=qos_profile_sensor_data.reliability,
            durability=qos_profile_sensor_data.durability,
            history=qos_profile_sensor_data.history,
        )
        return p, None
    assert var.topic is not None
    pubs = node.get_publishers_info_by_topic(var.topic)
    if not pubs:
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE), (
            f"input '{var.name}': no publisher on {var.topic} yet; subscribing reliable "
            "(set qos: in the config to choose)"
        )
    # A reliable reader does not match a best-effort writer; a transient-local
    # reader does not match a volatile writer: take the weakest offered.
    best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in pubs)
    transient = all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in pubs)
    return (
        QoSProfile(
            depth=depth,
            reliability=ReliabilityPolicy.BEST_EFFORT
            if best_effort
            else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE,
        ),
        None,
    )


@dataclass
class _Sub:
    name: str
    field: str
    msg_type: type
    sub: Any  # rclpy Subscription


@dataclass
class _Job:
    index: int  # requirement index in the monitor
    result: StepResult
    detected_ns: int
    record: dict[str, Any]


class SupervisorNode:
    """One rclpy node feeding a Runtime; :meth:`run` is the receive loop."""

    def __init__(
        self,
        project: Project,
        runtime: Runtime,
        log: ViolationLog,
        *,
        context: Context | None = None,
        node_name: str = "safety_supervisor",
    ) -> None:
        self.project = project
        self.cfg: Config = project.config
        self.runtime = runtime
        self.log = log
        self.requirements = [r for r in project.requirements if r.ok]  # monitor order
        self._formulas = [to_fret(r.formula) for r in self.requirements]
        self._stop = threading.Event()
        self._flagged = [False] * len(self.requirements)  # rising-edge reporting
        self.violations = 0
        self._queue: queue.Queue[_Job | None] = queue.Queue()
        step = self.cfg.step
        self._stale_ns = int(step.stale_after_ms * 1e6) if step.stale_after_ms else None
        period = int(step.period_ms * 1e6) if step.period_ms else STALE_CHECK_MAX_NS
        self._stale_every_ns = min(period, STALE_CHECK_MAX_NS)

        self.node = Node(node_name, context=context)
        self._subs: list[_Sub] = []
        self.no_publisher: list[str] = []
        for var in self.cfg.inputs:
            assert var.topic is not None and var.msg is not None
            klass = message_class(var.msg)
            qos, warning = qos_for(self.node, var)
            if warning:
                self.no_publisher.append(var.name)
                _warn(warning)
                self.log.supervisor("input_no_publisher", input=var.name, topic=var.topic)
            sub = self.node.create_subscription(klass, var.topic, _never, qos)
            self._subs.append(_Sub(var.name, var.field, klass, sub))
        self.publisher = self.node.create_publisher(_string_class(), VIOLATIONS_TOPIC, 10)
        from std_srvs.srv import Trigger

        self._trigger = Trigger
        self.reset_service = self.node.create_service(Trigger, RESET_SERVICE, _never)
        self._wake = self.node.create_guard_condition(_never)
        self._worker = threading.Thread(target=self._work, name="mitigations", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------ control

    def stop(self) -> None:
        """Ask :meth:`run` to return (safe from a signal handler)."""
        self._stop.set()

    def close(self) -> None:
        """After :meth:`run`: finish queued violations, destroy the node."""
        self._queue.put(None)
        self._worker.join(timeout=1.0)
        self.node.destroy_node()

    # ------------------------------------------------------------ receive loop

    def run(self, on_idle: Callable[[], None] | None = None) -> None:
        """Receive until :meth:`stop`.  ``on_idle`` runs once per wait (status)."""
        ctx = self.node.context
        by_ptr: dict[int, _Sub] = {}
        with contextlib.ExitStack() as stack:
            for s in self._subs:
                stack.enter_context(s.sub.handle)
                by_ptr[s.sub.handle.pointer] = s
            srv = self.reset_service.handle
            stack.enter_context(srv)
            stack.enter_context(self._wake.handle)
            stack.enter_context(ctx.handle)
            wait_set = _rclpy.WaitSet(len(self._subs), 1, 0, 0, 1, 0, ctx.handle)
            next_stale = time.monotonic_ns()
            rt = self.runtime
            while not self._stop.is_set() and ctx.ok():
                now = time.monotonic_ns()
                deadline = now + MAX_WAIT_NS
                due = rt.due(now)
                if due is not None:
                    deadline = min(deadline, due)
                if self._stale_ns:
                    deadline = min(deadline, next_stale)
                wait_set.clear_entities()
                for s in self._subs:
                    wait_set.add_subscription(s.sub.handle)
                wait_set.add_service(srv)
                wait_set.add_guard_condition(self._wake.handle)
                wait_set.wait(max(0, deadline - now))
                ready = wait_set.get_ready_entities("subscription")
                for ptr in ready:
                    s = by_ptr[ptr]
                    take = s.sub.handle.take_message
                    while True:
                        info = take(s.msg_type, False)
                        if info is None:
                            break
                        try:
                            value = get_field(info[0], s.field)
                        except AttributeError as e:  # cannot happen after check; report
                            self._input_events(
                                [InputEvent("input_rejected", s.name, time.monotonic_ns(), str(e))]
                            )
                            continue
                        result, events = rt.on_message(s.name, value, time.monotonic_ns())
                        if events:
                            self._input_events(events)
                        if result is not None and (result.violated or any(self._flagged)):
                            self._handle_step(result)
                if wait_set.get_ready_entities("service"):
                    self._serve_reset(srv)
                now = time.monotonic_ns()
                due = rt.due(now)
                if due is not None and due <= now:
                    result = rt.on_timer(now)
                    if result is not None and (result.violated or any(self._flagged)):
                        self._handle_step(result)
                if self._stale_ns and now >= next_stale:
                    events = rt.check_stale(now, self._stale_ns)
                    if events:
                        self._input_events(events)
                    next_stale = now + self._stale_every_ns
                if on_idle is not None:
                    on_idle()

    # ------------------------------------------------------------ events

    def _input_events(self, events: list[InputEvent]) -> None:
        for ev in events:
            if ev.what == "input_rejected":
                n = self.runtime.input_stats()[ev.name]["rejected"]
                if n > REJECT_REPORT_FIRST and n % REJECT_REPORT_EVERY:
                    continue
                self.log.supervisor(ev.what, input=ev.name, detail=ev.detail, rejected=n)
            else:
                self.log.supervisor(ev.what, input=ev.name, detail=ev.detail)

    def _handle_step(self, result: StepResult) -> None:
        violated = set(result.violated)
        for i in range(len(self._flagged)):
            was, now = self._flagged[i], i in violated
            self._flagged[i] = now
            if now and not was:
                self._violation(i, result)

    def _violation(self, i: int, result: StepResult) -> None:
        detected = time.monotonic_ns()
        req = self.requirements[i]
        rt = self.runtime
        record = {
            "requirement": req.id,
            "text": req.entry.text,
            "formula": self._formulas[i],
            "tick": result.tick,
            "inputs": dict(result.inputs),
            "recent": list(rt.recent),
            "stale": rt.stale_inputs(),
            "policy_state": {"report": "rising_edge"},
        }
        # On disk (fsynced) before anything else is done with it (CONTRACT.md).
        self.log.violation(
            req.id,
            text=record["text"],
            formula=record["formula"],
            tick=record["tick"],
            inputs=record["inputs"],
            recent=record["recent"],
            stale=record["stale"],
            policy_state=record["policy_state"],
        )
        self.violations += 1
        self._queue.put(_Job(i, result, detected, record))

    def _serve_reset(self, srv: Any) -> None:
        taken = srv.service_take_request(self._trigger.Request)
        if taken is None:
            return
        request, header = taken
        if header is None:
            return
        self.runtime.monitor.reset()
        self._flagged = [False] * len(self._flagged)
        self.log.reset("*", reason="operator reset (/safety_supervisor/reset)")
        response = self._trigger.Response(success=True, message="all requirements reset")
        srv.service_send_response(response, header)

    # ------------------------------------------------------------ worker

    def _work(self) -> None:
        string = _string_class()
        while True:
            job = self._queue.get()
            if job is None:
                return
            try:
                self._mitigate(job, string)
            except Exception as e:  # noqa: BLE001 - the worker must survive anything
                _warn(f"mitigation worker: {type(e).__name__}: {e}")

    def _mitigate(self, job: _Job, string: type) -> None:
        req = self.requirements[job.index]
        msg = string()
        msg.data = json.dumps(json_safe({"event": "violation", **job.record}))
        try:
            self.publisher.publish(msg)
        except Exception as e:  # noqa: BLE001 - e.g. the context is shutting down
            _warn(f"cannot publish on {VIOLATIONS_TOPIC}: {e}")
        for name in req.entry.on_violation:
            m = self.cfg.mitigations.get(name)
            kind = m.kind if m is not None else "undefined"
            latency_ms = (time.monotonic_ns() - job.detected_ns) / 1e6
            if kind == "log":
                self.log.mitigation(req.id, action=name, kind=kind, ok=True, latency_ms=latency_ms)
            else:
                # TODO(mitigation engine issue): publish / ssh / service actions.
                self.log.supervisor(
                    "mitigation_not_run",
                    requirement=req.id,
                    action=name,
                    kind=kind,
                    why="the mitigation engine is not implemented yet",
                )


def _never(*_args: Any) -> None:
    """Callback of entities the wait-set loop serves itself (never called)."""


def _string_class() -> type:
    from std_msgs.msg import String

    return String


def init_ros(domain_id: int | None = None) -> Context:
    """A fresh rclpy context without rclpy's signal handlers (the daemon has its own)."""
    from rclpy.signals import SignalHandlerOptions

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    return ctx


# ------------------------------------------------------------------ the daemon


def build_runtime(project: Project, monitor: Any) -> Runtime:
    from .runtime import InputSpec

    cfg = project.config
    step = cfg.step
    specs = [
        InputSpec(
            v.name,
            v.type,
            initial=v.initial,
            stale_after_ns=int(v.stale_after_ms * 1e6) if v.stale_after_ms else None,
        )
        for v in cfg.inputs
    ]
    return Runtime(
        inputs=specs,
        monitor=monitor,
        policy=step.policy,
        trigger=step.trigger,
        period_ns=int(step.period_ms * 1e6) if step.period_ms else None,
        max_skew_ns=int(step.max_skew_ms * 1e6) if step.max_skew_ms else None,
        recent_len=cfg.recent,
    )


def run_daemon(config: str, log_path: str | None = None, build_dir: str | None = None) -> int:
    """``safety-supervisor run``: build the monitor, subscribe, READY=1, receive until
    SIGTERM/SIGINT, STOPPING=1, clean shutdown.  Raises UserError for a bad config."""
    import os
    import signal
    import tempfile
    from pathlib import Path

    from monitors.errors import UserError
    from monitors.load import compile_spec

    from .notify import Notifier
    from .pipeline import project_for

    notifier = Notifier(unset_environment=True)
    stop_requested = threading.Event()
    node: SupervisorNode | None = None

    def on_signal(signum: int, _frame: Any) -> None:
        stop_requested.set()
        if node is not None:
            node.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    project = project_for(config)
    if not project.ok:
        err = project.first_error()
        assert err is not None
        raise err
    cfg = project.config
    path = log_path or cfg.log_path
    if not path:
        raise UserError(
            "no violation log configured", file=config, hint="set logging.violations or --log"
        )
    # rclpy writes its own log files; under ProtectSystem=strict only a few places
    # are writable.
    if not os.environ.get("ROS_LOG_DIR"):
        os.environ["ROS_LOG_DIR"] = os.environ.get("LOGS_DIRECTORY") or tempfile.mkdtemp(
            prefix="safety-supervisor-ros-log-"
        )
    with contextlib.ExitStack() as stack:
        log = stack.enter_context(ViolationLog(path, cfg.component, cfg.sha256))
        log.supervisor("start", config=str(config), pid=os.getpid())
        if build_dir is None:
            build_dir = stack.enter_context(
                tempfile.TemporaryDirectory(prefix="safety-supervisor-run-")
            )
        monitor = compile_spec(project.spec(), Path(build_dir))
        runtime = build_runtime(project, monitor)
        ctx = init_ros()
        stack.callback(_shutdown_ros, ctx)
        node = SupervisorNode(project, runtime, log, context=ctx)
        stack.callback(node.close)
        if stop_requested.is_set():
            node.stop()
        n_req = len(node.requirements)
        log.supervisor("ready", requirements=n_req, inputs=len(cfg.inputs), policy=cfg.step.policy)
        notifier.ready(status=f"monitoring {n_req} requirements on {len(cfg.inputs)} inputs")
        last_status = time.monotonic()

        def status() -> None:
            nonlocal last_status
            now = time.monotonic()
            if now - last_status >= 1.0:
                last_status = now
                stale = runtime.stale_inputs()
                notifier.status(
                    f"ticks={runtime.tick} violations={node.violations} "
                    f"stale={','.join(stale) if stale else 'none'}"
                )

        node.run(on_idle=status if notifier.enabled else None)
        notifier.stopping(status="stopping")
        log.supervisor("stop", ticks=runtime.tick, violations=node.violations)
    notifier.close()
    return 0


def _shutdown_ros(ctx: Context) -> None:
    with contextlib.suppress(Exception):
        rclpy.shutdown(context=ctx)
