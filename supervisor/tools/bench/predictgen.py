"""The scenarios of ``bench --predict``: recorded runs with labelled outcomes.

Each scenario is a config (written by :func:`config_text`) and runs of input values
with their receive times, as a JSON-lines trace ``replay`` reads
(docs/reference/commands.md, "replay"), and the span of each walk or approach, so
the bench can say which violation belongs to which walk.

- ``srobot``: the sRobot demo's perception feed (supervisor/tools/demo/robot.py's
  walks: whole metres at 10 Hz, nobody between walks, a dwell at the closest point,
  then away) while the UV lamp is on, with the thesis's "distance > 3 m while UV
  on" as the requirement.  Approach runs come into the red zone (closest 1-2.5 m)
  at one walking speed each; near misses come as fast but turn back at 3.6-6 m
  (nothing breaks, but nothing before the turn tells them from an approach); clean
  runs have no approach: a person working 5-9 m away (readings 5 to 9), moving back
  and forth at up to 0.5 m/s.
- ``mobile-base``: the mobile base's ``slow_near_obstacle`` (mobile-base.yaml): the
  closest lidar reading (40 Hz, 1 cm noise) and the base's speed (50 Hz) while it
  drives at a wall.  Approach runs do not slow down in time; near misses slow to
  0.2 m/s at 1 m and stop at 0.35 m, as a working planner does; clean runs drive
  along a corridor, 1.5-3 m from the closest wall.
"""

from __future__ import annotations

import json
import random
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from supervisor.tools.demo.robot import RED_MAX

MS = 1_000_000
S = 1_000_000_000
SROBOT_SPEEDS = (0.5, 1.0, 1.5, 2.0, 2.5)  # m/s toward the lamp
BASE_SPEEDS = (0.4, 0.6, 0.8, 1.0)  # m/s toward the wall

_SROBOT = """\
component: sRobot
step: {{policy: on_trigger, trigger: distance_to_target, stale_after_ms: 1000}}
variables:
  classifier: {{type: int64, topic: /sRobotClassifier, msg: std_msgs/msg/Int64, range: [0, 2]}}
  distance_to_target: {{type: int64, topic: /scan, msg: std_msgs/msg/Int64, range: [0, 100]}}
  uv_on: {{type: bool, topic: /sRobotUV, msg: std_msgs/msg/Bool}}
requirements:
  - id: uv_distance
    text: sRobot shall always satisfy classifier = 0 | !uv_on | distance_to_target > {red}
    rationale: Nobody within 3 m of the lamp while the UV light is on.
    on_violation: [uv_off]
    policy: {{reset: after_mitigation}}
    predict: {predict}
mitigations:
  uv_off: {{log: {{message: UV off}}}}
  uv_off_early: {{log: {{message: UV off before the person is within 3 m}}}}
"""

_BASE = """\
component: base
step: {{policy: periodic, period_ms: 20, stale_after_ms: 1000}}
variables:
  obstacle: {{type: double, topic: /scan_min, msg: std_msgs/msg/Float64}}
  speed: {{type: double, topic: /speed, msg: std_msgs/msg/Float64}}
requirements:
  - id: slow_near_obstacle
    text: base shall always satisfy (obstacle < 0.5 => speed <= 0.3)
    rationale: Within half a metre of an obstacle the base must crawl (mobile-base.yaml).
    on_violation: [stop_base]
    policy: {{reset: after_mitigation}}
    predict: {predict}
mitigations:
  stop_base: {{log: {{message: stop}}}}
  slow_early: {{log: {{message: slow down before the obstacle}}}}
"""

SCENARIOS = ("srobot", "mobile-base")
EARLY_ACTION = {"srobot": "uv_off_early", "mobile-base": "slow_early"}


@dataclass
class Run:
    """One recorded run: ``kind`` approach (each walk ends in a violation) or clean
    (none does); its events and the [start, end) of each walk."""

    scenario: str
    kind: str
    speed: float
    events: list[tuple[int, str, Any]] = field(default_factory=list)
    walks: list[tuple[int, int]] = field(default_factory=list)

    @property
    def seconds(self) -> float:
        return (self.events[-1][0] - self.events[0][0]) / S if self.events else 0.0

    def write(self, path: Path) -> Path:
        path.write_text(
            "".join(
                json.dumps({"t_ns": t, "name": n, "value": v}, separators=(",", ":")) + "\n"
                for t, n, v in self.events
            )
        )
        return path


def config_text(scenario: str, predict: Mapping[str, Any] | None = None) -> str:
    """The scenario's config, its requirement predicting with ``predict`` (the
    defaults when empty) and the early action."""
    settings = {"actions": [EARLY_ACTION[scenario]], **(predict or {})}
    flow = json.dumps(settings)  # JSON is YAML's flow style
    if scenario == "srobot":
        return _SROBOT.format(red=RED_MAX, predict=flow)
    return _BASE.format(predict=flow)


