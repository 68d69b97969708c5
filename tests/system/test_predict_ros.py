"""Predictions in the daemon over real DDS (docs/reference/prediction.md): a scripted
walk toward the sRobot's lamp makes a ``prediction`` record and the early publish
action before the violation, which then carries its lead time."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import UV_DISTANCE, WALKING, Daemon, Robot, variant  # noqa: E402

RATE_HZ = 20  # the robot's publishing rate (rosutil.Robot.until's)
SPEED = 2.0  # m/s: the reading drops a whole metre every half second


def test_a_walk_toward_the_lamp_is_predicted_and_acted_on_early(
    tmp_path: Path, robot_node: Any
) -> None:
    config = variant(tmp_path, UV_DISTANCE)
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        robot = Robot(robot_node)
        robot.matched()
        robot.warm_up(d, dict(WALKING, distance_to_target=10))

        def walked() -> dict[str, Any] | None:
            for r in d.records():
                if r["event"] == "violation" and r["requirement"] == "uv_distance":
                    return r
            return None

        # 10 m to 2 m at 2 m/s, published at the robot's rate: the pace of the walk
        # is the test's input, so it is set by the clock, not awaited.
        start = time.monotonic()
        violation = None
        while violation is None:
            t = time.monotonic() - start
            robot.publish(
                dict(WALKING, distance_to_target=max(2, round(10 - SPEED * t))),
                gap_before_trigger=0.002,
            )
            violation = walked()
            assert t < 15, f"no violation of uv_distance\n{d.explain()}"
            time.sleep(1 / RATE_HZ)
        early = d.wait_record(
            lambda r: r["event"] == "mitigation" and r.get("stage") == "prediction",
            "the early slow_down",
            timeout=10,
        )
        lines = [json.loads(x) for x in d.log.read_text().splitlines()]
        (pred,) = [r for r in lines if r["event"] == "prediction"]
        violation = next(
            r for r in lines if r["event"] == "violation" and r["requirement"] == "uv_distance"
        )
        assert pred["requirement"] == "uv_distance" and pred["actions"] == ["slow_down"]
        assert early["action"] == "slow_down" and early["kind"] == "publish" and early["ok"]
        # the prediction's record, then its action, then the violation with its lead
        assert lines.index(pred) < lines.index(early) < lines.index(violation)
        assert violation["predicted_ms"] >= 500, (pred, violation)
        assert violation["policy_state"]["predicted_tick"] == pred["tick"]
    finally:
        d.close()
