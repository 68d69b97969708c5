"""A dead supervisor is visible on the operator's page.

Real components only: the daemon and ``safety-supervisor ui`` as processes on the
test run's ROS domain, the page in headless Chromium.  The daemon is killed
(SIGKILL: no last document) while the page's stream stays open, then started
again; then the UI itself is killed, so the browser loses its stream.  Each time
the page must say "no status for N s" with N counting up, show nothing green, and
turn live again when status documents flow.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest
from browser import open_page

from tests.system.test_ui import TOKEN, UiProcess, free_port, wait_js

# The page's greens (state-holding and the like): a page that is not live shows none.
GREENS = ("rgb(200, 230, 201)", "rgb(27, 94, 32)", "rgb(76, 175, 80)")
GREEN_SHOWN = (
    "[...document.querySelectorAll('*')].filter(e => e.offsetParent !== null || e === document.body)"
    ".map(e => getComputedStyle(e)).some(s => "
    + " || ".join(f"s.color === '{g}' || s.backgroundColor === '{g}'" for g in GREENS)
    + ")"
)


def quiet_seconds(page: Any) -> int | None:
    """N of the visible "no status for N s", or None when it is not shown."""
    if not page.is_visible("#quiet"):
        return None
    m = re.fullmatch(r"no status for (\d+) s", page.inner_text("#quiet").strip())
    return int(m.group(1)) if m else None


def assert_not_live(page: Any, what: str) -> float:
    """The badge is shown and counts up, the header does not say live, nothing is
    green.  When the badge was first seen (monotonic)."""
    wait_js(page, "getComputedStyle(document.getElementById('quiet')).display !== 'none'", 10)
    shown = time.monotonic()
    first = quiet_seconds(page)
    assert first is not None, (what, page.inner_text("header"))
    uptime = page.inner_text("#uptime")
    deadline = time.monotonic() + 5
    while (n := quiet_seconds(page)) is not None and n <= first:
        assert time.monotonic() < deadline, f"{what}: the age stays at {n} s"
        page.wait_for_timeout(100)
    assert n is not None and n > first, (what, page.inner_text("header"))
    # a dead supervisor's uptime does not go on: it is the last document's
    assert page.inner_text("#uptime") == uptime, (what, uptime, page.inner_text("#uptime"))
    assert page.inner_text("#conn").strip() != "live", (what, page.inner_text("header"))
    assert page.get_attribute("body", "data-live") == "0", what
    assert not page.evaluate(f"() => {GREEN_SHOWN}"), f"{what}: something is still green"
    return shown


def assert_live(page: Any, what: str) -> None:
    wait_js(page, "document.body.dataset.live === '1'", 20)
    assert page.inner_text("#conn").strip() == "live", (what, page.inner_text("header"))
    assert not page.is_visible("#quiet"), (what, page.inner_text("header"))


@pytest.mark.ros
@pytest.mark.slow
def test_the_page_says_when_the_supervisor_or_its_stream_is_gone(
    tmp_path: Path, robot_node: Any
) -> None:
    from rosutil import S0, Daemon, Robot, variant

    config = variant(tmp_path)
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
        port = free_port()
        ui = UiProcess(tmp_path, port, token_file, None)
        ui.wait_status()
        robot = Robot(robot_node)
        robot.matched()
        robot.warm_up(d, S0)
        pw, page, console, _requests = open_page(ui.url)
        assert_live(page, "with the daemon running")
        # the requirements hold: the page is green while it is live
        assert page.evaluate(f"() => {GREEN_SHOWN}"), "a live page with holding requirements"

        # the daemon dies; the UI and the page's stream stay up
        t_kill = time.monotonic()  # kill() returns once reaped: take the time first
        d.child.kill()
        shown = assert_not_live(page, "the daemon killed")
        print(f"\nUI: not live {shown - t_kill:.2f} s after the daemon's SIGKILL")

        # the daemon comes back
        d2 = Daemon(second, config)
        d2.wait_notify("READY=1", timeout=60)
        t_back = time.monotonic()
        assert_live(page, "the daemon restarted")
        print(f"UI: live {time.monotonic() - t_back:.2f} s after the new daemon's READY=1")

        # the UI dies: the page's stream breaks, and its own clock says so
        t_kill = time.monotonic()
        ui.child.kill()
        ui = None
        shown = assert_not_live(page, "the UI killed")
        print(f"UI: not live {shown - t_kill:.2f} s after the UI's SIGKILL")
        assert page.inner_text("#conn").strip() == "reconnecting"
        assert [m for m in console if "ERR_CONNECTION_REFUSED" not in m] == [], console
    finally:
        if pw is not None:
            pw.stop()
        if ui is not None:
            ui.child.stop()
        d.close()
        if d2 is not None:
            d2.close()


def test_the_fleet_takes_the_period_the_documents_announce() -> None:
    """One document with ``status_period_s`` sets the bound (3 periods), without
    waiting for a second document; a robot with a slow status is not called lost."""
    from supervisor.tools.ui.fleet import Fleet, RobotSpec
    from tests.system.test_ui_fleet import Clock, doc_of

    clock = Clock()
    fleet = Fleet(
        [RobotSpec("r1", "/robot1", 3)], lambda doc, sock: {"available": False, "why": "t"}, clock
    )
    r1 = fleet.robot("r1")
    assert r1 is not None
    fleet.on_status(r1, doc_of("robot1", "/none", "2026-11-23T17:05:00Z", status_period_s=2.0))
    assert fleet.row(r1)["lost_after_s"] == 6.0
    clock.t += 5.9
    assert fleet.row(r1)["state"] == "live"
    clock.t += 0.2
    assert fleet.row(r1)["state"] == "lost"
