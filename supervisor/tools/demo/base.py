"""The simulated mobile base of ``safety-supervisor demo --example mobile-base``.

``python -m supervisor.tools.demo.base --seed N``

One process plays a holonomic base with its lidar, odometry, battery, estop button
and navigation stack, for the shipped ``mobile-base.yaml``
(docs/reference/commands.md, "demo").  It publishes

- ``/scan`` (``sensor_msgs/msg/LaserScan``, 1,440 readings, 10-40 Hz, with NaN,
  infinite and out-of-range readings sprinkled in, which REP 117 says are not
  readings, so the closest obstacle is still the wall),
- ``/odom`` (``nav_msgs/msg/Odometry``), ``/halt`` (``std_msgs/msg/Bool``, the base's
  halt state) and ``/cmd_vel`` (``geometry_msgs/msg/Twist``, the planner's command),
  at 50 Hz,
- ``/battery`` (``sensor_msgs/msg/BatteryState``) at 5 Hz,
- ``/estop`` (``std_msgs/msg/Empty``) when the scenario presses the button,
- ``/navigate_to_pose/_action/status`` (``action_msgs/msg/GoalStatusArray``), on each
  change, reliable and transient local, as an action server does,

and obeys the supervisor's mitigations: a latched ``true`` on ``/halt`` or a zero
Twist on ``/cmd_vel`` halts it until the scenario's next phase (an operator's resume).

:data:`SCENARIO` is the script: phases in order, each naming the requirement it
breaks (or none).  :class:`BaseModel` is the base without ROS, so the script can be
checked tick by tick without DDS (tests/supervisor/tools/test_demo_base.py).

Like :mod:`supervisor.tools.demo.robot`, it prints JSON lines on stdout for the demo's
view, waits for ``go`` on stdin before the scenario starts (its lidar alone runs from
discovery on: :data:`WARMUP_S`), and exits on SIGTERM, SIGINT or when stdin closes
(the demo went away: no orphans).
"""

from __future__ import annotations

import argparse
import math
import os
import random
import sys
import threading
import time
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from supervisor.tools.demo.robot import _Process, emit

# The requirements of mobile-base.yaml, in the order the scenario breaks them.
REQUIREMENTS = (
    "slow_near_obstacle",
    "fresh_scan",
    "scan_rate_ok",
    "estop_halts",
    "no_nav_on_low_battery",
    "cmd_vel_limit",
)

# The thresholds of mobile-base.yaml's requirements, for the scenario's own check
# (tests/supervisor/tools/test_demo_base.py) and the view's words.
NEAR_M, SLOW_MPS = 0.5, 0.3  # slow_near_obstacle
MAX_SCAN_AGE_MS = 300.0  # fresh_scan
MIN_SCAN_HZ = 8.0  # scan_rate_ok
RATE_WINDOW_S = 1.0  # scan_rate's window_ms
ESTOP_TICKS = 10  # estop_halts: within 10 ticks
LOW_BATTERY = 0.15  # no_nav_on_low_battery
MAX_CMD_MPS = 1.0  # cmd_vel_limit
TICK_S = 0.02  # the config's step.period_ms

DT = 0.01  # the simulation's step: scans up to 40 Hz land within 10 ms of their time
OPEN_M = 4.0  # the closest thing ahead on open floor
BUMPER_M = 0.25  # the base's own bumper stops it here (the supervisor should first)
READINGS = 1440
RANGE_MIN, RANGE_MAX = 0.05, 30.0
FRONT = 40  # readings either side of straight ahead that see the wall
# The lidar runs alone this long before the base says it is ready: scan_rate is known
# only a full window after the first scan, and the monitor waits for it
# (docs/reference/config.md, "Ages and rates"), so it steps from the scenario's start.
WARMUP_S, WARMUP_HZ = 1.2, 20.0


def _num(v: Any, unit: str, digits: int = 2) -> str:
    return f"{v:.{digits}f}{unit}" if isinstance(v, int | float) else "?"


def _pct(v: Any) -> Any:
    return v * 100 if isinstance(v, int | float) else v


