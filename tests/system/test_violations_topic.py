"""``/safety_supervisor/violations`` (docs/reference/ros-interfaces.md): every
violation record the real daemon writes is also published on the topic, not only
the first batch (the ``ui`` shows what this topic carries)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros

CONFIG = """\
component: R
step: {policy: on_message}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
    policy: {reset: after_mitigation}  # the next violation is a new one
mitigations:
  note: {log: {message: violated}}
"""


def test_every_violation_record_is_published(tmp_path: Path, robot_node: Any) -> None:
    from rosutil import Daemon, spin_until, wait_matched
    from std_msgs.msg import Float64, String

    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        seen: list[dict[str, Any]] = []
        sub = robot_node.create_subscription(
            String, "/safety_supervisor/violations", lambda m: seen.append(json.loads(m.data)), 10
        )
        speed = robot_node.create_publisher(Float64, "/speed", 10)
        wait_matched([speed])
        spin_until(
            robot_node, "the daemon's violations publisher", lambda: sub.get_publisher_count(), 15
        )
        # Three episodes (violated, then holding again): three records, three messages.
        for n in range(1, 4):
            speed.publish(Float64(data=3.0))
            d.wait_record(
                lambda r, n=n: sum(x["event"] == "violation" for x in d.records()) >= n,
                f"violation record {n}",
            )
            speed.publish(Float64(data=1.0))
        written = [r["tick"] for r in d.records() if r["event"] == "violation"]
        assert len(written) == 3, written
        spin_until(robot_node, "three messages on the violations topic", lambda: len(seen) >= 3, 10)
        assert [m["tick"] for m in seen] == written
        assert all(m["event"] == "violation" and m["requirement"] == "limit" for m in seen)
        d.terminate()
    finally:
        d.close()
