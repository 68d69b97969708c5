"""``safety-supervisor reset``: the operator's reset, from a shell on the robot.

Calls the running daemon's ``/safety_supervisor/reset`` (std_srvs/Trigger),
the same service a dashboard button would call.  The daemon resets every
requirement's monitor and lifts latched mitigations of requirements that
hold again; it refuses (and says which) for those still violated.
"""

from __future__ import annotations

import argparse
import time

from monitors.errors import UserError
from supervisor.names import RESET_SERVICE


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "reset", help="operator reset of the running supervisor (lifts latched mitigations)"
    )
    r.add_argument(
        "--timeout", type=float, default=10.0, help="seconds to find the service (default 10)"
    )


def cmd_reset(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from std_srvs.srv import Trigger

    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node("safety_supervisor_reset", context=ctx)
        client = node.create_client(Trigger, RESET_SERVICE)
        if not client.wait_for_service(timeout_sec=args.timeout):
            raise UserError(
                f"no service within {args.timeout:g} s",
                file=RESET_SERVICE,
                hint="is the supervisor running, with the same ROS_DOMAIN_ID?",
            )
        future = client.call_async(Trigger.Request())
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        deadline = time.monotonic() + args.timeout
        while not future.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if not future.done():
            raise UserError(f"no answer within {args.timeout:g} s", file=RESET_SERVICE)
        response = future.result()
        print(response.message, flush=True)
        executor.shutdown()
        node.destroy_node()
        return 0 if response.success else 1
    finally:
        rclpy.shutdown(context=ctx)
