"""The latency experiment's bare-DDS baseline: keeps the latest value of every topic
and, when the trigger arrives in the violating state, publishes the halt the daemon
would publish; it answers the driver's handshake on a service named like the daemon's."""

from __future__ import annotations

import argparse
from typing import Any

from supervisor.tools.bench.helper import (
    Topic,
    WaitLoop,
    emit,
    never,
    reliable,
    ros_node,
    stop_requested,
)


def run_echo(args: argparse.Namespace, topics: list[Topic]) -> None:
    from rclpy.serialization import serialize_message

    from mitigations.rosmsg import get_field, message_class

    # The floor the halt is judged against: reached over the daemon's transport.
    with ros_node("bench_echo", as_daemon=True) as node:
        halt_class = message_class(args.halt_msg)
        halt = node.create_publisher(
            halt_class, args.halt_topic, reliable("transient_local", depth=1)
        )
        # Published as bytes made once, as the daemon's publish action does: the
        # floor and the daemon send the halt the same way.
        halt_msg = serialize_message(halt_class(data=True))
        subs = [(node.create_subscription(t.klass, t.topic, never, reliable()), t.klass) for t in topics]  # fmt: skip
        from std_srvs.srv import Trigger

        # The daemon's reset service, as a ping: the driver's handshake (below).
        srv = node.create_service(Trigger, args.sync_service, never)
        loop = WaitLoop(node, subs, service=srv)
        names = [t.name for t in topics]
        fields = [t.field for t in topics]
        trigger = names.index(args.trigger)
        when_name, when_value = args.when.split("=", 1)
        when = names.index(when_name)
        latest: list[Any] = [None] * len(topics)
        want = int(when_value)
        emit(event="started")
        try:
            while not stop_requested.is_set():
                for i in loop.wait(100_000_000):
                    while (msg := loop.take(i)) is not None:
                        latest[i] = get_field(msg, fields[i])
                        if i == trigger and latest[when] == want:
                            halt.publish(halt_msg)
                if loop.service_ready:
                    taken = srv.handle.service_take_request(Trigger.Request)
                    if taken is not None and taken[1] is not None:
                        # take gives rmw_service_info_t; the reply wants its request id
                        request_id = getattr(taken[1], "request_id", taken[1])
                        srv.handle.service_send_response(Trigger.Response(success=True), request_id)
        finally:
            loop.close()