def _speed(inputs: dict[str, Any]) -> float | None:
    """The define's hypot(vx, vy): a record's inputs are the topic variables."""
    vx, vy = inputs.get("vx"), inputs.get("vy")
    if isinstance(vx, int | float) and isinstance(vy, int | float):
        return math.hypot(vx, vy)
    return None


# A violation's inputs (its log record's) in words, for the demo's events.
EXPLAIN: dict[str, Callable[[dict[str, Any]], str]] = {
    "slow_near_obstacle": lambda i: (
        f"{_num(_speed(i), ' m/s')} with an obstacle at {_num(i.get('obstacle'), ' m')}"
    ),
    "fresh_scan": lambda i: f"the scan is {_num(i.get('scan_age_ms'), ' ms', 0)} old",
    "scan_rate_ok": lambda i: f"the scan comes at {_num(i.get('scan_rate'), ' Hz', 1)}",
    "estop_halts": lambda i: f"no halt within {ESTOP_TICKS} ticks of the estop",
    "no_nav_on_low_battery": lambda i: (
        f"navigating with the battery at {_num(_pct(i.get('battery')), ' %', 0)}"
    ),
    "cmd_vel_limit": lambda i: f"the planner commands {_num(i.get('cmd_vel'), ' m/s')}",
}


@dataclass(frozen=True)
class Phase:
    """One scripted stretch of the scenario; times are seconds into the phase."""

    name: str
    seconds: float
    says: str  # what happens, in words, for the view
    breaks: str | None = None  # the requirement this phase breaks
    speed: float = 0.5  # the planner's command, m/s (forwards)
    strafe: float = 0.0  # the planner's sideways command, m/s (the base is holonomic)
    wall: float | None = None  # distance to a wall ahead at the start, m; None: open floor
    scan_hz: float = 15.0
    freeze_stamp: bool = False  # the lidar driver keeps sending its last stamp
    estop_at: float | None = None  # the button is pressed
    halt_delay: float = 0.0  # the base's own halt, after the estop
    battery: float = 0.8
    goal: tuple[float, float, str] | None = None  # (accepted at, ends at, how it ends)


SCENARIO: tuple[Phase, ...] = (
    Phase(
        "cruise",
        2.5,
        "cruising on open floor, navigating to a pose",
        speed=0.6,
        scan_hz=20.0,
        goal=(0.3, 2.3, "succeeded"),
    ),
    Phase(
        "wall",
        3.0,
        "driving at 0.8 m/s towards a wall 2 m ahead",
        "slow_near_obstacle",
        speed=0.75,
        strafe=0.25,
        wall=2.0,
    ),
    Phase("recover_1", 1.0, "resumed, open floor", speed=0.4, scan_hz=40.0),
    Phase(
        "stale_scan",
        2.0,
        "the lidar driver freezes its stamp (scans keep coming, all old)",
        "fresh_scan",
        speed=0.4,
        freeze_stamp=True,
    ),
    Phase("recover_2", 1.0, "resumed, the lidar stamps again", speed=0.4),
    Phase(
        "slow_scan",
        2.5,
        "the lidar drops to 5 Hz",
        "scan_rate_ok",
        speed=0.4,
        scan_hz=5.0,
    ),
    Phase("recover_3", 1.5, "resumed, the lidar back at 20 Hz", speed=0.4, scan_hz=20.0),
    Phase(
        "estop_ok",
        1.5,
        "estop pressed: the base halts at once",
        speed=0.5,
        estop_at=0.3,
    ),
    Phase(
        "estop_slow",
        2.0,
        "estop pressed: the base's halt path takes 0.6 s",
        "estop_halts",
        speed=0.5,
        estop_at=0.3,
        halt_delay=0.6,
    ),
    Phase(
        "low_battery",
        2.5,
        "battery at 12 %, and a navigation goal is accepted",
        "no_nav_on_low_battery",
        speed=0.0,
        battery=0.12,
        goal=(0.5, 2.0, "aborted"),
    ),
    Phase(
        "fast_command",
        1.5,
        "battery swapped; the planner commands 1.2 m/s",
        "cmd_vel_limit",
        speed=1.2,
    ),
    Phase("recover_4", 1.0, "resumed, open floor", speed=0.4),
)
SCENARIO_S = sum(p.seconds for p in SCENARIO)


