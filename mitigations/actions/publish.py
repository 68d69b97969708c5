"""``publish`` mitigations: a message of any installed type on a topic.

Default QoS is reliable + transient_local (depth 1): a controller that starts,
or restarts, after the violation still receives the latched halt.  The message
is built and serialized once, at start (``check`` has already validated type and
fields), so publishing costs one rclpy call on those bytes (no Python message
converted to C and then to CDR on every halt), made inline on the monitoring loop right after the
violation record is written (``inline``: no thread handoff before the halt; whether
the record's fsync comes before is ``logging.durability``, docs/reference/log.md).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from mitigations.actions.base import Outcome
from mitigations.rosmsg import build_message, message_class
from mitigations.settings import PublishSettings

QOS = {
    # name: (reliability, durability)
    "latched": (ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL),
    "reliable": (ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE),
    "best_effort": (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE),
}


def qos_profile(name: str) -> QoSProfile:
    reliability, durability = QOS[name]
    return QoSProfile(depth=1, reliability=reliability, durability=durability)


class PublishAction:
    kind = "publish"
    inline = True  # microseconds: the engine runs it in the loop, no thread handoff

    def __init__(
        self, node: Node, name: str, settings: PublishSettings, reuse: PublishAction | None = None
    ) -> None:
        """``reuse``: an action on the same topic, type and QoS (from before a
        config reload) whose publisher is kept, so what it latched stays latched."""
        self.name = name
        self.topic = settings.topic
        klass = message_class(settings.msg)
        self.message: Any = build_message(klass, settings.value, f"mitigation '{name}' value")
        # What goes on the wire, made once: rclpy publishes bytes as they are
        # (rcl_publish_serialized_message), the CDR its publish(message) would make.
        self.payload: bytes = serialize_message(self.message)
        if reuse is not None:
            self.publisher = reuse.publisher
        else:
            self.publisher = node.create_publisher(klass, self.topic, qos_profile(settings.qos))

    def run(self, cancel: threading.Event, on_attempt: Callable[[Outcome], None]) -> Outcome:
        try:
            self.publisher.publish(self.payload)
            out = Outcome(ok=True, detail={"topic": self.topic})
        except Exception as e:  # noqa: BLE001 - e.g. the context is shutting down
            out = Outcome(ok=False, error=f"publish on {self.topic}: {type(e).__name__}: {e}")
        on_attempt(out)
        return out
