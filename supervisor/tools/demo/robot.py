"""The simulated sRobot of ``safety-supervisor demo``, one process per role.

``python -m supervisor.tools.demo.robot perception --rate-hz 10 --seed N``
    The thesis's perception feed (YOLO + RealSense, sec. 4.2.3): a person,
    trained (classifier 1) or untrained (2), walking towards the robot and away
    again, through the green (> 7 m), yellow (3-7 m) and red (<= 3 m) zones;
    nobody (classifier 0, distance 0) between walks.  Publishes classifier
    then distance_to_target each cycle.

``python -m supervisor.tools.demo.robot controller --fault-rate P --seed N``
    The safety controller: class and zone -> OpState and the outputs of
    Tables 7 and 8, published once per perception cycle with turnoffUVC last
    (the supervisor's trigger).  The fault of sec. 5.3.2: with probability P
    per update in state 3, the UV light sticks on (turnoffUVC false) for the
    rest of the stay in state 3, until the supervisor's ``uv_off`` mitigation
    (true on /sRobotTurnoffUVC) cuts it, as the robot's UV relay would.

``python -m supervisor.tools.demo.robot poweroff-marker DIR``
    What the demo config runs instead of ``ssh robot-pc.local sudo systemctl
    poweroff``: writes a marker file in DIR.

Both ROS processes print JSON lines on stdout for the demo's view
(``{"ev": "matched"}``, ``{"ev": "walk", ...}``, ``{"ev": "cycle", ...}``),
wait for ``go`` on stdin before the walk starts, and exit on SIGTERM, SIGINT
or when stdin closes (the demo went away: no orphans).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

RED_MAX, YELLOW_MAX = 3, 7  # the requirements' dgt_3 = d > 3, dgt_7 = d > 7

# Tables 7 and 8: (classifier, zone) -> OpState; nobody (0) -> 0.
STATE_OF = {
    (1, "green"): 1,  # R1 trained, green: sound
    (2, "green"): 2,  # R2 untrained, green: sound + slow down
    (1, "yellow"): 2,  # R3 trained, yellow: sound + slow down
    (2, "yellow"): 3,  # R4 untrained, yellow: UV off + stop
    (1, "red"): 3,  # R5 anyone, red: UV off + stop
    (2, "red"): 3,
}
# OpState -> outputs, exactly the operationalstate_N requirements.
OUTPUTS: dict[int, dict[str, bool]] = {
    0: {"alert": False, "slowdown": False, "halt": False, "turnoffUVC": False},
    1: {"alert": True, "slowdown": False, "halt": False, "turnoffUVC": False},
    2: {"alert": True, "slowdown": True, "halt": False, "turnoffUVC": False},
    3: {"alert": False, "slowdown": False, "halt": True, "turnoffUVC": True},
}
TRIGGER_GAP_S = 0.002  # DDS does not order messages across topics: outputs first, then the trigger


def zone_of(distance: int) -> str:
    if distance > YELLOW_MAX:
        return "green"
    return "yellow" if distance > RED_MAX else "red"


def op_state(classifier: int, distance: int) -> int:
    if classifier == 0:
        return 0
    return STATE_OF[(classifier, zone_of(distance))]


def walks(rng: random.Random, dt: float) -> Iterator[tuple[int, int, int]]:
    """(classifier, distance in whole metres, walk number) per perception cycle.

    Deterministic for a seed.  The first walk always comes into the red zone,
    so state 3 is reached within a few seconds of any run."""
    walk = 0
    while True:
        gap = 0.5 if walk == 0 else rng.uniform(0.8, 2.0)
        for _ in range(max(1, round(gap / dt))):
            yield 0, 0, walk
        walk += 1
        cls = rng.choice((1, 2))
        start, end = rng.uniform(8.5, 11.0), rng.uniform(8.5, 11.0)
        closest = rng.uniform(1.0, 2.5) if walk == 1 else rng.uniform(1.0, 6.0)
        v_in, v_out = rng.uniform(1.5, 2.5), rng.uniform(1.5, 2.5)  # m/s, a brisk walk
        d = start
        while d > closest:
            yield cls, round(d), walk
            d -= v_in * dt
        for _ in range(max(1, round(rng.uniform(0.5, 1.5) / dt))):
            yield cls, round(closest), walk
        d = closest
        while d < end:
            yield cls, round(d), walk
            d += v_out * dt


def emit(**event: Any) -> None:
    try:
        # Wall-clock time: the demo orders these with the supervisor's log records.
        print(json.dumps({"t": time.time(), **event}, separators=(",", ":")), flush=True)
    except (BrokenPipeError, ValueError):
        pass  # the demo went away; stdin EOF stops us


class _Process:
    """rclpy context without rclpy's signal handlers, a stop flag set by
    SIGTERM/SIGINT or by stdin closing, and the ``go`` line from the demo."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        self.stop = threading.Event()
        self.go = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.stop.set())
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        from rclpy.node import Node

        self.node = Node(name, context=self.context)
        threading.Thread(target=self._stdin, name="stdin", daemon=True).start()

    def _stdin(self) -> None:
        for line in sys.stdin:
            if line.strip() == "go":
                self.go.set()
        self.stop.set()  # EOF: the demo is gone

    def close(self) -> None:
        import rclpy

        try:
            self.node.destroy_node()
            rclpy.shutdown(context=self.context)
        except Exception:  # noqa: BLE001, S110 - exiting anyway; nothing to report to
            pass


