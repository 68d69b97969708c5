"""Recordings others can play: the daemon's bag carries each topic's offered QoS as
rosbag2 (Jazzy, metadata version 9) writes it, in metadata.yaml and in the MCAP
channel metadata, and ``ros_distro: jazzy``, so ``ros2 bag play`` keeps latching
(docs/reference/config.md, record).

Over real DDS: a robot node with a transient-local (latched) publisher and a reliable
volatile one, the daemon recording as a subprocess; the bag is read back with yaml,
the mcap reader and rosbags, and compared with rosbag2's own test bags' format.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from mcap.reader import make_reader  # noqa: E402
from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import QosDurability, QosReliability  # noqa: E402
from rosbags.rosbag2 import Reader  # noqa: E402
from rosutil import Daemon, wait_matched  # noqa: E402
from std_msgs.msg import Float64, Int64  # noqa: E402

from supervisor.daemon.recorder import bag_dirs  # noqa: E402

CONFIG = """\
component: R
step: {policy: on_message}
variables:
  gear: {type: int64, topic: /mode, msg: std_msgs/msg/Int64}
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
requirements:
  - id: mode_ok
    text: R shall always satisfy gear <= 3
    on_violation: [note]
  - id: slow
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
"""

# rosbag2's offered-QoS entry keys (rosbag2_storage/src/rosbag2_storage/qos.cpp, and
# tests/data/bags/sqlite3/cdr_test/metadata.yaml, rosbag2's own recording).
ROSBAG2_KEYS = set(
    yaml.safe_load(
        yaml.safe_load(
            (
                Path(__file__).resolve().parents[1] / "data/bags/sqlite3/cdr_test/metadata.yaml"
            ).read_text()
        )["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"][
            "offered_qos_profiles"
        ]
    )[0]
)


def test_the_recording_keeps_each_topics_offered_qos(tmp_path: Path, robot_node: Any) -> None:
    latched = QoSProfile(
        depth=1,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    mode = robot_node.create_publisher(Int64, "/mode", latched)
    speed = robot_node.create_publisher(Float64, "/speed", 10)  # reliable, volatile
    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    bags = tmp_path / "bags"
    d = Daemon(tmp_path, config, args=["--record", str(bags)])
    try:
        d.wait_notify("READY=1", timeout=30)
        wait_matched([mode, speed])
        mode.publish(Int64(data=7))
        speed.publish(Float64(data=2.5))  # the first tick has both inputs: two violations
        d.wait_record(lambda r: r.get("requirement") == "mode_ok", "the latched gear")
        d.wait_record(lambda r: r.get("requirement") == "slow", "the speed")
        d.terminate(budget=10)
    finally:
        d.close()

    (bag,) = [p for _, p in bag_dirs(bags)]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["ros_distro"] == "jazzy"
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    want = {"/mode": "transient_local", "/speed": "volatile"}
    for name, durability in want.items():
        meta = topics[name]["topic_metadata"]
        assert topics[name]["message_count"] == 1
        (profile,) = meta["offered_qos_profiles"]  # v9: a YAML list, policies by name
        assert set(profile) == ROSBAG2_KEYS
        assert profile["durability"] == durability
        assert profile["reliability"] == "reliable"
        assert profile["history"] in {"keep_last", "keep_all", "unknown", "system_default"}

    # The MCAP channel metadata: the same list, as the YAML text rosbag2's mcap plugin
    # writes under "offered_qos_profiles"; and the "rosbag2" metadata record's distro.
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        for name, durability in want.items():
            (profile,) = yaml.safe_load(channels[name].metadata["offered_qos_profiles"])
            assert profile["durability"] == durability
            assert profile["reliability"] == "reliable"
        serialized = next(
            m.metadata["serialized_metadata"] for m in reader.iter_metadata() if m.name == "rosbag2"
        )
        assert yaml.safe_load(serialized)["ros_distro"] == "jazzy"

    # rosbags parses it back into its QoS types.
    with Reader(bag) as r:
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    assert qos["/mode"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert qos["/speed"][0].durability == QosDurability.VOLATILE
    assert {q[0].reliability for t, q in qos.items() if t in want} == {QosReliability.RELIABLE}
