"""Online equals offline: the daemon records its run (``run --record``), ``replay``
of that recording writes the decisions the daemon logged.

Over real DDS: a robot node publishes a scripted run (a debounced violation with a
cooldown, a latched one released by an operator reset through the control socket,
an input going stale and recovering) to the daemon as a subprocess; then the
recording is opened with rosbags and with the mcap reader, and replayed.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import Daemon, wait_matched  # noqa: E402
from std_msgs.msg import Bool, Float64  # noqa: E402

from mitigations.violationlog.reader import iter_records  # noqa: E402
from supervisor.tools.reset import request  # noqa: E402

CONFIG = """\
component: R
step: {policy: periodic, period_ms: 20, stale_after_ms: 300}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
    policy: {debounce_steps: 2, cooldown_ms: 100, reset: after_mitigation,
             escalate: {after_ms: 150, actions: [note]}}
  - id: halt_when_fast
    text: R shall always satisfy speed > 3.0 -> halted
    on_violation: [note]
    policy: {latch: true, repeat_ms: 100}
on_stale: [note]
mitigations:
  note: {log: {message: violated}}
control: {socket: ctl.sock}
"""


def decisions(records: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """What the supervisor decided, timestamps aside."""
    keep = ("input_stale", "input_recovered", "input_rejected")
    return {
        "violation": [
            (r["requirement"], r["tick"], r["inputs"], r["recent"], r["stale"], r["policy_state"])
            for r in records
            if r["event"] == "violation"
        ],
        "reset": [
            (r["requirement"], r["reason"], r.get("tick"), r.get("refused"))
            for r in records
            if r["event"] == "reset"
        ],
        # the engine logs an action when it is done, on its own thread: compare as a set
        "mitigation": sorted(
            (r["requirement"], r["action"], r.get("stage"), r["ok"])
            for r in records
            if r["event"] == "mitigation"
        ),
        "inputs": [(r["what"], r["input"]) for r in records if r.get("what") in keep],
    }


def publish(pub: Any, msg: Any, seconds: float, hz: float = 50.0) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish(msg)
        time.sleep(1 / hz)


def test_replay_of_the_daemons_recording_writes_what_it_logged(tmp_path: Path, robot_node: Any):
    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    bags = tmp_path / "bags"
    d = Daemon(tmp_path, config, args=["--record", str(bags)])
    try:
        d.wait_notify("READY=1", timeout=30)
        speed = robot_node.create_publisher(Float64, "/speed", 10)
        halted = robot_node.create_publisher(Bool, "/halted", 10)
        wait_matched([speed, halted])
        halted.publish(Bool(data=False))
        publish(speed, Float64(data=1.0), 0.4)
        publish(speed, Float64(data=2.5), 0.4)  # limit: debounce, act, cooldown, escalate
        publish(speed, Float64(data=3.5), 0.1)  # halt_when_fast: latched
        publish(speed, Float64(data=1.0), 0.3)
        answer = request(str(tmp_path / "ctl.sock"), {"command": "reset"}, 5)
        assert answer["ok"], answer
        publish(speed, Float64(data=1.0), 0.1)
        time.sleep(0.6)  # both inputs go stale (halted has been silent all along)
        halted.publish(Bool(data=True))
        publish(speed, Float64(data=1.5), 0.3)
        d.terminate(budget=10)
    finally:
        d.close()
    online = list(iter_records(str(d.log)))
    assert any(r.get("what") == "record_closed" and r["dropped"] == 0 for r in online)

    out = tmp_path / "replay.jsonl"
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(config), str(bags), "-o", str(out),
         "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    offline = list(iter_records(str(out)))
    assert all(r.get("dry_run") for r in offline if r["event"] == "mitigation")
    want, got = decisions(online), decisions(offline)
    # the run exercised what it should
    assert {v[0] for v in want["violation"]} == {"limit", "halt_when_fast"}
    assert any(r[0] == "*" for r in want["reset"])
    assert ("input_stale", "speed") in want["inputs"]
    assert "escalation" in {m[2] for m in want["mitigation"]}
    for key in want:
        assert got[key] == want[key], key
    assert summary["ticks"] > 50 and "start" in summary["markers"]


def test_the_recording_opens_with_rosbags_and_mcap(tmp_path: Path, robot_node: Any):
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    bags = tmp_path / "bags"
    d = Daemon(tmp_path, config, args=["--record", str(bags)])
    try:
        d.wait_notify("READY=1", timeout=30)
        speed = robot_node.create_publisher(Float64, "/speed", 10)
        halted = robot_node.create_publisher(Bool, "/halted", 10)
        wait_matched([speed, halted])
        halted.publish(Bool(data=True))
        publish(speed, Float64(data=3.5), 0.2)
        d.wait_record(lambda r: r["event"] == "violation", "a violation")
        d.terminate(budget=10)
    finally:
        d.close()
    dirs = sorted(p for p in bags.iterdir() if p.is_dir())
    assert len(dirs) == 1
    with AnyReader(dirs) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        values, records = [], []
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/speed":
                values.append(msg.data)
            elif conn.topic == "/safety_supervisor/records":
                records.append(json.loads(msg.data))
    assert topics["/speed"] == "std_msgs/msg/Float64"
    assert 3.5 in values
    assert any(r.get("event") == "violation" for r in records)
    assert [r["what"] for r in records if r.get("event") == "marker"][:1] == ["start"]
    mcaps = list(dirs[0].glob("*.mcap"))
    with mcaps[0].open("rb") as f:
        seen = {ch.topic for _s, ch, _m in make_reader(f).iter_messages()}
    assert {"/speed", "/halted", "/safety_supervisor/records"} <= seen


@pytest.mark.slow
def test_a_recorded_demo_run_replays_to_the_same_decisions(tmp_path: Path) -> None:
    """The demo (a walking person, the safety controller with the UV fault made
    frequent) recorded by its supervisor; replay with the demo's config."""
    rec = tmp_path / "rec"
    log = tmp_path / "demo.jsonl"
    demo = subprocess.run(
        [sys.executable, "-m", "supervisor", "demo", "--duration", "12", "--no-live",
         "--fault-rate", "0.3", "--seed", "11", "--rate-hz", "20", "--log", str(log),
         "--record", str(rec)],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert demo.returncode == 0, demo.stdout + demo.stderr
    assert f"read it with: safety-supervisor logs {rec}" in demo.stdout
    config = rec / "srobot-demo.yaml"
    out = tmp_path / "replay.jsonl"
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(config), str(rec), "-o", str(out),
         "--quiet"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    online, offline = list(iter_records(str(log))), list(iter_records(str(out)))
    want, got = decisions(online), decisions(offline)
    assert want["violation"]  # the UV fault
    assert want["reset"] and want["mitigation"]  # reset after each mitigation
    for key in want:
        assert got[key] == want[key], key
    # and the incident report of that run opens offline in a real browser, one marker
    # per violation, a why-tree for each (tests/system/test_report.py's checks)
    from tests.system.test_report import check_page

    page = tmp_path / "report.html"
    built = subprocess.run(
        [sys.executable, "-m", "supervisor", "report", str(log), "--bag", str(rec),
         "--config", str(config), "-o", str(page), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr
    trees = check_page(page, log)
    assert {k.split("@")[0] for k in trees} == {v[0] for v in want["violation"]}


class _LimitedDaemon(Daemon):
    """The daemon with a file-size limit (RLIMIT_FSIZE): a bag that outgrows it fails
    to write (EFBIG) as on a full disk; the violation log stays far below it."""

    def __init__(self, tmp: Path, config: Path, limit: int, args: list[str]) -> None:
        from rosutil import DOMAIN_ID, ROOT, ros_env

        from supervisor.tools.children import NotifySocket, daemon_argv

        self.log = tmp / "v.jsonl"
        self.notify = NotifySocket(tmp / "notify.sock")
        limited = [
            sys.executable,
            "-c",
            "import os, resource, sys; "
            f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit})); "
            "os.execv(sys.argv[1], sys.argv[1:])",
            *daemon_argv(config, self.log, tmp / "build", *args),
        ]
        self.spawn(tmp, limited, {**ros_env(DOMAIN_ID), **self.notify.env()}, cwd=ROOT)


