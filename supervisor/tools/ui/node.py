"""The UI's rclpy node: it only subscribes to the daemon's topics and feeds the hub.

Its own context and executor thread, so the HTTP threads never touch rclpy.
The QoS of each subscription matches what the daemon offers
(docs/reference/ros-interfaces.md, "The node" and "What the UI reads").  What
arrives is checked by the hub (:mod:`.schema`); the node names who published it
from the ROS graph, and watches that graph for a second publisher of the status
topic ("What the status topic can be trusted for").
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from supervisor.names import DIAGNOSTICS_TOPIC, STATUS_TOPIC, VIOLATIONS_TOPIC
from supervisor.tools.ui.fleet import Fleet, Robot, namespace_of, violations_topic
from supervisor.tools.ui.hub import Hub

NODE_NAME = "safety_supervisor_ui"


def own(name: str) -> str:
    """One of the daemon's own names, relative to the namespace (as the daemon has it)."""
    return name.lstrip("/")


GRAPH_S = 1.0  # how often the status topic's publishers are listed


def publishers(node: Any, topic: str) -> list[str]:
    """The nodes publishing ``topic`` (fully qualified names), from the ROS graph."""
    out = []
    for info in node.get_publishers_info_by_topic(topic):
        ns = info.node_namespace.rstrip("/")
        out.append(f"{ns}/{info.node_name}")
    return sorted(out)


def publisher_of(node: Any, topic: str) -> Callable[[], str]:
    """Who sent a message on ``topic``, as far as the graph tells: rclpy's message
    info has no publisher, so one publisher is named, several are listed."""

    def name() -> str:
        try:
            names = publishers(node, topic)
        except Exception:  # noqa: BLE001 - naming the sender must not lose the warning
            names = []
        if len(names) == 1:
            return names[0]
        if not names:
            return "a publisher no longer in the ROS graph"
        return "one of " + ", ".join(names)

    return name


class UiNode:
    """Starts rclpy in its own context; :meth:`close` stops it."""

    def __init__(self, hub: Hub, namespace: str = "/") -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        self._hub = hub
        self._ctx = Context()
        rclpy.init(context=self._ctx, signal_handler_options=SignalHandlerOptions.NO)
        # In the daemon's namespace (ros.namespace), its own topics are found by
        # their relative names, as the daemon names them; /diagnostics stays absolute.
        self.node = Node(NODE_NAME, namespace=namespace, context=self._ctx)
        self._status_topic = self.node.resolve_topic_name(own(STATUS_TOPIC))
        self._violations_topic = self.node.resolve_topic_name(own(VIOLATIONS_TOPIC))
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        # The status document is latched: a UI that starts late has the last one at once.
        self.node.create_subscription(String, own(STATUS_TOPIC), self._on_status, latched)
        # depth 100: a burst of violations is not cut short before the executor runs
        self.node.create_subscription(String, own(VIOLATIONS_TOPIC), self._on_violation, 100)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diag, 10)
        self._executor = SingleThreadedExecutor(context=self._ctx)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="ui-ros", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        next_graph = 0.0
        while not self._stop.is_set() and self._ctx.ok():
            if time.monotonic() >= next_graph:
                next_graph = time.monotonic() + GRAPH_S
                try:
                    self._hub.on_publishers(publishers(self.node, self._status_topic))
                except Exception as e:  # noqa: BLE001 - the graph query must not end the UI
                    print(f"safety-supervisor ui: WARNING: the ROS graph: {e}",
                          file=sys.stderr, flush=True)  # fmt: skip
            self._executor.spin_once(timeout_sec=0.1)

    def _on_status(self, msg: Any) -> None:
        self._hub.receive_status(msg.data, publisher_of(self.node, self._status_topic))

    def _on_violation(self, msg: Any) -> None:
        self._hub.receive_violation(msg.data, publisher_of(self.node, self._violations_topic))

    def _on_diag(self, msg: Any) -> None:
        statuses = []
        for s in msg.status:
            level = s.level if isinstance(s.level, int) else int.from_bytes(s.level, "little")
            statuses.append((s.name, level, s.message, {kv.key: kv.value for kv in s.values}))
        self._hub.on_diagnostics(statuses)

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self._thread.join(2.0)
        self._executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self._ctx)


DISCOVERY_S = 1.0  # how often each domain's graph is searched for status topics


class FleetNode:
    """The fleet's ROS side: one rclpy context, node and executor thread per DDS
    domain (a context is bound to one domain), each subscribing to its robots'
    status and violations and searching its graph for other supervisors.

    Subscriptions are created in the domain's own thread, between spins, so no
    two threads touch one executor.  /diagnostics is not read: every daemon of a
    domain publishes there, so it cannot be told which robot it is from."""

    def __init__(self, fleet: Fleet) -> None:
        self._fleet = fleet
        self._stop = threading.Event()
        self._domains = [_Domain(fleet, d, self._stop) for d in fleet.domains()]

    def close(self) -> None:
        self._stop.set()
        for d in self._domains:
            d.close()


class _Domain:
    def __init__(self, fleet: Fleet, domain: int, stop: threading.Event) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        self._fleet = fleet
        self.domain = domain
        self._stop = stop
        self._ctx = Context()
        rclpy.init(
            context=self._ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO
        )
        self.node = Node(NODE_NAME, context=self._ctx)
        self._executor = SingleThreadedExecutor(context=self._ctx)
        self._executor.add_node(self.node)
        self._watched: set[str] = set()
        for robot in fleet.robots():
            if robot.domain == domain:
                self._subscribe(robot)
        self._thread = threading.Thread(target=self._spin, name=f"ui-ros-{domain}", daemon=True)
        self._thread.start()

    def _subscribe(self, robot: Robot) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        if robot.topic in self._watched:
            return
        self._watched.add(robot.topic)
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )

        vtopic = violations_topic(robot.namespace)

        def on_status(msg: Any) -> None:
            self._fleet.receive_status(robot, msg.data, publisher_of(self.node, robot.topic))

        def on_violation(msg: Any) -> None:
            robot.hub.receive_violation(msg.data, publisher_of(self.node, vtopic))

        # as UiNode: the status latched, a burst of violations not cut short
        self.node.create_subscription(String, robot.topic, on_status, latched)
        self.node.create_subscription(String, vtopic, on_violation, 100)

    def _discover(self) -> None:
        for robot in self._fleet.robots():
            if robot.domain == self.domain and robot.topic in self._watched:
                self._fleet.on_publishers(robot, publishers(self.node, robot.topic))
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._watched or "std_msgs/msg/String" not in types:
                continue
            namespace = namespace_of(topic)
            if namespace is not None:
                robot, _new = self._fleet.watch(self.domain, namespace)
                self._subscribe(robot)

    def _spin(self) -> None:
        import time

        next_search = 0.0
        while not self._stop.is_set() and self._ctx.ok():
            if time.monotonic() >= next_search:
                next_search = time.monotonic() + DISCOVERY_S
                try:
                    self._discover()
                except Exception as e:  # noqa: BLE001 - the graph query must not end the UI
                    print(f"safety-supervisor ui: WARNING: domain {self.domain}: {e}",
                          file=sys.stderr, flush=True)  # fmt: skip
            self._executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        import rclpy

        self._thread.join(2.0)
        self._executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self._ctx)
