"""Margins and predictions on the operator's page, with the real daemon over DDS.

The daemon (margins on, the sRobot's "nobody within 3 m while the UV light is on"
predicted) and ``safety-supervisor ui`` as processes on the test run's ROS domain,
the page in headless Chromium: each requirement's gauge shows the margin the daemon
published, a walk toward the lamp shows its prediction before the violation, and a
second node's status with a NaN or huge margin is refused and counted
(docs/reference/ros-interfaces.md, "Status").
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path
from typing import Any

import pytest
from browser import eval_all, open_page

from tests.system.test_ui import TOKEN, UiProcess, free_port

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import UV_DISTANCE, WALKING, Daemon, Robot, variant, wait_until  # noqa: E402

MARGINS_ON = ("  trigger: turnoffUVC\n", "  trigger: turnoffUVC\n  margins: true\n")
ROW = "tr.req[data-requirement='uv_distance'] .margin"


def _published(ui: UiProcess) -> Any:
    """uv_distance's margin as the UI last received it from the daemon."""
    doc = ui.state()["status"] or {}
    for r in doc.get("requirements", []):
        if r["id"] == "uv_distance":
            return r["margin"]
    return None


def _forger(robot_node: Any) -> tuple[Any, Any]:
    from rclpy.node import Node

    from tests.system.test_ui_trust import _latched_publisher

    node = Node("margin_forger", context=robot_node.context)
    return node, _latched_publisher(node)  # the QoS the UI subscribes with


@pytest.mark.slow
def test_the_page_shows_the_published_margins_and_a_prediction(
    tmp_path: Path, robot_node: Any
) -> None:
    from std_msgs.msg import String

    config = variant(tmp_path, UV_DISTANCE, MARGINS_ON)
    token_file = tmp_path / "ui.token"
    token_file.write_bytes(TOKEN + b"\n")
    token_file.chmod(0o640)
    d = Daemon(tmp_path, config)
    ui: UiProcess | None = None
    pw = forger = None
    try:
        d.wait_notify("READY=1", timeout=60)
        ui = UiProcess(tmp_path, free_port(), token_file, None)
        ui.wait_status()
        robot = Robot(robot_node)
        robot.matched()
        robot.warm_up(d, dict(WALKING, distance_to_target=9))
        pw, page, console, requests = open_page(ui.url)

        # a person standing 9 m away: the margin is 9 - 3 m, on the page as published
        def shown() -> str | None:
            robot.publish(dict(WALKING, distance_to_target=9), gap_before_trigger=0.002)
            el = page.query_selector(ROW)
            return el.get_attribute("data-margin") if el else None

        wait_until("the margin on the page", lambda: shown() == "6", 15, d.explain)
        published = _published(ui)
        assert published["value"] == 6.0 and published["prediction"] is None, published
        assert "distance_to_target" in published["unit"], published
        value_text = page.inner_text(ROW + " .value")
        assert value_text == "6", value_text
        assert "distance_to_target" in page.inner_text(ROW)
        # the other requirements' margins (step.margins) are shown too, each as published
        doc = ui.state()["status"]
        for r in doc["requirements"]:
            assert r["margin"] is not None, r
        gauges = eval_all(
            page,
            "tr.req .margin",
            "es => es.map(e => [e.closest('tr').dataset.requirement, e.dataset.margin])",
        )
        assert {g[0] for g in gauges} == {r["id"] for r in doc["requirements"]}, gauges

        # a forged document from a second node: a NaN margin, then a huge one; each
        # refused with its field named, counted, and the page keeps the daemon's
        forger, pub = _forger(robot_node)
        wait_until("the forger's match", lambda: pub.get_subscription_count() > 0, 15)
        for i, bad in enumerate((float("nan"), 1e300), start=1):
            before = ui.state()["invalid"]["count"]
            forged = copy.deepcopy(ui.state()["status"])
            forged["supervisor"] = "forger"
            for r in forged["requirements"]:
                if r["margin"] is not None:
                    r["margin"]["value"] = bad
            pub.publish(String(data=json.dumps(forged)))  # NaN as JSON's NaN literal
            wait_until(f"forged document {i} counted",
                       lambda b=before: ui.state()["invalid"]["count"] > b, 10)  # fmt: skip
            why = ui.state()["invalid"]["why"]
            assert "margin.value" in why and len(why.splitlines()) == 1, why
        page.wait_for_selector("#trust-invalid:not([hidden])")
        assert (ui.state()["status"] or {})["supervisor"] != "forger"
        assert page.get_attribute(ROW, "data-margin") == "6"

        # a walk toward the lamp at 1 m/s: the prediction is on the page (its time to
        # violation, distinct from the margin) before the violation is logged
        start = time.monotonic()
        predicted_at = ttv = None
        while not any(
            r["event"] == "violation" and r["requirement"] == "uv_distance" for r in d.records()
        ):
            t = time.monotonic() - start
            robot.publish(
                dict(WALKING, distance_to_target=max(2, round(9 - t))), gap_before_trigger=0.002
            )
            el = page.query_selector(ROW + " .predicted")
            if el is not None and predicted_at is None:
                predicted_at, ttv = time.monotonic(), el.get_attribute("data-ttv-ms")
            assert t < 15, f"no violation of uv_distance\n{d.explain()}"
            page.wait_for_timeout(50)  # the robot's publishing period
        assert predicted_at is not None, "no prediction shown before the violation"
        assert ttv and 0 < float(ttv) <= 1500, ttv
        lines = [json.loads(x) for x in d.log.read_text().splitlines()]
        assert [r["requirement"] for r in lines if r["event"] == "prediction"] == ["uv_distance"]
        # a margin below 0 is drawn on the other side of the gauge

        def negative() -> bool:
            robot.publish(dict(WALKING, distance_to_target=2), gap_before_trigger=0.002)
            return page.query_selector(ROW + " rect.neg") is not None

        wait_until("the negative margin on the page", negative, 10, d.explain)
        assert console == [], console
        assert all(u.startswith(ui.url) for u in requests), requests
    finally:
        if pw is not None:
            pw.stop()
        if forger is not None:
            forger.destroy_node()
        if ui is not None:
            ui.child.stop()
        d.close()
