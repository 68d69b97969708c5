"""Array fields reduced to one value (``reduce:``, supervisor/inputs/reductions.py): against
a plain reference on random arrays, the config's checks, replay of a LaserScan
bag, and the daemon over real DDS (REP 117: NaN, infinite and out-of-range
readings are not obstacles)."""

from __future__ import annotations

import math
import random
import textwrap
from pathlib import Path
from typing import Any

import pytest

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.inputs.reductions import reduce_values
from supervisor.pipeline import project_for

BASE = """\
component: base
step: {policy: periodic, period_ms: 20}
variables:
  obstacle: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: ranges, reduce: min}
  speed:    {type: double, topic: /odom, msg: nav_msgs/msg/Odometry, field: twist.twist.linear.x}
requirements:
  - id: slow_near_obstacle
    text: base shall always satisfy (obstacle < 0.5 => speed <= 0.3)
    on_violation: [note]
    policy: {reset: after_mitigation}
mitigations:
  note: {log: {message: too fast near an obstacle}}
"""


def reference(values: list[float], how: str, bounds: tuple[float, float] | None) -> Any:
    if how == "len":
        return len(values)
    ok = [x for x in values if not math.isnan(x)]
    if bounds is not None:
        ok = [x for x in ok if math.isfinite(x) and bounds[0] <= x <= bounds[1]]
    if how == "count":
        return len(ok)
    if not ok:
        return {"min": math.inf, "max": -math.inf, "mean": math.nan, "sum": 0.0}[how]
    total = sum(ok)  # inf - inf is NaN, as in numpy
    return {"min": min(ok), "max": max(ok), "sum": total, "mean": total / len(ok)}[how]


@pytest.mark.parametrize("seed", range(20))
def test_reductions_equal_a_plain_reference(seed):
    rng = random.Random(seed)
    for _ in range(50):
        n = rng.choice([0, 1, 2, 7, 100])
        values = [
            rng.choice([math.nan, math.inf, -math.inf, 0.0, rng.uniform(-5, 40)]) for _ in range(n)
        ]
        bounds = rng.choice([None, (0.1, 30.0)])
        for how in ("min", "max", "count", "len", "sum", "mean"):
            got = reduce_values(values, how, bounds)
            want = reference(values, how, bounds)
            if isinstance(want, float) and math.isnan(want):
                assert math.isnan(got), how
            elif how in ("sum", "mean"):
                assert got == pytest.approx(want, rel=1e-12, abs=1e-12), (how, values)
            else:
                assert got == want, (how, values, bounds)
    assert reduce_values([1, 5, 3], "max") == 5 and isinstance(reduce_values([1, 5], "sum"), int)
    assert reduce_values([True, False], "any") is True and reduce_values([], "all") is True


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(textwrap.dedent(text))
    return p


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (
            ("field: ranges, reduce: min", "field: ranges, reduce: median"),
            "unknown reduce 'median'",
        ),
        (("field: ranges, reduce: min", "reduce: min"), "reduce needs the array's field"),
    ],
)
def test_bad_reductions_are_located(tmp_path, edit, needle):
    with pytest.raises(UserError) as e:
        load_config(write(tmp_path, BASE.replace(*edit)))
    assert needle in e.value.message and e.value.line == 4


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (("field: ranges, reduce: min", "field: range_min, reduce: min"), "not an array"),
        (
            ("obstacle: {type: double", "obstacle: {type: bool"),
            "gives min of float, which cannot feed a bool variable",
        ),
    ],
)
def test_check_knows_what_a_reduction_gives(tmp_path, edit, needle):
    project = project_for(write(tmp_path, BASE.replace(*edit)))
    err = project.first_error()
    assert err is not None and needle in err.message and err.line == 4


def _scan(ranges: list[float]) -> Any:
    from sensor_msgs.msg import LaserScan

    msg = LaserScan()
    msg.range_min, msg.range_max = 0.1, 30.0
    msg.ranges = ranges
    return msg