def phase_at(t: float) -> tuple[int, Phase, float]:
    """(index, phase, seconds into it) at ``t`` seconds after ``go``; the script
    repeats for demos longer than it."""
    t = t % SCENARIO_S
    for i, p in enumerate(SCENARIO):
        if t < p.seconds:
            return i, p, t
        t -= p.seconds
    return len(SCENARIO) - 1, SCENARIO[-1], SCENARIO[-1].seconds


@dataclass
class Observation:
    """What the base publishes at one simulation step."""

    t: float  # seconds since go
    phase: Phase
    obstacle: float  # the closest wall ahead, m
    vx: float
    vy: float
    cmd: float  # the planner's forward command
    halted: bool
    battery: float
    estop: bool  # the button was pressed at this step
    scan_stamp: float | None  # a scan is sent at this step, with this stamp (s since go)
    nav: str  # the goal's state: '' (none), accepted, executing, succeeded, aborted
    nav_changed: bool


@dataclass
class BaseModel:
    """The simulated base without ROS: one :meth:`step` per ``DT``."""

    t: float = 0.0
    index: int = -1
    halted: bool = False
    halted_by: str = ""
    obstacle: float = OPEN_M
    estop_pressed_at: float | None = None
    next_scan: float = 0.0
    frozen_stamp: float | None = None
    nav: str = ""
    supervisor_halt: bool = False  # set from another thread; taken at the next step

    def step(self) -> Observation:
        t = self.t
        index, p, into = phase_at(t)
        if index != self.index:  # a new phase: the operator resumes the base
            self.index = index
            self.halted, self.halted_by = False, ""
            self.obstacle = p.wall if p.wall is not None else OPEN_M
            self.estop_pressed_at = None
            self.frozen_stamp = t if p.freeze_stamp else None
            self.next_scan = min(self.next_scan, t + 1.0 / p.scan_hz)
        if self.supervisor_halt:
            self.supervisor_halt = False
            if not self.halted:
                self.halted, self.halted_by = True, "supervisor"
        estop = False
        if p.estop_at is not None and self.estop_pressed_at is None and into >= p.estop_at:
            self.estop_pressed_at, estop = t, True
        if (
            self.estop_pressed_at is not None
            and not self.halted
            and t >= self.estop_pressed_at + p.halt_delay - 1e-9
        ):
            self.halted, self.halted_by = True, "estop"
        cmd = 0.0 if self.halted else p.speed
        strafe = 0.0 if self.halted else p.strafe
        if p.wall is not None and self.obstacle <= BUMPER_M:
            cmd = strafe = 0.0  # the bumper: the last line of defence, not the supervisor's
        if p.wall is not None:
            self.obstacle = max(BUMPER_M, self.obstacle - cmd * DT)
        stamp = None
        if t >= self.next_scan - 1e-9:
            stamp = self.frozen_stamp if self.frozen_stamp is not None else t
            self.next_scan += 1.0 / p.scan_hz
            if self.next_scan <= t:  # never a burst to catch up
                self.next_scan = t + 1.0 / p.scan_hz
        nav = ""
        if p.goal is not None:
            start, end, outcome = p.goal
            if into >= end:
                nav = outcome
            elif into >= start + 0.1:
                nav = "executing"
            elif into >= start:
                nav = "accepted"
        changed = nav != self.nav
        self.nav = nav
        self.t = round(t + DT, 9)
        return Observation(
            t=t,
            phase=p,
            obstacle=self.obstacle,
            vx=cmd,
            vy=strafe,
            cmd=cmd,
            halted=self.halted,
            battery=p.battery,
            estop=estop,
            scan_stamp=stamp,
            nav=nav,
            nav_changed=changed,
        )


# ------------------------------------------------------------ the scenario's check


