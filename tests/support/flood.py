"""A robot gone mad: the 7 srobot topics republished in a tight loop, for the stop
tests (tests/system/test_daemon_stop.py).  Nominal values (rosutil.S0), so the daemon
monitors without violations; runs until killed.  ``python tests/support/flood.py``
with the test run's ROS environment."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rosutil import S0, TOPICS  # noqa: E402


def main() -> None:
    stop = False

    def on_term(_signum: int, _frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    ctx = Context()
    domain = int(os.environ["ROS_DOMAIN_ID"])
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("flood", context=ctx)
    out = [(node.create_publisher(t, topic, 10), t(data=S0[name])) for name, topic, t in TOPICS]
    while not stop:
        for pub, msg in out:
            pub.publish(msg)
    node.destroy_node()
    rclpy.shutdown(context=ctx)


if __name__ == "__main__":
    main()