def test_replay_of_a_laserscan_bag(tmp_path):
    """A bag written with rosbags: the closest valid reading crosses 0.5 m at the
    4th scan while the robot moves at 0.4 m/s; NaN, inf and 0.05 m (below
    range_min) before that are not obstacles."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from supervisor.tools.replay.session import replay_files

    ts = get_typestore(Stores.ROS2_JAZZY)
    scan_t, odom_t = "sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry"
    Scan = ts.types[scan_t]
    import numpy as np

    def scan(ranges: list[float]) -> Any:
        header = ts.types["std_msgs/msg/Header"](
            stamp=ts.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="laser"
        )
        return Scan(
            header=header, angle_min=0.0, angle_max=1.0, angle_increment=0.1,
            time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=30.0,
            ranges=np.array(ranges, dtype=np.float32), intensities=np.array([], dtype=np.float32),
        )  # fmt: skip

    bag = tmp_path / "bag"
    scans = [[2.0, math.nan], [1.0, math.inf], [0.05, 3.0], [0.4, 5.0], [3.0]]
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cs = w.add_connection("/scan", scan_t, typestore=ts)
        co = w.add_connection("/odom", odom_t, typestore=ts)
        from rclpy.serialization import serialize_message

        from mitigations.rosmsg import message_class

        o = message_class(odom_t)()
        o.twist.twist.linear.x = 0.4
        odom_bytes = serialize_message(o)
        for k, ranges in enumerate(scans):
            t = 10**9 + k * 100_000_000
            w.write(co, t, odom_bytes)
            w.write(cs, t + 1, bytes(ts.serialize_cdr(scan(ranges), scan_t)))
    result = replay_files(write(tmp_path, BASE), [bag], tmp_path / "out.jsonl", None)
    assert result["error"] is None
    from mitigations.violationlog.reader import iter_records

    obstacles = [
        r["inputs"]["obstacle"] for r in iter_records(str(tmp_path / "out.jsonl"))
        if r["event"] == "violation"
    ]  # fmt: skip
    assert obstacles and all(o == pytest.approx(0.4) for o in obstacles)


@pytest.mark.ros
def test_an_obstacle_while_moving_is_caught_over_dds(tmp_path: Path, robot_node: Any):
    from nav_msgs.msg import Odometry
    from rosutil import Daemon, StatusWatch, messages, wait_matched
    from sensor_msgs.msg import LaserScan

    # a status document a tick: what the daemon has received and judged, awaited
    d = Daemon(tmp_path, write(tmp_path, BASE + "ros: {status_ms: 20}\n"))
    try:
        d.wait_notify("READY=1", timeout=30)
        status = StatusWatch(robot_node)
        scan = robot_node.create_publisher(LaserScan, "/scan", 10)
        odom = robot_node.create_publisher(Odometry, "/odom", 10)
        wait_matched([scan, odom])
        moving = Odometry()
        moving.twist.twist.linear.x = 0.4
        odom.publish(moving)
        # invalid readings (NaN, inf, below range_min) are not obstacles
        for n, ranges in enumerate(([math.nan, 2.0], [math.inf, 1.5], [0.05, 3.0]), 1):
            scan.publish(_scan(ranges))
            got = status.until(
                f"scan {n} received", lambda doc, n=n: messages(doc, "obstacle") == n
            )
            status.until(f"scan {n} judged", lambda doc, got=got: doc["ticks"] > got["ticks"])
        assert not [r for r in d.records() if r["event"] == "violation"], d.explain()
        scan.publish(_scan([0.4, 5.0]))  # a valid reading at 0.4 m while moving
        v = d.wait_record(lambda r: r["event"] == "violation", "the obstacle violation", 5)
        assert v["requirement"] == "slow_near_obstacle"
        assert v["inputs"]["obstacle"] == pytest.approx(0.4)
        d.terminate()
    finally:
        d.close()
