"""The publish action over real DDS: what a subscriber receives is the configured
message, sent as the bytes made when the action was built (mitigations/actions/publish.py)."""

from __future__ import annotations

import threading
from typing import Any

import pytest
from rosutil import ros_node, spin_until

from mitigations.actions.base import Outcome
from mitigations.actions.publish import PublishAction, qos_profile
from mitigations.settings import PublishSettings

pytestmark = pytest.mark.ros

TWIST = PublishSettings(
    topic="/test_publish_action/cmd_vel",
    msg="geometry_msgs/msg/Twist",
    value={"linear": {"x": 0.25}, "angular": {"z": -1.5}},
)


def _published(action: PublishAction, node: Any, *, raw: bool) -> tuple[Outcome, list[Any]]:
    """Run ``action`` once a subscriber matches; the outcome and what arrived."""
    from geometry_msgs.msg import Twist

    got: list[Any] = []
    node.create_subscription(Twist, TWIST.topic, got.append, qos_profile(TWIST.qos), raw=raw)
    spin_until(
        node, "the subscriber to match", lambda: action.publisher.get_subscription_count(), 15
    )
    attempts: list[Outcome] = []
    out = action.run(threading.Event(), attempts.append)
    assert attempts == [out]
    spin_until(node, "the halt to arrive", lambda: got, 15)
    return out, got


def test_the_subscriber_receives_the_configured_message() -> None:
    with ros_node("test_publish_action") as node:
        action = PublishAction(node, "zero_cmd_vel", TWIST)
        out, got = _published(action, node, raw=False)
    assert out.ok and out.detail == {"topic": TWIST.topic}
    (msg,) = got
    assert (msg.linear.x, msg.linear.y, msg.angular.z) == (0.25, 0.0, -1.5)


def test_the_bytes_on_the_wire_are_made_once_when_the_action_is_built() -> None:
    from rclpy.serialization import serialize_message

    with ros_node("test_publish_action_raw") as node:
        action = PublishAction(node, "zero_cmd_vel", TWIST)
        # The CDR rclpy makes of the configured message, and nothing made per run:
        # a change of the message object after the build does not reach the wire.
        assert action.payload == serialize_message(action.message)
        action.message.linear.x = 99.0
        out, got = _published(action, node, raw=True)
    assert out.ok
    assert got == [action.payload]
