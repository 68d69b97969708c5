"""``safety-supervisor ui --fleet``: several supervisors in one UI.

Without DDS: the fleet file's errors, the rows (lost, never removed; discovered
ones), each robot's own page, stream and resets, served in this process.  In
headless Chromium: the fleet page going LOST, and keeping up with a hundred robots.
Over real DDS: supervisors in two namespaces and on a second domain, one listed, one
discovered, one stopped.
"""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from browser import eval_all, open_page

from monitors.errors import UserError
from supervisor.tools.ui.fleet import Fleet, RobotSpec, load_fleet, local_reset_availability
from supervisor.tools.ui.server import UiServer, reset_availability
from tests.system.test_ui import ROOT, TOKEN, FakeControl, http, post_reset, status_doc, wait_js

HERE = socket.gethostname()

# ---------------------------------------------------------------- the fleet file


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ("- {name: r1, namespace: /robot1}\n- {name: r2, domain: 300}\n", 2, "0 to 232"),
        ("- {name: r1}\n- name: r1\n  namespace: /x\n", 2, "listed twice (first at line 1)"),
        ("- {name: r1, namspace: /robot1}\n", 1, "did you mean 'namespace'"),
        ("robots: []\n", 1, "non-empty list of robots"),
        ("[]\n", 1, "non-empty list of robots"),
        ("- {name: r1, namespace: 'a b'}\n", 1, "must be a ROS namespace"),
        ("- {name: r1}\n- {name: r2, namespace: /}\n", 2, "namespace and domain of 'r1'"),
        ("- {name: r1}\n- {namespace: /x}\n", 2, "needs a 'name'"),
        ("- {name: 'r 1'}\n", 1, "'name' must be letters"),
        ("- {name: r1, domain: two}\n", 1, "'domain' must be a whole number"),
        ("- {name: r1}\n- just a name\n", 2, "must be a mapping"),
        ("- {name: r1}\n- {name: r2, namespace: /b, socket: 5}\n", 2, "'socket' must be a path"),
        ("- {name: r1\n", 2, "invalid YAML"),
    ],
)
def test_a_bad_fleet_file_is_one_line_at_its_line(
    tmp_path: Path, text: str, line: int, message: str
) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(text)
    with pytest.raises(UserError) as e:
        load_fleet(path, env={})
    shown = str(e.value)
    assert shown.startswith(f"{path}:{line}:") and message in shown, shown
    assert "\n" not in shown


def test_the_fleet_file_defaults_and_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        "- {name: a}\n- {name: b, namespace: robot2/, domain: 7}\n- {name: c, namespace: /c, socket: c.sock}\n"
    )
    env = {"ROS_DOMAIN_ID": "5", "XDG_RUNTIME_DIR": "/run/user/7"}
    assert [(r.name, r.namespace, r.domain, r.socket) for r in load_fleet(path, env)] == [
        # without socket: where `reset` looks for a supervisor of that domain
        ("a", "/", 5, "/run/user/7/safety-supervisor/control-5.sock"),
        ("b", "/robot2", 7, "/run/user/7/safety-supervisor/control-7.sock"),
        ("c", "/c", 5, str(tmp_path / "c.sock")),  # relative to the file
    ]
    path.write_text("- {name: a, domain: -1}\n")
    for extra in ([], ["--namespace", "/x"]):
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", "ui", "--fleet", str(path),
             "--bind", "127.0.0.1:0", *extra],
            capture_output=True, text=True, timeout=60, cwd=ROOT,
        )  # fmt: skip
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert (f"{path}:1:" if not extra else "--namespace") in r.stderr, r.stderr


# ---------------------------------------------------------------- without DDS


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def doc_of(name: str, sock: str, now: str, host: str = HERE, **over: Any) -> dict[str, Any]:
    return status_doc(sock, supervisor=f"{host}:/{name}/safety_supervisor", now=now, **over)