def test_a_full_disk_stops_the_recording_not_the_monitoring(tmp_path: Path, robot_node: Any):
    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    d = _LimitedDaemon(tmp_path, config, 1_000_000, ["--record", str(tmp_path / "bags")])
    try:
        d.wait_notify("READY=1", timeout=30)
        speed = robot_node.create_publisher(Float64, "/speed", 1000)
        halted = robot_node.create_publisher(Bool, "/halted", 10)
        wait_matched([speed, halted])
        halted.publish(Bool(data=False))
        deadline = time.monotonic() + 30
        while not any(r.get("what") == "record_stopped" for r in d.records()):
            assert time.monotonic() < deadline, d.explain()
            for _ in range(2000):
                speed.publish(Float64(data=1.0))
            time.sleep(0.05)
        stopped = next(r for r in d.records() if r.get("what") == "record_stopped")
        assert "File too large" in stopped["reason"] or "No space" in stopped["reason"]
        # monitoring goes on: a violation after the recording stopped is caught and logged
        publish(speed, Float64(data=2.5), 0.2)
        d.wait_record(
            lambda r: r["event"] == "violation" and r["requirement"] == "limit", "a violation"
        )
        d.terminate(budget=10)
    finally:
        d.close()
    assert len([r for r in d.records() if r.get("what") == "record_stopped"]) == 1
