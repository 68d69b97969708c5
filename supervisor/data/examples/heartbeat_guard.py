"""A robot-side guard: stop the base when the safety supervisor's heartbeat stops.

The supervisor publishes ``/safety_supervisor/heartbeat`` (``std_msgs/msg/UInt64``, a
counter 1, 2, ... every ``ros.heartbeat_ms``, 100 ms by default) from its monitoring
loop.  This node listens to it and, while the heartbeat is not live, publishes a zero
``geometry_msgs/msg/Twist`` on the stop topic every check period.  Live means: the
last beat came within ``--timeout`` seconds on this node's own monotonic clock (never
ROS time, which ``/clock`` sets), and the last ``--rearm`` beats had strictly
increasing counters.  A repeated or decreasing counter is a restarted supervisor or a
second publisher: the guard stops and re-arms only after ``--rearm`` increasing beats.

It guards against a dead or hung supervisor, not a forged one: any node of the domain
can publish the topic (docs/reference/ros-interfaces.md, "The heartbeat contract").

Copy it into the robot's workspace, or run it from the installed package:

    python3 -m supervisor.data.examples.heartbeat_guard --stop-topic /cmd_vel

It needs rclpy, std_msgs and geometry_msgs only, nothing of the supervisor.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Sequence

HEARTBEAT_TOPIC = "/safety_supervisor/heartbeat"
PERIOD_S = 0.1  # the supervisor's ros.heartbeat_ms
TIMEOUT_S = 3 * PERIOD_S + 0.05  # three periods and a margin for DDS and scheduling
REARM = 3  # increasing beats in a row before the guard lets the base move again


class Watch:
    """The guard's decision, without ROS: fed beats and asked at times of one
    monotonic clock (seconds)."""

    def __init__(self, timeout_s: float, rearm: int) -> None:
        self.timeout_s = timeout_s
        self.rearm = rearm
        self.last_count: int | None = None
        self.last_beat: float | None = None
        self.streak = 0  # beats in a row with a strictly increasing counter

    def beat(self, count: int, now: float) -> str | None:
        """Take one beat; why it does not count (a repeated or decreasing counter)."""
        previous, self.last_count = self.last_count, count
        if previous is not None and count <= previous:
            self.streak = 0
            return f"counter went from {previous} to {count}: a restart or a second publisher"
        self.streak += 1
        self.last_beat = now
        return None

    def silence(self, now: float) -> float | None:
        """Seconds since the last counted beat (None: never one)."""
        return None if self.last_beat is None else now - self.last_beat

    def live(self, now: float) -> bool:
        quiet = self.silence(now)
        return quiet is not None and quiet <= self.timeout_s and self.streak >= self.rearm


def say(text: str) -> None:
    print(f"heartbeat_guard: {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import UInt64

    # Our own SIGINT/SIGTERM handling: rclpy's would shut the context down before
    # the last stop could be published.
    leaving = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: leaving.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = Node("heartbeat_guard")
    watch = Watch(args.timeout, args.rearm)
    state = {"live": False}
    # Best effort, depth 1: only the newest beat matters, and it matches the
    # supervisor's reliable publisher.  The stop is reliable, as a command should be.
    beats_qos = QoSProfile(
        depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE
    )
    stop = node.create_publisher(Twist, args.stop_topic, 10)

    def check() -> None:
        now = time.monotonic()
        live = watch.live(now)
        if live != state["live"]:
            state["live"] = live
            if live:
                say(f"live (counter {watch.last_count}): the base may move")
            else:
                quiet = watch.silence(now)
                why = "no heartbeat yet" if quiet is None else f"no heartbeat for {quiet:.2f} s"
                say(f"stopping: {why} (timeout {args.timeout:g} s)")
        if not live:
            stop.publish(Twist())  # all zero: stand still

    def on_beat(msg: UInt64) -> None:
        why = watch.beat(int(msg.data), time.monotonic())
        if why is not None and state["live"]:
            state["live"] = False
            say(f"stopping: {why}")
            stop.publish(Twist())

    node.create_subscription(UInt64, args.heartbeat_topic, on_beat, beats_qos)
    node.create_timer(args.check, check)
    say(f"watching {args.heartbeat_topic}, stopping on {args.stop_topic}")
    check()  # stopped until the heartbeat is live
    while not leaving.is_set():
        rclpy.spin_once(node, timeout_sec=0.1)
    stop.publish(Twist())  # the guard going away is no reason to move
    say("leaving: stop published")
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not 0 < v <= 3600:
        raise argparse.ArgumentTypeError(f"must be above 0 and at most 3600 s: {text!r}")
    return v


def count(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 1000:
        raise argparse.ArgumentTypeError(f"must be a whole number from 1 to 1000: {text!r}")
    return int(text)


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"heartbeat_guard: {message}\n")  # one line, no usage block


def main(argv: Sequence[str] | None = None) -> int:
    ap = Parser(prog="heartbeat_guard", description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--heartbeat-topic", default=HEARTBEAT_TOPIC)
    ap.add_argument("--stop-topic", default="/cmd_vel", help="where the zero Twist goes")
    ap.add_argument("--timeout", type=seconds, default=TIMEOUT_S, help="seconds without a beat")
    ap.add_argument("--rearm", type=count, default=REARM, help="increasing beats to re-arm")
    ap.add_argument("--check", type=seconds, default=PERIOD_S / 2, help="check period, s")
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