@dataclass
class Judge:
    """The requirements of mobile-base.yaml over the model's observations, at the
    supervisor's 20 ms ticks, as docs/reference/config.md defines the inputs: the
    scan's age from its stamp, its rate over a 1 s window, the estop an event.
    Only for checking the script; the supervisor is the judge of the real run."""

    scans: deque[tuple[float, float]] = field(  # (arrival, stamp), the warm-up's first
        default_factory=lambda: deque(
            (-k / WARMUP_HZ, -k / WARMUP_HZ) for k in range(round(WARMUP_S * WARMUP_HZ), 0, -1)
        )
    )
    estop_tick: int | None = None
    tick: int = 0
    last: Observation | None = None

    def see(self, o: Observation) -> None:
        if o.scan_stamp is not None:
            self.scans.append((o.t, o.scan_stamp))
        if o.estop:
            self.estop_tick = self.tick + 1  # an event is true at the next step
        self.last = o

    def judge(self, t: float) -> set[str]:
        """The requirements broken at the tick at ``t``."""
        self.tick += 1
        o = self.last
        if o is None or not self.scans:
            return set()
        while self.scans and self.scans[0][0] <= t - RATE_WINDOW_S:
            self.scans.popleft()
        broken = set()
        if o.obstacle < NEAR_M and math.hypot(o.vx, o.vy) > SLOW_MPS:
            broken.add("slow_near_obstacle")
        if self.scans and (t - self.scans[-1][1]) * 1000 >= MAX_SCAN_AGE_MS:
            broken.add("fresh_scan")
        if len(self.scans) / RATE_WINDOW_S < MIN_SCAN_HZ:
            broken.add("scan_rate_ok")
        if self.estop_tick is not None:
            if o.halted:
                self.estop_tick = None  # halted in time
            elif self.tick - self.estop_tick >= ESTOP_TICKS:
                broken.add("estop_halts")
        if o.battery < LOW_BATTERY and o.nav in ("accepted", "executing"):
            broken.add("no_nav_on_low_battery")
        if abs(o.cmd) > MAX_CMD_MPS:
            broken.add("cmd_vel_limit")
        return broken


def scenario_breaks(seconds: float = SCENARIO_S) -> dict[str, set[str]]:
    """Each phase's name -> the requirements that become broken in it (a violation
    that lasts into the next phase, as a scan rate's window recovering, counts
    where it began), with no supervisor to halt the base."""
    model, judge = BaseModel(), Judge()
    found: dict[str, set[str]] = {p.name: set() for p in SCENARIO}
    before: set[str] = set()
    next_tick = TICK_S
    while model.t < seconds - 1e-9:
        o = model.step()
        judge.see(o)
        if o.t >= next_tick - 1e-9:
            next_tick += TICK_S
            broken = judge.judge(o.t)
            found[o.phase.name] |= broken - before
            before = broken
    return found


# ------------------------------------------------------------------ the ROS process


def scan_ranges(rng: random.Random, room: list[float], obstacle: float) -> array:
    """1,440 readings: the room, the wall ahead, and what REP 117 says are not
    readings (NaN, +-inf, under range_min, over range_max) sprinkled in."""
    ranges = array("f", room)
    mid = READINGS // 2
    for i in range(mid - FRONT, mid + FRONT + 1):
        ranges[i] = min(ranges[i], obstacle)
    for _ in range(rng.randint(10, 30)):
        i = rng.randrange(READINGS)
        ranges[i] = rng.choice((math.nan, math.inf, -math.inf, 0.01, 0.0, 45.0))
    return ranges


