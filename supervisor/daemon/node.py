"""The rclpy side of the daemon: subscriptions -> Core -> policies -> actions.

Everything ROS-independent (latest values, step policies, stale inputs, policy
timers, records) lives in :mod:`supervisor.daemon.core` and the runtime under it;
:class:`SupervisorNode` composes the parts that move messages in and effects out,
one module per job, each talking to the :class:`~supervisor.daemon.core.Core` only:

- ``receive.py``: the wait-set receive loop (take -> read -> core -> flush);
- ``graph.py``: the inputs' subscriptions, publishers and QoS in the graph;
- ``interfaces.py``: the daemon's own topics (violations, heartbeat, status,
  ``/diagnostics``) and the reset service (docs/reference/ros-interfaces.md);
- ``resets.py``: operator resets and the control socket's requests;
- ``reload.py``: reload and log reopen requests; the swap itself is here;
- ``loss.py``: lost-message reports.

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

import json
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from rclpy.context import Context
from rclpy.node import Node

from mitigations.actions import PublisherKey, build_action
from mitigations.actions.base import Outcome
from mitigations.actions.publish import PublishAction
from mitigations.engine import Engine, Request
from mitigations.violationlog.format import json_safe
from mitigations.violationlog.writer import ViolationLog
from supervisor.config import Config
from supervisor.daemon import heap
from supervisor.daemon.control import ControlServer
from supervisor.daemon.core import Core, warn
from supervisor.daemon.graph import InputGraph, never
from supervisor.daemon.interfaces import Interfaces
from supervisor.daemon.loss import LossReports, OwnWrites, RecordingPublisher, stop_stats
from supervisor.daemon.notify import Notifier
from supervisor.daemon.receive import Receiver
from supervisor.daemon.reload import Reloader, keep_policies
from supervisor.daemon.resets import Resets
from supervisor.daemon.session import Session
from supervisor.daemon.status import StatusBoard, status_answer

if TYPE_CHECKING:  # rosbags loads only when recording is on
    from supervisor.daemon.recorder import Recorder

MAX_WAIT_NS = 100_000_000  # the loop checks its flags at least this often
STATUS_EVERY_NS = 1_000_000_000


def _said_by_its_record(_text: str) -> None:
    """The daemon's core and loss reports warn with a record each, which the log
    echoes on stderr or sends to the journal (docs/reference/log.md): a print as
    well would say every warning twice.  (``replay`` keeps the core's warnings.)"""


class SupervisorNode:
    """One rclpy node feeding a Session through its Core; :meth:`run` is the receive loop."""

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
        self.log = log
        # run --record: every input message as received, the log's records and the
        # core's markers, into rosbag2 bags (docs/reference/config.md, record).
        self.recorder = recorder
        self.notifier = notifier or Notifier()
        self.watchdog_ns = int(watchdog_s * 1e9) if watchdog_s else None
        self._stop = threading.Event()
        self.reloads = 0
        self._done: list[tuple[Request, str, Outcome]] = []  # engine -> loop
        self._done_lock = threading.Lock()
        self._own = OwnWrites()  # what our mitigation publishers wrote

        cfg = session.config
        # The daemon's own topics and service are named relative to its namespace
        # (ros.namespace): in the default one they are the absolute names, and
        # supervisors of several robots on one graph stay apart.
        self.node = Node(cfg.ros.node_name, namespace=cfg.ros.namespace, context=context)
        self.inputs = InputGraph(self.node, log, recorder)
        self.inputs.subscribe(cfg)
        self.interfaces = Interfaces(self.node, log, self._own, cfg)
        # Operator resets: the socket thread hands requests to this loop.
        self.control = control
        self._wake = self.node.create_guard_condition(never)
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
            published=self.interfaces.unpublished.append,
            marker=self._marker if recorder is not None else None,
            warn=_said_by_its_record,
        )
        self.reloader = Reloader(
            self.core,
            log,
            self.notifier,
            prepare=reload,
            poke=self._poke,
            swap=self._swap,
            status_line=self.status_line,
        )
        self.resets = Resets(
            self.core, log, control, self.reloader.asked, status=self._status_answer
        )
        self.loss = LossReports(log, _said_by_its_record)
        self.receiver = Receiver(self.core, log, self.inputs, self._own, self.interfaces, recorder)
        # Each record also goes to the status topic's feed, and to the recording.
        self.status = StatusBoard(cfg.ros.node_name, self.node.get_namespace())
        log.tee = self._tee

    @property
    def session(self) -> Session:
        """The session in force (the core's: a reload swaps it there)."""
        return self.core.session

    # ------------------------------------------------------------ building

    def _tee(self, line: str) -> None:
        self.status.record(line)
        if self.recorder is not None:
            self.recorder.record(time.monotonic_ns(), line)

    def _publish_status(self, now: int) -> None:
        doc = self.status.document(
            self.core,
            now_ns=now,
            reloads=self.reloads,
            recording=self.recorder is not None,
            watchdog_s=self.watchdog_ns / 1e9 if self.watchdog_ns else None,
            control_socket=self.control.path if self.control is not None else None,
        )
        # Whether operators can reset: the socket thread's health and counts.
        doc["control"] = self.control.health() if self.control is not None else None
        # A page tells a dead supervisor from a slow one by this (ros-interfaces.md, Status).
        doc["status_period_s"] = self.session.config.ros.status_ms / 1000
        self.interfaces.publish_status(doc)

    def _status_answer(self) -> dict[str, Any]:
        """What ``safety-supervisor status`` shows: the status document without its
        event feed (left for the status topic), flat and small."""
        doc = self.status.document(
            self.core,
            now_ns=time.monotonic_ns(),
            reloads=self.reloads,
            recording=self.recorder is not None,
            watchdog_s=self.watchdog_ns / 1e9 if self.watchdog_ns else None,
            control_socket=self.control.path if self.control is not None else None,
            peek=True,
        )
        return status_answer(doc, self.status.started_wall, time.time())

    def _marker(self, what: str, t: int, fields: dict[str, Any]) -> None:
        assert self.recorder is not None
        record = {"event": "marker", "what": what, **fields}
        self.recorder.record(t, json.dumps(json_safe(record), sort_keys=True))

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
        self.reloader.request(prepare)

    def request_reopen(self) -> None:
        """Reopen the violation log (logrotate); safe from a signal handler."""
        self.reloader.request_reopen()

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
        destroyed (:meth:`Receiver.serve`).  The inputs' readers go first, so a robot's
        flood stops arriving; rclpy then destroys the rest and the participant."""
        self.inputs.destroy()
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
        while not self._stop.is_set() and self.node.context.ok():
            self.receiver.rebuild = False
            self.receiver.serve(
                self.node.context,
                self._wake,
                self._stop,
                reset_service=self._reset_service,
                deadline=self._deadline,
                timed_work=self._timed_work,
                serve_reset=self._serve_reset,
                trigger=self.session.config.step.trigger,
            )

    def _reset_service(self) -> Any:
        """The reset service as the config in force wants it (None: off)."""
        self.interfaces.sync_reset_service(self.session.config)
        return self.interfaces.reset_service

    def _serve_reset(self, srv: Any) -> None:
        def reset() -> tuple[bool, str]:
            ok, message, _ = self.resets.operator_reset(via="ros_service", caller=None)
            return ok, message

        self.interfaces.serve_reset(srv, reset)

    def _deadline(self, now: int) -> int:
        d = min(now + MAX_WAIT_NS, *self._next.values())
        due = self.core.next_due(now)
        return d if due is None else min(d, due)

    def _timed_work(self, now: int) -> None:
        self.core.advance(now)  # steps, stale inputs, policy deadlines: each at its time
        if self.interfaces.unpublished:
            self.interfaces.publish_reports()
        if self._done:
            self._outcomes()
        self.resets.work(now)
        nxt = self._next
        ros = self.session.config.ros
        if now >= nxt["heartbeat"]:
            self.interfaces.beat()
            nxt["heartbeat"] = now + int(ros.heartbeat_ms * 1e6)
        if ros.status_ms and now >= nxt.get("status_topic", now):
            self._publish_status(now)
            nxt["status_topic"] = now + int(ros.status_ms * 1e6)
        if now >= nxt["diagnostics"]:
            if self.inputs.check():
                self.receiver.rebuild = True  # the wait set must hold the new handle
            self.inputs.destroy_retired()
            self.interfaces.publish_diagnostics(self.core, self.inputs, self.loss, now)
            nxt["diagnostics"] = now + int(ros.diagnostics_ms * 1e6)
        if self.watchdog_ns and now >= nxt.get("watchdog", now):
            if self._ticking(now) and self.resets.serving():
                self.notifier.watchdog()
                nxt["watchdog"] = now + self.watchdog_ns
        if now >= nxt["status"]:
            nxt["status"] = now + STATUS_EVERY_NS
            self.loss.report(
                self.core.input_stats(),
                ((v.name, s.var.topic, s.streams) for s, v in self.inputs.inputs()),
            )
            if self.notifier.enabled:
                head = self.reloader.headline(now)
                line = self.status_line()
                self.notifier.status(f"{head} | {line}" if head else line)
        self.reloader.step()

    def _ticking(self, now: int) -> bool:
        """Ticks flow as configured: a periodic monitor is not behind its timer
        by more than a watchdog interval (event-driven policies step inside
        this loop, so the loop running is the evidence)."""
        due = self.core.step_due(now)
        if self.session.config.step.policy != "periodic" or due is None:
            return True
        assert self.watchdog_ns is not None
        return now - due < self.watchdog_ns

    def status_line(self) -> str:
        core = self.core
        stale = core.stale_inputs()
        missing = core.missing_inputs()
        latched = [self.session.requirements[i].id for i in core.supervision.latched()]
        parts = [
            f"ticks={core.tick}",
            f"violations={core.violations}",
            f"stale={','.join(stale) if stale else 'none'}",
        ]
        stats = core.input_stats()
        parts.append(f"received={sum(st['messages'] + st['rejected'] for st in stats.values())}")
        lost = {n: st["lost"] for n, st in stats.items() if st["lost"]}
        parts.append("lost=" + (",".join(f"{n}:{c}" for n, c in lost.items()) or "0"))
        if missing:
            parts.append(f"waiting_for={','.join(missing)}")
        if latched:
            parts.append(f"latched={','.join(sorted(latched))}")
        if not self.resets.serving():
            parts.append("control=down")
        return " ".join(parts)

    def stop_stats(self) -> dict[str, dict[str, Any]]:
        """Per input, for the ``stop`` record (:func:`supervisor.daemon.loss.stop_stats`)."""
        streams = {v.name: s.streams for s, v in self.inputs.inputs()}
        return stop_stats(self.core.input_stats(), streams)

    def _outcomes(self) -> None:
        # A failed attempt's warning is its mitigation record (ok false), which the
        # log echoes on stderr: the outcomes need nothing more of the loop.
        with self._done_lock:
            self._done.clear()

    # ------------------------------------------------------------ reload

    def _swap(self, new: Session, how: dict[str, Any]) -> None:
        """Put ``new`` in force between two loop turns: subscriptions and mitigation
        publishers that did not change are kept, and so are the policies of
        requirements that did not (reload.keep_policies: a latch stays latched)."""
        old = self.session
        self.inputs.subscribe(new.config)
        old_engine = self.engine
        kept = keep_policies(old, new)
        self.engine = self._make_engine(new.config)
        self.core.swap(new)  # takes over the inputs; kept policies go on where they were
        self.log.config_sha256 = new.config.sha256
        self.log.retry_buffer = new.config.log_retry_buffer
        self.log.durability = new.config.log_durability
        self.reloads += 1
        self.receiver.rebuild = True
        threading.Thread(target=old_engine.close, name="old-engine", daemon=True).start()
        if old.cleanup is not None:
            old.cleanup()
        heap.settle()  # the old session collected here, not on the halt's path
        n = len(new.requirements)
        self.log.supervisor(
            "reload",
            ok=True,
            config=new.config.path,
            kept_state=kept,
            requirements=n,
            inputs=len(new.config.inputs),
            policy=new.config.step.policy,
            tick=self.core.tick,  # the first tick judged by the new monitor
            **new.config.log_fields(),
            **how,
        )
        if new.config.ros.status_ms:  # the status topic names the new config at once
            self._publish_status(time.monotonic_ns())
        self.notifier.ready(status=f"reloaded: monitoring {n} requirements | {self.status_line()}")