def _wait_matched(proc: _Process, matched: Any) -> bool:
    """Until ``matched()`` (DDS discovery) then ``go``; False when stopped."""
    while not proc.stop.is_set() and not matched():
        time.sleep(0.02)  # polling the graph cache, which DDS threads update
    if proc.stop.is_set():
        return False
    emit(ev="matched")
    while not proc.stop.is_set() and not proc.go.wait(0.05):
        pass
    return not proc.stop.is_set()


# ------------------------------------------------------------------ perception


def run_perception(rate_hz: float, seed: int) -> int:
    from std_msgs.msg import Int64

    proc = _Process("srobot_perception")
    node = proc.node
    classifier = node.create_publisher(Int64, "/sRobotClassifier", 10)
    distance = node.create_publisher(Int64, "/scan", 10)
    try:
        # Both the supervisor and the controller must hear the first cycle.
        if not _wait_matched(
            proc,
            lambda: (
                classifier.get_subscription_count() >= 2 and distance.get_subscription_count() >= 2
            ),
        ):
            return 0
        dt = 1.0 / rate_hz
        samples = walks(random.Random(f"{seed}:perception"), dt)
        t0 = time.monotonic()
        last_walk = 0
        k = 0
        while not proc.stop.is_set():
            cls, d, walk = next(samples)
            if walk != last_walk:
                last_walk = walk
                emit(ev="walk", n=walk, cls=cls)
            classifier.publish(Int64(data=cls))
            distance.publish(Int64(data=d))
            k += 1
            # Fixed grid: a late cycle does not shift the ones after it.
            proc.stop.wait(max(0.0, t0 + k * dt - time.monotonic()))
    finally:
        proc.close()
    return 0


# ------------------------------------------------------------------ controller