class Base:
    """The ROS side of :class:`BaseModel`: publishers, the mitigations it obeys."""

    def __init__(self, proc: _Process, seed: int) -> None:
        from action_msgs.msg import GoalStatusArray
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.event_handler import SubscriptionEventCallbacks
        from rclpy.qos import (
            DurabilityPolicy,
            QoSProfile,
            ReliabilityPolicy,
            qos_profile_sensor_data,
        )
        from sensor_msgs.msg import BatteryState, LaserScan
        from std_msgs.msg import Bool, Empty

        node = proc.node
        self.proc = proc
        self.model = BaseModel()
        self.rng = random.Random(f"{seed}:base")
        self.room = [self.rng.uniform(2.5, 8.0) for _ in range(READINGS)]
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.pubs = {
            "scan": node.create_publisher(LaserScan, "/scan", qos_profile_sensor_data),
            "odom": node.create_publisher(Odometry, "/odom", 10),
            "halt": node.create_publisher(Bool, "/halt", 10),
            "cmd_vel": node.create_publisher(Twist, "/cmd_vel", 10),
            "battery": node.create_publisher(BatteryState, "/battery", 10),
            "estop": node.create_publisher(Empty, "/estop", 10),
            # As an action server publishes its goals' states.
            "nav": node.create_publisher(
                GoalStatusArray, "/navigate_to_pose/_action/status", latched
            ),
        }
        # The supervisor's publish mitigations are latched; a transient-local reader
        # matches only those, not this base's own volatile /halt and /cmd_vel.
        quiet = SubscriptionEventCallbacks(incompatible_qos=lambda _e: None)
        self.mitigations = [
            node.create_subscription(Bool, "/halt", self._halt, latched, event_callbacks=quiet),
            node.create_subscription(
                Twist, "/cmd_vel", self._zero_cmd, latched, event_callbacks=quiet
            ),
        ]
        self.msgs = (LaserScan, Odometry, Bool, Twist, BatteryState, Empty, GoalStatusArray)
        self.goal_id = bytes(16)
        self.goals = 0
        self.lock = threading.Lock()

    def matched(self) -> bool:
        """The supervisor reads every topic, and its mitigations are there."""
        return all(p.get_subscription_count() >= 1 for p in self.pubs.values()) and all(
            s.get_publisher_count() >= 1 for s in self.mitigations
        )

    def _halt(self, msg: Any) -> None:
        if msg.data:
            with self.lock:
                self.model.supervisor_halt = True
            emit(ev="mitigation", what="halt")

    def _zero_cmd(self, msg: Any) -> None:
        if msg.linear.x == 0.0 and msg.linear.y == 0.0:
            with self.lock:
                self.model.supervisor_halt = True
            emit(ev="mitigation", what="zero_cmd_vel")

    def run(self) -> None:
        """The fixed ``DT`` grid from ``go`` until stopped."""
        t0_wall, t0 = time.time(), time.monotonic()
        k, last_index, was_halted, last_view = 0, -1, False, -1.0
        while not self.proc.stop.is_set():
            with self.lock:
                o = self.model.step()
            if self.model.index != last_index:
                last_index = self.model.index
                p = o.phase
                emit(ev="phase", n=last_index, name=p.name, says=p.says, breaks=p.breaks)
            self.publish(o, t0_wall)
            if o.halted and not was_halted:
                emit(ev="halted", by=self.model.halted_by)
            was_halted = o.halted
            if o.t - last_view >= 0.1:
                last_view = o.t
                emit(
                    ev="base",
                    obstacle=round(o.obstacle, 3),
                    speed=round(math.hypot(o.vx, o.vy), 3),
                    cmd=o.cmd,
                    scan_hz=o.phase.scan_hz,
                    frozen=o.phase.freeze_stamp,
                    battery=o.battery,
                    nav=o.nav,
                    halted=o.halted,
                )
            k += 1
            # Fixed grid: a late step does not shift the ones after it.
            self.proc.stop.wait(max(0.0, t0 + k * DT - time.monotonic()))

    def publish(self, o: Observation, t0_wall: float) -> None:
        _, Odometry, Bool, Twist, BatteryState, Empty, _ = self.msgs
        now = self.proc.node.get_clock().now().to_msg()
        k = round(o.t / DT)
        if o.estop:
            self.pubs["estop"].publish(Empty())
            emit(ev="estop", halt_delay=o.phase.halt_delay)
        if o.scan_stamp is not None:
            if o.phase.freeze_stamp:
                wall = t0_wall + o.scan_stamp
                self.scan(o.obstacle, o.phase.scan_hz, self.stamp(wall))
            else:
                self.scan(o.obstacle, o.phase.scan_hz, now)
        if o.nav_changed:
            self.pubs["nav"].publish(self.status(o.nav, now))
        if k % 2 == 0:  # 50 Hz
            odom = Odometry()
            odom.header.stamp, odom.header.frame_id, odom.child_frame_id = now, "odom", "base"
            odom.twist.twist.linear.x, odom.twist.twist.linear.y = o.vx, o.vy
            self.pubs["odom"].publish(odom)
            cmd = Twist()
            cmd.linear.x, cmd.linear.y = o.cmd, o.vy
            self.pubs["cmd_vel"].publish(cmd)
            self.pubs["halt"].publish(Bool(data=o.halted))
        if k % 20 == 0:  # 5 Hz
            battery = BatteryState()
            battery.header.stamp = now
            battery.percentage = o.battery
            battery.present = True
            self.pubs["battery"].publish(battery)

    def stamp(self, wall: float) -> Any:
        from builtin_interfaces.msg import Time

        return Time(sec=int(wall), nanosec=int((wall - int(wall)) * 1e9))

    def scan(self, obstacle: float, hz: float, stamp: Any) -> None:
        LaserScan = self.msgs[0]
        scan = LaserScan()
        scan.header.frame_id = "laser"
        scan.header.stamp = stamp
        scan.angle_min, scan.angle_max = -math.pi, math.pi
        scan.angle_increment = 2 * math.pi / READINGS
        scan.scan_time = 1.0 / hz
        scan.range_min, scan.range_max = RANGE_MIN, RANGE_MAX
        scan.ranges = scan_ranges(self.rng, self.room, obstacle)
        self.pubs["scan"].publish(scan)

    def warm_up(self) -> bool:
        """The lidar alone at ``WARMUP_HZ`` from discovery until ``go``, saying
        ``matched`` after ``WARMUP_S``; False when stopped."""
        t0, k, said = time.monotonic(), 0, False
        while not self.proc.stop.is_set():
            if not said and time.monotonic() - t0 >= WARMUP_S:
                said = True
                emit(ev="matched")
            if said and self.proc.go.is_set():
                return True
            self.scan(OPEN_M, WARMUP_HZ, self.proc.node.get_clock().now().to_msg())
            k += 1
            self.proc.stop.wait(max(0.0, t0 + k / WARMUP_HZ - time.monotonic()))
        return False

    def status(self, nav: str, now: Any) -> Any:
        from action_msgs.msg import GoalStatus

        _, _, _, _, _, _, GoalStatusArray = self.msgs
        array_msg = GoalStatusArray()
        if not nav:
            return array_msg  # no goal: an empty list
        if nav == "accepted":  # a new goal
            self.goals += 1
            self.goal_id = self.goals.to_bytes(16, "big")
        code = {
            "accepted": GoalStatus.STATUS_ACCEPTED,
            "executing": GoalStatus.STATUS_EXECUTING,
            "succeeded": GoalStatus.STATUS_SUCCEEDED,
            "aborted": GoalStatus.STATUS_ABORTED,
        }[nav]
        status = GoalStatus(status=code)
        status.goal_info.goal_id.uuid = list(self.goal_id)
        status.goal_info.stamp = now
        array_msg.status_list = [status]
        emit(ev="nav", state=nav)
        return array_msg


