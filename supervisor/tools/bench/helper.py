"""What every bench helper process shares: JSON lines to the bench, the stop flag,
the spec's topics, QoS, an rclpy node, and the wait-set loop.

The wait-set loop uses the same private rclpy API as the daemon's receive loop
(``supervisor/daemon/receive.py``) but is written out here on purpose: a baseline
that imported the daemon's code would not be a baseline.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from supervisor.tools.bench.plan import DEPTH

REPORT_EVERY_NS = 100_000_000  # receivers print their counts this often

stop_requested = threading.Event()  # SIGTERM, or the bench went away


def emit(**obj: Any) -> None:
    try:
        print(json.dumps(obj), flush=True)
    except (BrokenPipeError, ValueError):
        stop_requested.set()  # the bench is gone


def on_term(_signum: int, _frame: Any) -> None:
    stop_requested.set()


# ------------------------------------------------------------------ topics


@dataclass
class Topic:
    name: str  # the config's variable name
    topic: str
    msg: str  # package/msg/Name
    field: str  # dotted path of the value
    klass: type
    leaf: str  # ROS type of the field

    def message(self, value: Any) -> Any:
        """A message whose ``field`` holds ``value`` (other fields default)."""
        from mitigations.rosmsg import build_message

        if self.leaf == "boolean":
            value = bool(value)
        elif "float" in self.leaf or self.leaf == "double":
            value = float(value)
        else:
            value = int(value)
        nested: Any = value
        for part in reversed(self.field.split(".")):
            nested = {part: nested}
        return build_message(self.klass, nested, f"bench value of {self.name}")


def load_topics(spec: str) -> list[Topic]:
    from mitigations.rosmsg import field_type, message_class

    out = []
    for t in json.loads(spec):
        klass = message_class(t["msg"])
        out.append(
            Topic(t["name"], t["topic"], t["msg"], t["field"], klass, field_type(klass, t["field"]))
        )
    return out


def reliable(durability: str = "volatile", depth: int = DEPTH) -> Any:
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


@contextlib.contextmanager
def ros_node(name: str, *, as_daemon: bool = False) -> Iterator[Any]:
    """A node in its own context.  ``as_daemon``: on the daemon's DDS transport (UDP
    only unless the environment chooses; supervisor/daemon/transport.py), so a
    baseline standing in for the daemon is reached the way the daemon is."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    from supervisor.daemon.transport import udp_only

    ctx = Context()
    with udp_only() if as_daemon else contextlib.nullcontext():
        rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        node = Node(name, context=ctx)
    try:
        yield node
    finally:
        with contextlib.suppress(Exception):
            node.destroy_node()
        with contextlib.suppress(Exception):
            rclpy.shutdown(context=ctx)


def never(*_args: Any) -> None:
    """Callback of subscriptions served by a wait-set loop (never called)."""


class WaitLoop:
    """Subscriptions (and at most one service and one client) served by one rclpy
    wait set, as the daemon's loop does."""

    def __init__(
        self, node: Any, subs: list[tuple[Any, type]], *, service: Any = None, client: Any = None
    ) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        self.node = node
        self.subs = subs
        self.service, self.client = service, client
        self._stack = contextlib.ExitStack()
        ctx = node.context
        for sub, _klass in subs:
            self._stack.enter_context(sub.handle)
        for extra in (service, client):
            if extra is not None:
                self._stack.enter_context(extra.handle)
        self._stack.enter_context(ctx.handle)
        self.by_ptr = {sub.handle.pointer: i for i, (sub, _k) in enumerate(subs)}
        self.ws = _rclpy.WaitSet(
            len(subs), 0, 0, int(client is not None), int(service is not None), 0, ctx.handle
        )
        self.service_ready = self.client_ready = False

    def wait(self, timeout_ns: int) -> list[int]:
        """Indices of the subscriptions with messages (after at most ``timeout_ns``);
        ``service_ready`` / ``client_ready`` say whether a request / response came."""
        ws = self.ws
        ws.clear_entities()
        for sub, _klass in self.subs:
            ws.add_subscription(sub.handle)
        if self.service is not None:
            ws.add_service(self.service.handle)
        if self.client is not None:
            ws.add_client(self.client.handle)
        ws.wait(max(0, timeout_ns))
        self.service_ready = bool(self.service and ws.get_ready_entities("service"))
        self.client_ready = bool(self.client and ws.get_ready_entities("client"))
        return [self.by_ptr[p] for p in ws.get_ready_entities("subscription")]

    def take(self, i: int) -> Any:
        """The next message of subscription ``i``, or None."""
        sub, klass = self.subs[i]
        info = sub.handle.take_message(klass, False)
        return None if info is None else info[0]

    def close(self) -> None:
        self._stack.close()


def publishers_seen(node: Any, topics: list[Topic], publisher_node: str) -> bool:
    """Every topic has a publisher of node ``publisher_node`` in this node's graph."""
    for t in topics:
        infos = node.get_publishers_info_by_topic(t.topic)
        if not any(i.node_name == publisher_node for i in infos):
            return False
    return True
