"""Subscription QoS for an input: the configured preset, or one that matches the publishers.

``auto`` inputs take the weakest QoS any current publisher offers, so a
best-effort sensor driver is still heard; the node resubscribes when a
publisher appears later (docs/reference/config.md, ``qos``).
"""

from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from supervisor.config import Variable


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
    return matching_qos(depth, [p.qos_profile for p in pubs]), None


def matching_qos(depth: int, offered: list[QoSProfile]) -> QoSProfile:
    # A reliable reader does not match a best-effort writer; a transient-local
    # reader does not match a volatile writer: take the weakest offered.
    best_effort = any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered)
    transient = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE,
    )


def graph_type_name(msg: str) -> str:
    """``std_msgs/msg/Int64`` as the graph reports it."""
    parts = msg.split("/")
    return msg if len(parts) == 3 else f"{parts[0]}/msg/{parts[-1]}"