def run_base(seed: int) -> int:
    from rclpy.executors import SingleThreadedExecutor

    proc = _Process("mobile_base")
    executor: SingleThreadedExecutor | None = None
    spinner: threading.Thread | None = None
    try:
        base = Base(proc, seed)
        executor = SingleThreadedExecutor(context=proc.context)
        executor.add_node(proc.node)
        # The mitigations arrive on the executor's thread, the scenario runs here.
        spinner = threading.Thread(target=_spin, args=(executor, proc), daemon=True)
        spinner.start()
        while not proc.stop.is_set() and not base.matched():
            time.sleep(0.02)  # polling the graph cache, which DDS threads update
        if base.warm_up():
            base.run()
    finally:
        proc.stop.set()
        if spinner is not None:
            spinner.join(timeout=2.0)
        if executor is not None:
            executor.shutdown()
        proc.close()
    return 0


def _spin(executor: Any, proc: _Process) -> None:
    while not proc.stop.is_set():
        executor.spin_once(timeout_sec=0.05)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.demo.base")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:
        return run_base(args.seed)
    except KeyboardInterrupt:
        return 130
    except Exception as e:  # noqa: BLE001 - one line for the demo to show, no traceback
        if os.environ.get("SAFETY_SUPERVISOR_DEBUG"):
            raise
        print(f"demo_base: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
