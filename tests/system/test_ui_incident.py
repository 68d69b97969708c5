"""An incident on the operator's page, with the real daemon over DDS.

The daemon and ``safety-supervisor ui`` as processes on the test run's ROS domain,
the page in headless Chromium: a float32 input shows at its precision, a
requirement the policy resets within milliseconds stays shown violated (in red,
first) while the daemon says it holds, and a restarted daemon is marked in the feed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from browser import eval_all, open_page

from tests.system.test_ui import TOKEN, UiProcess, free_port, wait_js

CONFIG = """\
component: R
step: {policy: on_message}
variables:
  speed: {type: double, topic: /incident_speed, msg: std_msgs/msg/Float32}
requirements:
  - id: calm
    text: R shall always satisfy speed > -100.0
    on_violation: [note]
  - id: limit
    text: R shall always satisfy speed <= 1.0
    on_violation: [note]
    policy: {reset: after_mitigation}
mitigations:
  note: {log: {message: too fast}}
ros: {status_ms: 100}
"""
ROW = "document.querySelector(\"tr.req[data-requirement='limit']\")"


@pytest.mark.ros
@pytest.mark.slow
def test_an_incident_on_the_page_with_the_real_daemon(tmp_path: Path, robot_node: Any) -> None:
    from rosutil import Daemon, wait_matched, wait_until
    from std_msgs.msg import Float32

    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    token_file = tmp_path / "ui.token"
    token_file.write_bytes(TOKEN + b"\n")
    token_file.chmod(0o640)
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    d = Daemon(first, config)
    d2: Daemon | None = None
    ui: UiProcess | None = None
    pw = None
    try:
        d.wait_notify("READY=1", timeout=60)
        ui = UiProcess(tmp_path, free_port(), token_file, None)
        ui.wait_status()
        speed = robot_node.create_publisher(Float32, "/incident_speed", 10)
        wait_matched([speed])
        pw, page, console, requests = open_page(ui.url)
        value = "document.querySelector(\"tr.input[data-input='speed'] .value\")?.textContent"
        wait_until("0.8 on the page", lambda: (speed.publish(Float32(data=0.8)),
                   page.evaluate(f"() => {value}"))[1] == "0.8", 15)  # fmt: skip
        assert [r[0] for r in rows(page)] == ["calm", "limit"]

        # too fast once: the policy resets 'limit' at once; the page keeps it violated
        speed.publish(Float32(data=1.5))
        d.wait_record(lambda r: r["event"] == "violation", "the violation")
        speed.publish(Float32(data=0.8))
        wait_js(page, f"{ROW} && {ROW}.dataset.daemonState === 'holding'", 10)
        wait_until(
            "the daemon's documents say it holds again",
            lambda: (
                {r["id"]: r["state"] for r in ui.state()["status"]["requirements"]}["limit"]
                == "holding"
                if ui
                else False
            ),
            10,
        )
        # The document that says 'holding' and the violation's message reach the page
        # on two topics, in either order: the violation is shown first once both are in
        wait_until(
            "'limit' first, shown violated",
            lambda: rows(page)[0] == ["limit", "violated"],
            5,
        )
        badge = page.inner_text("tr.req[data-requirement='limit'] .state")
        assert badge.startswith("violated ") and badge.endswith(" s ago"), badge

        # the daemon dies and is started again: the new one's first document marks the feed
        d.child.kill()
        d2 = Daemon(second, config)
        d2.wait_notify("READY=1", timeout=60)
        pid = d2.proc.pid
        wait_js(page, "document.querySelector('#feed li.restart') !== null", 20)
        assert f"pid {pid}" in page.inner_text("#feed li.restart")
        # the old daemon's violation is below the mark
        order = eval_all(page, "#feed li", "ls => ls.map(l => l.dataset.event)")
        assert order.index("restart") < order.index("violation"), order
        # the previous daemon's violation is still held on the page after the restart
        assert rows(page)[0] == ["limit", "violated"], rows(page)
        assert [m for m in console if "ERR_CONNECTION_REFUSED" not in m] == [], console
        assert all(u.startswith(ui.url) for u in requests), requests
    finally:
        if pw is not None:
            pw.stop()
        if ui is not None:
            ui.child.stop()
        d.close()
        if d2 is not None:
            d2.close()


def rows(page: Any) -> list[list[str]]:
    return eval_all(page, "tr.req", "rs => rs.map(r => [r.dataset.requirement, r.dataset.state])")