def test_rows_go_lost_and_stay_and_discovered_robots_join() -> None:
    clock = Clock()
    fleet = Fleet(
        [RobotSpec("r1", "/robot1", 3), RobotSpec("r2", "/robot2", 4)],
        lambda doc, sock: {"available": False, "why": "test"},
        clock,
    )
    assert fleet.domains() == [3, 4]
    r1 = fleet.robot("r1")
    assert r1 is not None
    q = fleet.subscribe()
    assert [r["state"] for r in json.loads(q.get_nowait())["robots"]] == ["waiting", "waiting"]
    fleet.on_status(r1, doc_of("robot1", "/none", "2026-11-23T17:05:00.000000Z"))
    row = fleet.row(r1)
    assert row["state"] == "live" and row["lost_after_s"] == 3.0  # no period yet
    assert row["host"] == HERE and row["open"] == ["operationalstate_2"]  # latched
    clock.t += 0.5
    fleet.on_status(r1, doc_of("robot1", "/none", "2026-11-23T17:05:00.500000Z"))
    assert fleet.row(r1)["lost_after_s"] == 1.5  # 3 periods of 0.5 s
    clock.t += 1.4
    assert fleet.row(r1)["state"] == "live"
    clock.t += 0.2
    assert fleet.row(r1)["state"] == "lost"
    clock.t += 3600
    assert [r["id"] for r in fleet.snapshot()["robots"]] == ["r1", "r2"]  # never removed
    # a supervisor found on a domain's graph joins; a listed one is not added twice
    assert fleet.watch(3, "/robot1") == (r1, False)
    new, added = fleet.watch(3, "/robot9")
    assert added and new.id == "d3-robot9" and not new.configured
    assert fleet.watch(3, "/")[0].id == "d3-root"
    messages = [json.loads(q.get_nowait()) for _ in range(q.qsize())]
    assert [m["robot"]["id"] for m in messages] == ["r1", "r1", "d3-robot9", "d3-root"]


def test_resets_only_for_a_supervisor_on_this_machine(tmp_path: Path) -> None:
    control = FakeControl(tmp_path / "ctl.sock")
    try:
        sock = str(control.path)
        doc = doc_of("robot1", "/forged.sock", "t")
        state = local_reset_availability(doc, sock, TOKEN, reset_availability)
        assert state["available"] and state["socket"] == sock  # the fleet file's, not the doc's
        far = doc_of("robot1", sock, "t", host="elsewhere")
        state = local_reset_availability(far, sock, TOKEN, reset_availability)
        assert not state["available"] and "elsewhere" in state["why"]
        assert not local_reset_availability(None, sock, TOKEN, reset_availability)["available"]
        # a discovered supervisor has no socket of its own: its document cannot give one
        state = local_reset_availability(
            doc_of("robot1", sock, "t"), None, TOKEN, reset_availability
        )
        assert not state["available"] and "fleet file" in state["why"]
    finally:
        control.close()


