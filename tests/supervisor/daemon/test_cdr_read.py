"""Reading one field from a serialized message (supervisor/daemon/cdr.py
``FieldPlan.read``), as the recording daemon does, against rclpy's own
deserialisation of the same bytes: random values, messages with strings and
sequences before the field, the types rclpy gives differently left to it."""

from __future__ import annotations

import math
import random

import pytest
from rosbags.typesys import Stores, get_typestore

pytest.importorskip("rclpy")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from mitigations.rosmsg import get_field, message_class  # noqa: E402
from supervisor.daemon.cdr import field_plan  # noqa: E402

STORE = get_typestore(Stores.ROS2_JAZZY)

CASES = [
    ("std_msgs/msg/Int64", "data"),
    ("std_msgs/msg/Bool", "data"),
    ("std_msgs/msg/Float32", "data"),
    ("std_msgs/msg/UInt64", "data"),
    ("std_msgs/msg/Int8", "data"),
    ("geometry_msgs/msg/Twist", "linear.x"),
    ("geometry_msgs/msg/Twist", "angular.z"),
    ("nav_msgs/msg/Odometry", "twist.twist.linear.x"),  # after a frame_id and a string
    ("sensor_msgs/msg/LaserScan", "range_min"),  # after the header's string
    ("sensor_msgs/msg/LaserScan", "scan_time"),
    ("sensor_msgs/msg/BatteryState", "percentage"),
    ("sensor_msgs/msg/Imu", "linear_acceleration.z"),  # after a float64[9] array
    ("sensor_msgs/msg/NavSatFix", "altitude"),
    ("diagnostic_msgs/msg/DiagnosticStatus", "level"),  # a byte: left to rclpy
]


def randomise(msg, rng: random.Random, depth: int = 0):
    """Every field set at random: numbers, strings of random length, sequences."""
    for name, typ in msg.get_fields_and_field_types().items():
        cur = getattr(msg, name)
        if typ == "boolean":
            setattr(msg, name, rng.random() < 0.5)
        elif typ in ("float", "double"):
            setattr(msg, name, rng.choice([rng.uniform(-1e6, 1e6), 0.0, -0.0, math.inf]))
        elif typ.startswith(("int", "uint")):
            bits = int("".join(c for c in typ if c.isdigit()))
            lo, hi = (
                (0, 2**bits - 1)
                if typ.startswith("u")
                else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
            )
            setattr(msg, name, rng.randint(lo, hi))
        elif typ == "octet":
            setattr(msg, name, bytes([rng.randint(0, 255)]))
        elif typ == "string":
            setattr(msg, name, "x" * rng.randint(0, 13))
        elif typ.startswith("sequence<float") or typ.startswith("sequence<double"):
            setattr(msg, name, [rng.random() for _ in range(rng.randint(0, 7))])
        elif hasattr(cur, "get_fields_and_field_types") and depth < 5:
            randomise(cur, rng, depth + 1)
    return msg


@pytest.mark.parametrize(("msgtype", "path"), CASES)
def test_read_equals_rclpy(msgtype, path):
    plan = field_plan(STORE, msgtype, path)
    klass = message_class(msgtype)
    rng = random.Random(msgtype + path)
    read_directly = 0
    for _ in range(200):
        data = serialize_message(randomise(klass(), rng))
        got = plan.read(data) if plan is not None else None
        if got is None:
            continue  # left to rclpy
        read_directly += 1
        want = get_field(deserialize_message(data, klass), path)  # what the daemon saw
        assert type(got) is type(want) and (got == want or (got != got and want != want))
    if msgtype.startswith("diagnostic_msgs"):
        assert read_directly == 0  # a byte field: rclpy gives bytes, read by rclpy
    else:
        assert read_directly == 200


def test_a_short_or_big_endian_payload_is_left_to_rclpy():
    plan = field_plan(STORE, "std_msgs/msg/Int64", "data")
    data = serialize_message(message_class("std_msgs/msg/Int64")(data=5))
    assert plan.read(data) == 5
    assert plan.read(data[:-1]) is None
    assert plan.read(b"\x00\x00\x00\x00" + data[4:]) is None  # big-endian CDR
