"""The daemon's own ROS interfaces: the violations, heartbeat, status and
``/diagnostics`` topics and the opt-in reset service (docs/reference/ros-interfaces.md).

Served by the receive loop's thread only (supervisor/daemon/receive.py); what
they say comes from the core (supervisor/daemon/core.py).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from mitigations.rosmsg import message_class
from mitigations.violationlog.format import json_safe
from mitigations.violationlog.writer import ViolationLog
from supervisor.config import Config
from supervisor.daemon.core import Core, warn
from supervisor.daemon.diagnostics import diagnostic_array, input_status, requirement_status
from supervisor.daemon.graph import InputGraph, never
from supervisor.daemon.loss import LossReports, OwnWrites, RecordingPublisher
from supervisor.names import (
    DIAGNOSTICS_TOPIC,
    HEARTBEAT_TOPIC,
    RESET_SERVICE,
    STATUS_TOPIC,
    VIOLATIONS_TOPIC,
)


class Interfaces:
    """The publishers and the reset service of ``node``, created in this order."""

    def __init__(self, node: Node, log: ViolationLog, own_writes: OwnWrites, cfg: Config) -> None:
        self.node = node
        self.log = log
        self.publisher = node.create_publisher(
            _msg("std_msgs/msg/String"), own(VIOLATIONS_TOPIC), 10
        )
        self.heartbeat = node.create_publisher(_msg("std_msgs/msg/UInt64"), own(HEARTBEAT_TOPIC), 1)
        # Latched (transient local, depth 1): a page that starts late has the latest.
        self.status_publisher = node.create_publisher(
            _msg("std_msgs/msg/String"),
            own(STATUS_TOPIC),
            QoSProfile(
                depth=1,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
            ),
        )
        self.diagnostics = node.create_publisher(
            _msg("diagnostic_msgs/msg/DiagnosticArray"), DIAGNOSTICS_TOPIC, 10
        )
        # A config may read /diagnostics (or any of our topics) as an input: our own
        # writes are remembered and never taken for the robot's (loss.py).
        self.publisher, self.heartbeat, self.status_publisher, self.diagnostics = (
            RecordingPublisher(p, p.topic_name, own_writes)
            for p in (self.publisher, self.heartbeat, self.status_publisher, self.diagnostics)
        )
        # Violation records written and not yet on the violations topic (Core's
        # ``published``); emptied in place, as the core holds its append.
        self.unpublished: list[dict[str, Any]] = []
        self.heartbeats = 0
        from std_srvs.srv import Trigger

        self._trigger = Trigger
        # Opt-in (ros.reset_service): a Trigger carries no credentials; the
        # control socket is the authenticated way (docs/reference/ros-interfaces.md).
        self.reset_service: Any = None
        self.sync_reset_service(cfg)

    # ------------------------------------------------------------ topics

    def publish_reports(self) -> None:
        """Each violation record written since the last call, on the violations topic."""
        records = self.unpublished[:]
        self.unpublished.clear()
        for record in records:
            msg = _msg("std_msgs/msg/String")()
            msg.data = json.dumps(json_safe({"event": "violation", **record}))
            try:
                self.publisher.publish(msg)
            except Exception as e:  # noqa: BLE001 - e.g. the context is shutting down
                warn(f"cannot publish on {VIOLATIONS_TOPIC}: {e}")

    def beat(self) -> None:
        """One more heartbeat: its count, from 1."""
        self.heartbeats += 1
        self.heartbeat.publish(_msg("std_msgs/msg/UInt64")(data=self.heartbeats))

    def publish_status(self, doc: dict[str, Any]) -> None:
        msg = _msg("std_msgs/msg/String")()
        msg.data = json.dumps(doc)
        try:
            self.status_publisher.publish(msg)
        except Exception as e:  # noqa: BLE001 - shutdown race
            warn(f"cannot publish {STATUS_TOPIC}: {e}")

    def publish_diagnostics(
        self, core: Core, inputs: InputGraph, loss: LossReports, now: int
    ) -> None:
        """Each requirement's policy state and each input's counts and graph problems."""
        s = core.session
        cfg = s.config
        name = cfg.ros.node_name
        stats = core.input_stats()
        statuses = []
        for i, req in enumerate(s.requirements):
            pol = s.policies[i]
            statuses.append(
                requirement_status(name, cfg.component, req.id, pol.state(), not pol.holds)
            )
        for sub, v in inputs.inputs():
            st = dict(stats[v.name])
            st["problem"], st["publishers"] = sub.problem, sub.publishers
            st["lost_recent"] = loss.since_diagnostics(v.name, st["lost"])
            st["by_publisher"] = sub.streams.by_publisher() if sub.streams else []
            statuses.append(input_status(name, cfg.component, v.name, sub.var.topic or "", st, now))
        stamp = self.node.get_clock().now().to_msg()
        try:
            self.diagnostics.publish(diagnostic_array(stamp, statuses))
        except Exception as e:  # noqa: BLE001 - shutdown race
            warn(f"cannot publish /diagnostics: {e}")

    # ------------------------------------------------------------ reset service

    def sync_reset_service(self, cfg: Config) -> None:
        """The ROS reset service exists iff ``ros.reset_service`` (also after a reload)."""
        if cfg.ros.reset_service and self.reset_service is None:
            self.reset_service = self.node.create_service(self._trigger, own(RESET_SERVICE), never)
            self.log.supervisor("reset_service", enabled=True, service=RESET_SERVICE)
        elif not cfg.ros.reset_service and self.reset_service is not None:
            self.node.destroy_service(self.reset_service)
            self.reset_service = None
            self.log.supervisor("reset_service", enabled=False, service=RESET_SERVICE)

    def serve_reset(self, srv: Any, reset: Callable[[], tuple[bool, str]]) -> None:
        """Answer one request of the reset service (``srv``, its handle) with ``reset()``."""
        taken = srv.service_take_request(self._trigger.Request)
        if taken is None:
            return
        request, header = taken
        if header is None:
            return
        ok, message = reset()
        # take_request gives rmw_service_info_t; the reply wants its request id.
        request_id = getattr(header, "request_id", header)
        try:
            srv.service_send_response(
                self._trigger.Response(success=ok, message=message), request_id
            )
        except Exception as e:  # noqa: BLE001 - the caller went away; the reset stands
            warn(f"cannot answer {RESET_SERVICE}: {e}")


def own(name: str) -> str:
    """One of the daemon's own names, relative to its namespace."""
    return name.lstrip("/")


_MSG_CACHE: dict[str, type] = {}


def _msg(name: str) -> type:
    klass = _MSG_CACHE.get(name)
    if klass is None:
        klass = _MSG_CACHE[name] = message_class(name)
    return klass
