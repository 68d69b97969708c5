"""The injector's own ROS node: publishers for the configured topics, waiting for
the supervisor to subscribe, and asking it for an operator reset."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any

# rclpy and the ROS message packages are imported where they are used: --dry-run
# computes and prints without ROS.
from mitigations.rosmsg import message_class
from monitors.errors import UserError
from monitors.verify.interpret import Value
from supervisor.names import client_control_socket
from supervisor.tools.inject.errors import InjectError
from supervisor.tools.inject.report import fmt_value
from supervisor.tools.inject.schedule import Topic
from supervisor.tools.reset import request


class RosOut:
    """Publishers for the configured topics, from a node of our own."""

    def __init__(self, cfg: Any, topics: list[Topic]) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        self.cfg = cfg
        self.ctx = Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("safety_supervisor_inject", context=self.ctx)
        # reliable + volatile: matches reliable and best-effort readers alike
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.topics = topics
        self.classes = {t.name: message_class(t.msg) for t in topics}
        self.pubs = {
            t.name: self.node.create_publisher(self.classes[t.name], t.name, qos) for t in topics
        }

    def close(self) -> None:
        import rclpy

        try:
            self.node.destroy_node()
        finally:
            rclpy.shutdown(context=self.ctx)

    def wait_for_supervisor(self, timeout: float) -> None:
        """Until the supervisor's node subscribes to every topic and each publisher is
        matched (DDS discovery takes ~3 s on localhost)."""
        name = self.cfg.ros.node_name.strip("/").split("/")[-1]
        deadline = time.monotonic() + timeout
        missing: list[str] = []
        while True:
            missing = []
            for t in self.topics:
                subs = self.node.get_subscriptions_info_by_topic(t.name)
                mine = any(s.node_name == name for s in subs)
                if not mine or self.pubs[t.name].get_subscription_count() < 1:
                    missing.append(t.name)
            if not missing:
                return
            if time.monotonic() > deadline:
                break
            time.sleep(0.05)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        raise InjectError(
            f"no supervisor is listening: node '{name}' has no subscription to "
            f"{', '.join(missing)} after {timeout:g} s (is it running, on ROS_DOMAIN_ID={domain}?)"
        )

    def message(self, topic: Topic, state: Mapping[str, Value]) -> Any:
        msg = self.classes[topic.name]()
        for var, path in topic.fields:
            try:
                set_field(msg, path, state[var])
            except (AssertionError, TypeError, ValueError) as e:
                raise InjectError(
                    f"{var} = {fmt_value(state[var])} cannot be set in {topic.msg}.{path}: {e}"
                ) from None
        return msg

    def publish(self, topic: Topic, state: Mapping[str, Value]) -> None:
        self.pubs[topic.name].publish(self.message(topic, state))


def set_field(msg: Any, path: str, value: Any) -> None:
    """Set a dotted field path ('twist.twist.linear.x') in a message."""
    *parents, leaf = path.split(".")
    for part in parents:
        msg = getattr(msg, part)
    current = getattr(msg, leaf)
    if isinstance(current, bool):
        value = bool(value)
    elif isinstance(current, int):
        value = int(value)
    elif isinstance(current, float):
        value = float(value)
    setattr(msg, leaf, value)


def request_reset(out: RosOut) -> str:
    """Ask the supervisor for an operator reset (judge every requirement afresh),
    through its control socket, as ``safety-supervisor reset`` does."""
    path = out.cfg.control.socket or client_control_socket()
    try:
        answer = request(path, {"command": "reset"}, 5.0)
    except UserError as e:
        return f"not done: {e}"
    return f"{'ok' if answer.get('ok') is True else 'refused'}: {answer.get('message', '')}"