class Controller:
    def __init__(self, proc: _Process, fault_rate: float, seed: int) -> None:
        from rclpy.event_handler import SubscriptionEventCallbacks
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Bool, Int64

        self.Bool, self.Int64 = Bool, Int64
        node = proc.node
        self.rng = random.Random(f"{seed}:controller")
        self.fault_rate = fault_rate
        self.cut = False  # uv_off cut a stuck relay during this stay in state 3
        self.pending: dict[str, dict[int, int]] = {"c": {}, "d": {}}
        self.counters = {"c": 0, "d": 0}
        self.state = 0
        self.faulty = False  # this stay in state 3 has the UV light stuck on
        self.inputs = [
            node.create_subscription(
                Int64, "/sRobotClassifier", lambda m, i: self._input("c", m, i), 10
            ),
            node.create_subscription(Int64, "/scan", lambda m, i: self._input("d", m, i), 10),
        ]
        self.pubs = {
            "OpState": node.create_publisher(Int64, "/sRobotState", 10),
            "alert": node.create_publisher(Bool, "/sRobotAlert", 10),
            "slowdown": node.create_publisher(Bool, "/sRobotSlowdown", 10),
            "halt": node.create_publisher(Bool, "/sRobotHalt", 10),
            "turnoffUVC": node.create_publisher(Bool, "/sRobotTurnoffUVC", 10),
        }
        # The supervisor's publish mitigations are latched (reliable,
        # transient-local); a transient-local reader matches only those, not
        # this controller's own volatile outputs on the same topics.
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        quiet = SubscriptionEventCallbacks(incompatible_qos=lambda _e: None)
        self.mitigations = [
            node.create_subscription(
                Bool, "/sRobotTurnoffUVC", self._uv_off, latched, event_callbacks=quiet
            ),
            node.create_subscription(
                Bool, "/sRobotHalt", self._halt, latched, event_callbacks=quiet
            ),
        ]

    def matched(self) -> bool:
        return (
            all(p.get_subscription_count() >= 1 for p in self.pubs.values())
            and all(s.get_publisher_count() >= 1 for s in self.inputs)
            and all(s.get_publisher_count() >= 1 for s in self.mitigations)
        )

    def _input(self, key: str, msg: Any, info: dict[str, Any]) -> None:
        # A cycle is the classifier and the distance of the same perception
        # cycle: the n-th message of each writer (never a new class with an
        # old distance, whichever of the two is taken first).
        self.counters[key] += 1
        seq = info.get("publication_sequence_number") or self.counters[key]
        self.pending[key][seq] = int(msg.data)
        common = self.pending["c"].keys() & self.pending["d"].keys()
        if not common:
            return
        n = max(common)
        cls, dist = self.pending["c"][n], self.pending["d"][n]
        for q in self.pending.values():
            for old in [s for s in q if s <= n]:
                del q[old]
        self._cycle(cls, dist)

    def _cycle(self, cls: int, dist: int) -> None:
        state = op_state(cls, dist)
        if state == 3:
            # The thesis's fault (sec. 5.3.2): on each update in state 3 the UV
            # relay may stick on, until the supervisor's uv_off cuts it for the
            # rest of this stay.
            if self.state != 3:
                self.cut = False
            if not self.faulty and not self.cut and self.rng.random() < self.fault_rate:
                self.faulty = True
                emit(ev="fault")
        else:
            self.faulty = False
        if state != self.state:
            emit(ev="state", old=self.state, new=state)
        self.state = state
        out = dict(OUTPUTS[state])
        if self.faulty:
            out["turnoffUVC"] = False  # sec. 5.3.2: the UV light stays on
        self.pubs["OpState"].publish(self.Int64(data=state))
        for name in ("alert", "slowdown", "halt"):
            self.pubs[name].publish(self.Bool(data=out[name]))
        time.sleep(TRIGGER_GAP_S)
        self.pubs["turnoffUVC"].publish(self.Bool(data=out["turnoffUVC"]))
        emit(ev="cycle", c=cls, d=dist, state=state, fault=self.faulty, **out)

    def _uv_off(self, msg: Any) -> None:
        if not msg.data:
            return
        # The UV relay obeys the cut: the fault is over for this stay in state 3.
        fixed = self.faulty
        self.faulty = False
        self.cut = self.cut or fixed
        emit(ev="uv_off", fixed=fixed, state=self.state)

    def _halt(self, msg: Any) -> None:
        if msg.data:
            emit(ev="halt", state=self.state)  # in state 3 the robot is stopping already


def run_controller(fault_rate: float, seed: int) -> int:
    from rclpy.executors import SingleThreadedExecutor

    proc = _Process("srobot_controller")
    try:
        ctl = Controller(proc, fault_rate, seed)
        executor = SingleThreadedExecutor(context=proc.context)
        executor.add_node(proc.node)
        while not proc.stop.is_set() and not ctl.matched():
            executor.spin_once(timeout_sec=0.02)
        if proc.stop.is_set():
            return 0
        emit(ev="matched")
        while not proc.stop.is_set():
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
    finally:
        proc.close()
    return 0


# ------------------------------------------------------------------ power off


def poweroff_marker(directory: str) -> int:
    path = Path(directory) / f"poweroff-{time.time_ns()}.marker"
    path.write_text("simulated: ssh robot-pc.local sudo systemctl poweroff\n")
    print(f"robot powered off (simulated): {path}")
    return 0


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, not {text}")
    return value


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.demo.robot")
    sub = p.add_subparsers(dest="role", required=True)
    per = sub.add_parser("perception")
    per.add_argument("--rate-hz", type=float, default=10.0)
    per.add_argument("--seed", type=int, default=0)
    ctl = sub.add_parser("controller")
    ctl.add_argument("--fault-rate", type=_fraction, default=0.01)
    ctl.add_argument("--seed", type=int, default=0)
    off = sub.add_parser("poweroff-marker")
    off.add_argument("dir")
    args = p.parse_args(argv)
    try:
        if args.role == "perception":
            return run_perception(args.rate_hz, args.seed)
        if args.role == "controller":
            return run_controller(args.fault_rate, args.seed)
        return poweroff_marker(args.dir)
    except KeyboardInterrupt:
        return 130
    except Exception as e:  # noqa: BLE001 - one line for the demo to show, no traceback
        if os.environ.get("SAFETY_SUPERVISOR_DEBUG"):
            raise
        print(f"demo_robot {args.role}: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
