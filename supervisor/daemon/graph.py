"""The inputs' subscriptions and what the ROS graph says of them.

One subscription per topic, kept across a reload when its topic, type and QoS
did not change; publishers that cannot reach the daemon (wrong type,
incompatible QoS) and topics without publishers are logged once each; an
``auto`` QoS subscription follows the publishers found
(docs/reference/ros-interfaces.md).  The receive loop (supervisor/daemon/receive.py)
takes messages from :attr:`InputGraph.subs`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rclpy.node import Node
from rclpy.qos import QoSCompatibility, QoSProfile, qos_check_compatible

from mitigations.rosmsg import message_class
from mitigations.violationlog.writer import ViolationLog
from supervisor.config import Config, Variable
from supervisor.daemon.core import warn
from supervisor.daemon.loss import SequenceStreams
from supervisor.daemon.qos import graph_type_name, matching_qos, qos_for
from supervisor.inputs.readers import make_reader, plain_field

if TYPE_CHECKING:  # rosbags loads only when recording is on
    from supervisor.daemon.recorder import Recorder

RAW_CHECKS = 3  # first messages of a topic read both ways when recording (receive.py)


@dataclass
class Sub:
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


class InputGraph:
    """The subscriptions of the current config's inputs, on ``node``."""

    def __init__(self, node: Node, log: ViolationLog, recorder: Recorder | None) -> None:
        self.node = node
        self.log = log
        self.recorder = recorder
        self.subs: list[Sub] = []
        self.retired: list[Any] = []  # subscriptions replaced by a QoS change

    def subscribe(self, cfg: Config) -> None:
        """Subscriptions for ``cfg``'s inputs, keeping those that did not change."""
        old = {(s.var.topic, s.var.msg, s.var.qos, s.var.depth): s for s in self.subs}
        subs: list[Sub] = []
        by_key: dict[tuple[Any, ...], Sub] = {}
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
            if warning:  # the record is the warning: the log echoes it on stderr
                self.log.supervisor("input_no_publisher", input=var.name, topic=var.topic)
            sub = self.node.create_subscription(klass, var.topic, never, qos)
            new = Sub(
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
        self.subs = subs
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
                    self.offer_qos(s, self.publishers(s))

    def inputs(self) -> list[tuple[Sub, Variable]]:
        """Each input variable with the subscription that feeds it."""
        return [(s, v) for s in self.subs for v in s.vars]

    def check(self) -> bool:
        """Publishers that cannot reach us (wrong type, incompatible QoS), topics
        without publishers; auto-QoS subscriptions follow the publishers found.
        True when a subscription was replaced: the loop's wait set must be rebuilt."""
        replaced = False
        for s in self.subs:
            topic = s.var.topic
            assert topic is not None
            try:
                pubs = self.node.get_publishers_info_by_topic(topic)
            except Exception as e:  # noqa: BLE001 - graph queries fail during shutdown
                warn(f"cannot query publishers of {topic}: {e}")
                return replaced
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
                            replaced = True
                            problem = None
                        else:
                            problem = f"incompatible QoS with {p.node_name} on {topic}: {reason}"
                        break
            if s.publishers is not None and not pubs and s.publishers:
                self.log.supervisor("input_publisher_gone", input=s.name, topic=topic)
            if s.publishers is not None and pubs and not s.publishers:
                self.log.supervisor("input_publisher_found", input=s.name, topic=topic)
            s.publishers = len(right)
            self.offer_qos(s, right)
            if problem != s.problem:
                if problem is not None and (pubs or s.problem is not None):
                    self.log.supervisor("input_problem", input=s.name, detail=problem)
                elif problem is None and s.problem is not None:
                    self.log.supervisor("input_problem_cleared", input=s.name, topic=topic)
                s.problem = problem
        return replaced

    def publishers(self, s: Sub) -> list[Any]:
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

    def offer_qos(self, s: Sub, pubs: list[Any]) -> None:
        """The recording writes the QoS the topic's publishers offer, as rosbag2 does,
        so that ``ros2 bag play`` of it keeps latching (docs/reference/config.md, record)."""
        if self.recorder is not None and s.recorded is not None:
            self.recorder.offered_qos(s.recorded, [p.qos_profile for p in pubs])
            s.offered = s.offered or bool(pubs)

    def _resubscribe(self, s: Sub, offered: list[QoSProfile]) -> None:
        qos = matching_qos(s.var.depth, offered)
        self.log.supervisor(
            "input_qos_changed",
            input=s.name,
            topic=s.var.topic,
            reliability=qos.reliability.name.lower(),
            durability=qos.durability.name.lower(),
        )
        old = s.sub
        s.sub = self.node.create_subscription(s.msg_type, s.var.topic, never, qos)
        self.retired.append(old)  # destroyed once the loop no longer holds its handle

    def destroy_retired(self) -> None:
        """The subscriptions a QoS change replaced.  A handle the loop's wait set
        still holds is destroyed by rclpy once the loop lets it go (its rebuild)."""
        for old in self.retired:
            with contextlib.suppress(Exception):
                self.node.destroy_subscription(old)
        self.retired = []

    def destroy(self) -> None:
        """Every subscription, so that a robot's flood stops arriving (faults.md, "Stop")."""
        for s in self.subs:
            self.node.destroy_subscription(s.sub)
        for old in self.retired:
            self.node.destroy_subscription(old)
        self.subs, self.retired = [], []


def never(*_args: Any) -> None:
    """Callback of entities the wait-set loop serves itself (never called)."""


def _field_plans(subs: list[Sub]) -> dict[int, list[Any]]:
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