@pytest.fixture
def fleet_served(tmp_path: Path) -> Iterator[tuple[UiServer, Fleet, FakeControl]]:
    control = FakeControl(tmp_path / "ctl.sock")
    fleet = Fleet(
        [RobotSpec("r1", "/robot1", 0, socket=str(control.path)),
         RobotSpec("r2", "/robot2", 0, socket="/nonexistent")],
        lambda doc, sock: local_reset_availability(doc, sock, TOKEN, reset_availability),
    )  # fmt: skip
    server = UiServer(("127.0.0.1", 0), None, TOKEN, lambda: None, fleet=fleet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield server, fleet, control
    finally:
        server.stop()
        control.close()


def robot(fleet: Fleet, rid: str) -> Any:
    r = fleet.robot(rid)
    assert r is not None
    return r


def test_each_robot_has_its_own_page_stream_and_reset(fleet_served: Any) -> None:
    server, fleet, control = fleet_served
    base = server.url()
    r1, r2 = robot(fleet, "r1"), robot(fleet, "r2")
    # r1's document names another socket: resets still go to the fleet file's
    fleet.on_status(r1, doc_of("robot1", "/forged.sock", "t", component="one"))
    fleet.on_status(r2, doc_of("robot2", "/nonexistent", "t", host="far", component="two"))
    code, headers, body = http(base)
    assert code == 200 and "safety-supervisor fleet" in body.decode()
    assert "default-src 'none'" in headers["Content-Security-Policy"]
    assert http(base + "fleet")[0] == 200
    rows = json.loads(http(base + "api/fleet")[2])["robots"]
    assert [(r["id"], r["component"]) for r in rows] == [("r1", "one"), ("r2", "two")]
    page = http(base + "robot/r1")[2].decode()
    # every placeholder filled in (the CSP nonce itself may hold "__": token_urlsafe)
    assert '"/robot/r1"' in page and 'href="/fleet"' in page
    assert not re.search(r"__[A-Z_]+__", page), re.findall(r"__[A-Z_]+__", page)
    assert http(base + "robot/nobody")[0] == 404
    assert http(base + "events")[0] == 404  # the single robot's paths are not the fleet's
    assert json.loads(http(base + "robot/r2/api/state")[2])["status"]["component"] == "two"
    state = json.loads(http(base + "robot/r2/api/state")[2])
    assert not state["reset"]["available"] and "far" in state["reset"]["why"]
    # a robot's stream carries only that robot
    q = r1.hub.subscribe()
    assert json.loads(q.get_nowait())["status"]["component"] == "one"
    fleet.on_violation(r2, {"event": "violation", "requirement": "x", "tick": 1})
    fleet.on_status(r2, doc_of("robot2", "/nonexistent", "t2", host="far", component="two"))
    fleet.on_status(r1, doc_of("robot1", str(control.path), "t2", component="one"))
    assert [json.loads(q.get_nowait())["status"]["component"] for _ in range(q.qsize())] == ["one"]
    r1.hub.unsubscribe(q)
    # resets: the local supervisor's socket; the far one's never
    auth = "Bearer " + TOKEN.decode()
    assert post_reset(base + "robot/r1/", {"requirement": "state_req103"}) == 401
    assert (
        post_reset(base + "robot/r1/", {"requirement": "state_req103"}, Authorization=auth) == 200
    )
    assert post_reset(base + "robot/r2/", Authorization=auth) == 503
    assert post_reset(base, Authorization=auth) == 404
    assert control.requests == [
        {"command": "reset", "via": "ui", "client": "127.0.0.1", "requirement": "state_req103"}
    ]


def test_a_robots_invalid_documents_and_second_publisher_are_on_its_row() -> None:
    fleet = Fleet(
        [RobotSpec("r1", "/robot1", 0)], lambda doc, sock: {"available": False, "why": "t"}
    )
    r1 = robot(fleet, "r1")
    fleet.receive_status(r1, json.dumps(doc_of("robot1", "/x", "t", component="one")), lambda: "/a")
    forged = doc_of("robot1", "/x", "t2", component="<b>two</b>", lost="many")
    fleet.receive_status(r1, json.dumps(forged), lambda: "/forger")
    fleet.on_publishers(r1, ["/forger", "/robot1/safety_supervisor"])
    row = fleet.row(r1)
    assert row["component"] == "one" and row["invalid"] == 1 and row["publishers"] == 2
    assert r1.hub.invalid["publisher"] == "/forger" and "lost" in r1.hub.invalid["why"]


def test_one_listed_robot_is_the_page_and_the_single_ui_has_no_fleet(tmp_path: Path) -> None:
    from supervisor.tools.ui.hub import Hub

    fleet = Fleet([RobotSpec("solo", "/", 0)], lambda doc, sock: {"available": False, "why": "t"})
    server = UiServer(("127.0.0.1", 0), None, None, lambda: None, fleet=fleet)
    single = UiServer(("127.0.0.1", 0), Hub(lambda d: {}), None, lambda: None)
    for s in (server, single):
        threading.Thread(target=s.serve_forever, daemon=True).start()
    try:
        req = urllib_request(server.url())
        assert req == (303, "/robot/solo")
        assert http(server.url() + "fleet")[0] == 200
        assert http(single.url() + "fleet")[0] == 404
        assert http(single.url() + "robot/solo")[0] == 404
    finally:
        server.stop()
        single.stop()


def urllib_request(url: str) -> tuple[int, str]:
    """The status and Location of a GET, redirects not followed."""
    import http.client
    from urllib.parse import urlsplit

    u = urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    conn.request("GET", "/")
    r = conn.getresponse()
    conn.close()
    return r.status, r.getheader("Location") or ""


# ---------------------------------------------------------------- in the browser


def fleet_rows(page: Any) -> dict[str, dict[str, Any]]:
    return {
        r[0]: {"state": r[1], "open": r[2], "text": r[3]}
        for r in eval_all(
            page,
            "tr.robot",
            "rs => rs.map(r => [r.dataset.robot, r.dataset.state, +r.dataset.open, r.innerText])",
        )
    }


@pytest.mark.slow
def test_the_fleet_page_shows_a_silent_robot_as_lost(fleet_served: Any) -> None:
    server, fleet, control = fleet_served
    r1, r2 = robot(fleet, "r1"), robot(fleet, "r2")
    pw, page, console, requests = open_page(server.url())
    try:
        page.wait_for_selector("tr.robot[data-robot='r2']")
        assert fleet_rows(page)["r1"]["state"] == "waiting"
        for i in range(2):  # two documents: the period (0.5 s), so lost after 1.5 s
            now = f"2026-11-23T17:05:00.{5 * i}Z"
            fleet.on_status(r1, doc_of("robot1", str(control.path), now))
            fleet.on_status(r2, doc_of("robot2", str(control.path), now))
        wait_js(page, "document.querySelector(\"tr.robot[data-robot='r1']\").dataset.state"
                " === 'live'")  # fmt: skip
        rows = fleet_rows(page)
        assert rows["r1"]["open"] == 1 and "operationalstate_2" in rows["r1"]["text"]
        assert "sRobot" in rows["r1"]["text"] and ("ab" * 6) in rows["r1"]["text"]
        t0 = time.monotonic()
        deadline = t0 + 5
        while time.monotonic() < deadline and fleet_rows(page)["r2"]["state"] != "lost":
            fleet.on_status(r1, doc_of("robot1", str(control.path), "2026-11-23T17:05:03.0Z"))
            page.wait_for_timeout(200)
        rows = fleet_rows(page)
        assert rows["r2"]["state"] == "lost" and "LOST" in rows["r2"]["text"], rows
        assert rows["r1"]["state"] == "live"
        colour = page.eval_on_selector(
            "tr.robot[data-robot='r2'] .state", "e => getComputedStyle(e).backgroundColor"
        )
        assert colour == "rgb(211, 47, 47)"  # red
        page.click("tr.robot[data-robot='r1'] a")
        page.wait_for_selector("tr.req[data-requirement='state_req103']")
        assert page.url == server.url() + "robot/r1"
        assert console == [], console
        assert all(u.startswith(server.url()) for u in requests), requests
    finally:
        pw.stop()


FLEET_SIZE = 100
FLEET_RATE = 400  # status documents a second: 100 robots at 4 Hz (ros.status_ms 250)
FLEET_BURST_S = 3.0
CURRENT_S = 2.0  # a document sent after the burst is on the page this soon


@pytest.mark.slow
def test_the_fleet_page_stays_current_with_many_robots(tmp_path: Path) -> None:
    """A hundred robots' documents: the page redraws once per burst, not once per
    document, so a row shows its robot's latest document within CURRENT_S."""
    control = FakeControl(tmp_path / "ctl.sock")
    sock = str(control.path)
    specs = [RobotSpec(f"r{i:03d}", f"/robot{i:03d}", 0, socket=sock) for i in range(FLEET_SIZE)]
    fleet = Fleet(specs, lambda doc, s: local_reset_availability(doc, s, TOKEN, reset_availability))
    server = UiServer(("127.0.0.1", 0), None, TOKEN, lambda: None, fleet=fleet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    robots = [robot(fleet, spec.name) for spec in specs]
    pw, page, console, requests = open_page(server.url())
    try:
        page.wait_for_selector(f"tr.robot[data-robot='r{FLEET_SIZE - 1:03d}']")
        sent = 0
        start = time.monotonic()
        while (elapsed := time.monotonic() - start) < FLEET_BURST_S:
            while sent < elapsed * FLEET_RATE:
                i = sent % FLEET_SIZE
                fleet.on_status(robots[i], doc_of(f"robot{i:03d}", sock, f"{sent}",
                                                  component=f"c{sent}"))  # fmt: skip
                sent += 1
            time.sleep(0.005)
        fleet.on_status(robots[50], doc_of("robot050", sock, "last", component="marker"))
        t0 = time.monotonic()
        page.wait_for_selector("tr.robot[data-robot='r050'] >> text=marker", timeout=60_000)
        lag = time.monotonic() - t0
        assert lag < CURRENT_S, f"the page was {lag:.1f} s behind after {sent} documents"
        assert console == [], console
        assert all(u.startswith(server.url()) for u in requests), requests
    finally:
        pw.stop()
        server.stop()
        control.close()


def held_click(page: Any, selector: str, hold_ms: int, during: Any = None) -> None:
    """A person's click: pressed, held ``hold_ms`` (longer than the page's redraws,
    during which ``during()`` may send documents), released on the same spot."""
    box = None
    for _ in range(50):  # None while a redraw replaces the element (before the fix: often)
        if (box := page.locator(selector).bounding_box()) is not None:
            break
        page.wait_for_timeout(20)
    assert box is not None, selector
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    if during is not None:
        during()
    page.wait_for_timeout(hold_ms)
    page.mouse.up()


@pytest.mark.slow
def test_a_held_click_on_a_robots_link_survives_the_rows_updates(fleet_served: Any) -> None:
    """The rows update four times a second and on every document: a click held
    longer than that (a person's) still follows the link."""
    server, fleet, control = fleet_served
    r1, r2 = robot(fleet, "r1"), robot(fleet, "r2")
    pw, page, console, requests = open_page(server.url())
    try:
        fleet.on_status(r1, doc_of("robot1", str(control.path), "2026-11-23T17:05:00.0Z"))
        page.wait_for_selector("tr.robot[data-robot='r1'][data-state='live']")

        def documents() -> None:
            for i in range(3):
                fleet.on_status(r2, doc_of("robot2", "/nonexistent", f"2026-11-23T17:05:0{i}.0Z"))
                page.wait_for_timeout(150)

        held_click(page, "tr.robot[data-robot='r1'] a", 300, documents)
        page.wait_for_url(server.url() + "robot/r1", timeout=5000)
        assert console == [], console
    finally:
        pw.stop()


# ---------------------------------------------------------------- over DDS


ROBOT_CONFIG = """\
component: R{n}
step: {{policy: on_message, stale_after_ms: 200}}
variables:
  speed: {{type: double, topic: /speed, msg: std_msgs/msg/Float64}}
requirements:
  - id: limit_{n}
    text: R{n} shall always satisfy speed <= 2.0
    on_violation: [note]
mitigations:
  note: {{log: {{message: violated}}}}
ros: {{namespace: /robot{n}}}
control: {{socket: ctl.sock}}
"""


def other_domain(domain: int) -> int:
    """A second domain beside the test run's (random, 1-200: tests/support/rosutil.py)."""
    return domain + 1 if domain < 232 else domain - 1


class FleetUi:
    """``safety-supervisor ui --fleet FILE`` as a child on the test run's domain."""

    def __init__(self, tmp: Path, fleet_file: Path, token_file: Path) -> None:
        from rosutil import DOMAIN_ID

        from supervisor.tools.children import Child, ros_env
        from tests.system.test_ui import free_port

        port = free_port()
        self.url = f"http://127.0.0.1:{port}/"
        argv = [sys.executable, "-m", "supervisor", "ui", "--bind", f"127.0.0.1:{port}",
                "--token-file", str(token_file), "--fleet", str(fleet_file)]  # fmt: skip
        self.stderr = tmp / "ui.stderr"
        self.child = Child("ui", argv, env=ros_env(DOMAIN_ID), cwd=ROOT, stderr=self.stderr)
        deadline = time.monotonic() + 30
        while True:
            try:
                if http(self.url + "api/fleet")[0] == 200:
                    return
            except OSError:
                pass
            if not self.child.alive() or time.monotonic() > deadline:
                raise AssertionError(f"ui did not start\n{self.stderr.read_text()}")
            time.sleep(0.1)

    def rows(self) -> dict[str, dict[str, Any]]:
        return {r["id"]: r for r in json.loads(http(self.url + "api/fleet")[2])["robots"]}


@pytest.mark.ros
@pytest.mark.slow
def test_the_fleet_of_real_supervisors_in_two_namespaces_and_two_domains(tmp_path: Path) -> None:
    from rosutil import DOMAIN_ID, Daemon, wait_until

    second = other_domain(DOMAIN_ID)
    daemons: dict[int, Daemon] = {}
    ui: FleetUi | None = None
    pw = None
    try:
        for n, domain in ((1, DOMAIN_ID), (2, DOMAIN_ID), (3, second)):
            d = tmp_path / f"r{n}"
            d.mkdir()
            (d / "c.yaml").write_text(ROBOT_CONFIG.format(n=n))
            env = {"ROS_DOMAIN_ID": str(second)} if domain != DOMAIN_ID else None
            daemons[n] = Daemon(d, d / "c.yaml", env=env)
        for d in daemons.values():
            d.wait_notify("READY=1", timeout=60)
        # robot1 listed on the run's domain, robot3 on the second; robot2 discovered
        fleet_file = tmp_path / "fleet.yaml"
        fleet_file.write_text(
            f"- {{name: robot1, namespace: /robot1, socket: r1/ctl.sock}}\n"
            f"- {{name: robot3, namespace: /robot3, domain: {second}, socket: r3/ctl.sock}}\n"
        )
        token_file = tmp_path / "ui.token"
        token_file.write_bytes(TOKEN + b"\n")
        token_file.chmod(0o640)
        ui = FleetUi(tmp_path, fleet_file, token_file)
        found = f"d{DOMAIN_ID}-robot2"

        def all_live() -> bool:
            rows = ui.rows() if ui else {}
            return {"robot1", "robot3", found} <= set(rows) and all(
                r["state"] == "live" for r in rows.values()
            )

        wait_until("three live supervisors", all_live, 30, lambda: str(ui and ui.rows()))
        rows = ui.rows()
        assert rows["robot3"]["domain"] == second and rows["robot3"]["component"] == "R3"
        assert rows[found]["component"] == "R2" and not rows[found]["configured"]
        assert rows["robot1"]["host"] == HERE

        pw, page, console, requests = open_page(ui.url)
        page.wait_for_selector(f"tr.robot[data-robot='{found}'][data-state='live']")
        shown = fleet_rows(page)
        assert {"robot1", "robot3", found} <= set(shown)
        assert all(shown[r]["state"] == "live" for r in ("robot1", "robot3", found)), shown

        # robot2 stopped: LOST within a few seconds, and still there
        t0 = time.monotonic()
        daemons[2].terminate()
        page.wait_for_selector(f"tr.robot[data-robot='{found}'][data-state='lost']", timeout=8000)
        assert time.monotonic() - t0 < 6.0
        shown = fleet_rows(page)
        assert "LOST" in shown[found]["text"] and shown["robot1"]["state"] == "live"
        page.wait_for_timeout(1000)
        assert fleet_rows(page)[found]["state"] == "lost"  # not removed

        # each link leads to that robot's page, with only its requirements
        for rid, req, other in (("robot1", "limit_1", "limit_3"), ("robot3", "limit_3", "limit_1")):
            page.goto(ui.url + "fleet")
            page.click(f"tr.robot[data-robot='{rid}'] a")
            page.wait_for_selector(f"tr.req[data-requirement='{req}']")
            assert page.url == ui.url + f"robot/{rid}"
            assert page.locator(f"tr.req[data-requirement='{other}']").count() == 0
            assert f"R{rid[-1]}" in page.inner_text("#component")
            # its socket is on this machine and the token is set: resets are offered
            wait_js(page, "!document.getElementById('reset-all').disabled")
        assert console == [], console
        assert all(u.startswith(ui.url) for u in requests), requests
        assert ui.child.stop() == 0, ui.stderr.read_text()
        ui = None
        for n in (1, 3):
            daemons[n].terminate()
    finally:
        if pw is not None:
            pw.stop()
        if ui is not None:
            ui.child.stop()
        for d in daemons.values():
            d.close()