def srobot_run(seed: int, speed: float, kind: str, walks: int, rate_hz: float = 10.0) -> Run:
    """``walks`` walks of the sRobot demo's shape at ``speed`` m/s toward the lamp."""
    rng = random.Random(f"srobot:{seed}:{speed}:{kind}")
    dt = 1.0 / rate_hz
    run = Run("srobot", kind, speed)
    t = S
    run.events.append((t, "uv_on", True))
    for _ in range(walks):
        for _ in range(round(rng.uniform(0.8, 2.0) / dt)):  # nobody between walks
            t += int(dt * S)
            run.events += [(t, "classifier", 0), (t + MS, "distance_to_target", 0)]
        start = t
        closest = rng.uniform(1.0, 2.5) if kind == "approach" else rng.uniform(3.6, 6.0)
        walk = _wander(rng, dt) if kind == "clean" else _walk(rng, dt, speed, closest)
        for cls, d in walk:
            t += int(dt * S)
            run.events += [(t, "classifier", cls), (t + MS, "distance_to_target", d)]
        run.walks.append((start, t + 2 * MS))
    return run


def _walk(rng: random.Random, dt: float, v_in: float, closest: float) -> Iterator[tuple[int, int]]:
    """(classifier, distance in whole metres) per perception cycle: in from 8.5-11 m
    at ``v_in``, a dwell at ``closest``, away at 1.5-2.5 m/s (robot.walks' shape)."""
    cls = rng.choice((1, 2))
    d, end = rng.uniform(8.5, 11.0), rng.uniform(8.5, 11.0)
    while d > closest:
        yield cls, round(d)
        d -= v_in * dt
    for _ in range(max(1, round(rng.uniform(0.5, 1.5) / dt))):
        yield cls, round(closest)
    v_out, d = rng.uniform(1.5, 2.5), closest
    while d < end:
        yield cls, round(d)
        d += v_out * dt


def _wander(rng: random.Random, dt: float) -> Iterator[tuple[int, int]]:
    """A person working 5-9 m from the lamp for 10-30 s: a new pace of up to
    0.5 m/s either way every 1-3 s."""
    cls = rng.choice((1, 2))
    d = rng.uniform(5.0, 8.5)
    left = rng.uniform(10.0, 30.0)
    while left > 0:
        v, hold = rng.uniform(-0.5, 0.5), rng.uniform(1.0, 3.0)
        while hold > 0 and left > 0:
            d = min(9.0, max(5.0, d + v * dt))
            yield cls, round(d)
            hold -= dt
            left -= dt


def base_run(seed: int, speed: float, kind: str, approaches: int) -> Run:
    """``approaches`` drives at a wall from 3 m at ``speed``: approach runs slow down
    too late (at 0.3 m) and violate; near misses slow to 0.2 m/s at 1 m; clean runs
    drive 20-40 s along a corridor instead (see the module's docstring)."""
    rng = random.Random(f"base:{seed}:{speed}:{kind}")
    run = Run("mobile-base", kind, speed)
    t = S
    scan_ns, odom_ns = 25 * MS, 20 * MS
    wall = rng.uniform(1.5, 3.0)  # clean runs: the corridor's closest wall
    for _ in range(approaches):
        t += 20 * MS
        start = t
        if kind == "clean":
            t, wall = _corridor(rng, run, t, speed, wall)
            run.walks.append((start, t))
            continue
        x = 3.0 + rng.uniform(0.0, 1.0)  # the wall's distance
        v = 0.0
        next_scan = next_odom = t
        backing = 0.0
        while True:
            if t >= next_odom:
                run.events.append((t, "speed", round(v, 4)))
                next_odom += odom_ns
            if t >= next_scan:
                run.events.append((t + 1, "obstacle", round(x + rng.gauss(0.0, 0.01), 4)))
                next_scan += scan_ns
            step = 5 * MS
            t += step
            if backing > 0:
                x += v * step / S
                backing -= step / S
                if backing <= 0:
                    break
                continue
            slow_at = 1.0 if kind == "near_miss" else 0.3
            stop_at = 0.35 if kind == "near_miss" else 0.2
            v = speed if x > slow_at else min(speed, 0.2)
            if x <= stop_at:
                v, backing = 0.2, 4.0 + rng.uniform(0.0, 2.0)  # back off at a crawl
                continue
            x -= v * step / S
        run.walks.append((start, t))
        for _ in range(round(rng.uniform(0.5, 1.5) / 0.02)):  # standing, far from it
            t += 20 * MS
            run.events += [(t, "speed", 0.0), (t + 1, "obstacle", round(x, 4))]
    return run


def _corridor(rng: random.Random, run: Run, t: int, speed: float, x: float) -> tuple[int, float]:
    """20-40 s along a corridor at ``speed``, the closest wall 1.5-3 m away (``x`` at
    first) and drifting; returns the time and the distance reached."""
    drift = 0.0
    end = t + int(rng.uniform(20.0, 40.0) * S)
    k = 0
    while t < end:
        if k % 50 == 0:  # a new heading every second
            drift = rng.uniform(-0.2, 0.2)
        x = min(3.0, max(1.5, x + drift * 0.02))
        run.events.append((t, "speed", speed))
        if k % 5 < 4:  # 40 Hz scans beside 50 Hz odometry
            run.events.append((t + 1, "obstacle", round(x + rng.gauss(0.0, 0.01), 4)))
        t += 20 * MS
        k += 1
    return t, x


KINDS = ("approach", "near_miss", "clean")


def runs(scenario: str, seed: int, walks: Mapping[str, int]) -> list[Run]:
    """Per speed, one run of each kind, of ``walks[kind]`` walks (approaches)."""
    if scenario == "srobot":
        return [srobot_run(seed, v, k, walks[k]) for v in SROBOT_SPEEDS for k in KINDS]
    return [base_run(seed, v, k, walks[k]) for v in BASE_SPEEDS for k in KINDS]
