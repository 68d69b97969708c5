"""``/safety_supervisor/status`` (supervisor/daemon/status.py): the document an
operator's page shows; built from a real session without ROS, and published by the
real daemon over DDS."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from mitigations.policy import RequirementPolicy
from mitigations.settings import PolicyConfig
from mitigations.violationlog.testing import MemoryLog
from monitors.backends.load import compile_spec
from supervisor.daemon.core import Core
from supervisor.daemon.session import build_session
from supervisor.daemon.status import EVENTS_KEPT, StatusBoard, requirement_state
from supervisor.pipeline import project_for

MS = 1_000_000

CONFIG = """\
component: R
step: {policy: on_message, stale_after_ms: 200}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
  fast: {type: bool, define: speed > 3.0}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
    policy: {debounce_steps: 3, reset: after_mitigation}
  - id: halt_when_fast
    text: R shall always satisfy fast -> halted
    on_violation: [note]
    policy: {latch: true, repeat_ms: 100}
mitigations:
  note: {log: {message: violated}}
"""


def test_one_word_per_policy_state():
    pol = RequirementPolicy(PolicyConfig(debounce_steps=2, cooldown_ms=100.0), ("a",))
    assert requirement_state(pol, 0) == "holding"
    pol.on_step(True, 0, 10 * MS, {})
    assert requirement_state(pol, 10 * MS) == "debouncing"
    pol.on_step(True, 1, 20 * MS, {})
    assert requirement_state(pol, 20 * MS) == "violated"
    pol.on_step(False, 2, 30 * MS, {})
    assert requirement_state(pol, 30 * MS) == "cooldown"
    assert requirement_state(pol, 200 * MS) == "holding"
    pol.latched = True
    assert requirement_state(pol, 200 * MS) == "latched"


def test_the_document_of_a_session(tmp_path: Path):
    (tmp_path / "c.yaml").write_text(CONFIG)
    project = project_for(tmp_path / "c.yaml", ros=False)
    session = build_session(project, compile_spec(project.spec(), tmp_path / "b"))
    board = StatusBoard("safety_supervisor")

    # the records as the writer renders them, teed to the board
    log = MemoryLog(lambda r: board.record(json.dumps({"ts": "2026-11-23T00:00:00.000000Z", **r})))

    def submit(request: Any) -> None:
        for a in request.actions:
            log.mitigation(
                request.requirement, action=a, stage=request.stage, ok=True, latency_ms=0.5
            )

    core = Core(session, log, submit, warn=lambda _t: None)
    core.start(0)
    core.fields([("halted", False)], 1 * MS)
    core.fields([("speed", 3.5)], 2 * MS)  # fast, not halted: latched; limit debouncing
    doc = board.document(
        core,
        now_ns=3 * MS,
        reloads=0,
        recording=False,
        watchdog_s=None,
        control_socket="/tmp/c.sock",
    )
    reqs = {r["id"]: r for r in doc["requirements"]}
    assert reqs["halt_when_fast"]["state"] == "latched"
    assert reqs["halt_when_fast"]["actions"][0]["action"] == "note"
    assert reqs["limit"]["state"] == "debouncing"
    assert {i["name"]: i["value"] for i in doc["inputs"]} == {"speed": 3.5, "halted": False}
    assert [i["age_s"] for i in doc["inputs"]] == [0.001, 0.002]
    assert [e["event"] for e in doc["events"]] == ["violation", "mitigation", "reset"]
    core.advance(300 * MS)  # both inputs go stale
    doc = board.document(
        core, now_ns=300 * MS, reloads=0, recording=False, watchdog_s=None, control_socket=None
    )
    reqs = {r["id"]: r for r in doc["requirements"]}
    assert sorted(reqs["halt_when_fast"]["stale_inputs"]) == ["halted", "speed"]  # via 'fast'
    assert [e["what"] for e in doc["events"]] == ["input_stale", "input_stale"]
    json.dumps(doc)  # JSON as it is


@pytest.mark.ros
@pytest.mark.parametrize("namespace", ["/", "/robot1"])
def test_the_daemon_publishes_its_status(tmp_path: Path, robot_node: Any, namespace: str):
    from rosutil import Daemon, StatusWatch, messages, spin_until, wait_matched
    from std_msgs.msg import Bool, Float64

    config = tmp_path / "r.yaml"
    config.write_text(CONFIG + f"ros: {{status_ms: 100, namespace: '{namespace}'}}\n")
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        status = StatusWatch(robot_node, namespace)
        docs = status.docs
        speed = robot_node.create_publisher(Float64, "/speed", 10)
        halted = robot_node.create_publisher(Bool, "/halted", 10)
        wait_matched([speed, halted])
        halted.publish(Bool(data=False))
        status.until("halted=False received", lambda doc: messages(doc, "halted") == 1)
        speed.publish(Float64(data=3.5))

        def latched() -> Any:
            for doc in docs:
                states = {r["id"]: r["state"] for r in doc["requirements"]}
                if states.get("halt_when_fast") == "latched":
                    return doc
            return None

        doc = spin_until(robot_node, "a status with the latch", latched, timeout=15)
        assert doc["component"] == "R" and doc["schema"] == 1 and doc["policy"] == "on_message"
        assert doc["supervisor"].endswith(f":{namespace.rstrip('/')}/safety_supervisor")
        assert any(e["event"] == "violation" for d_ in docs for e in d_["events"])
        assert {i["name"] for i in doc["inputs"]} == {"speed", "halted"}
        d.terminate()
    finally:
        d.close()


SHOWN = (
    "uptime_s",
    "ticks",
    "tick_rate_hz",
    "receive_rate_hz",
    "received",
    "lost",
    "violations",
    "reloads",
    "recording",
    "watchdog",
    "control_socket",
    "inputs",
    "events_dropped",
)


def test_rates_inputs_and_dropped_events_between_two_documents(tmp_path: Path):
    (tmp_path / "c.yaml").write_text(CONFIG)
    project = project_for(tmp_path / "c.yaml", ros=False)
    session = build_session(project, compile_spec(project.spec(), tmp_path / "b"))
    board = StatusBoard("safety_supervisor")
    log = MemoryLog(lambda r: board.record(json.dumps({"ts": "2026-11-23T00:00:00.000000Z", **r})))
    core = Core(session, log, lambda _request: None, warn=lambda _t: None)
    core.start(0)

    def document(now_ns: int) -> dict[str, Any]:
        doc = board.document(
            core, now_ns=now_ns, reloads=2, recording=True, watchdog_s=5.0, control_socket=None
        )
        return {k: doc[k] for k in SHOWN}

    core.fields([("halted", False)], 1 * MS)
    first = document(100 * MS)
    for i in range(1, 5):
        core.fields([("speed", 1.0 * i)], (100 + i) * MS)
    for _ in range(EVENTS_KEPT + 3):  # more records than a document keeps
        board.record(json.dumps({"event": "supervisor", "what": "x"}))
    second = document(600 * MS)
    core.advance(700 * MS)  # both inputs go stale
    third = document(700 * MS)
    fixed = {
        "lost": 0,
        "reloads": 2,
        "recording": True,
        "watchdog": {"enabled": True, "interval_s": 5.0},
        "control_socket": None,
    }

    def inputs(speed: tuple[Any, ...], halted: tuple[Any, ...]) -> list[dict[str, Any]]:
        keys = ("value", "age_s", "stale", "messages")
        return [
            {
                "name": "speed",
                "topic": "/speed",
                "type": "double",
                **dict(zip(keys, speed, strict=True)),
            }
            | {"lost": 0, "precision": None},
            {
                "name": "halted",
                "topic": "/halted",
                "type": "bool",
                **dict(zip(keys, halted, strict=True)),
            }
            | {"lost": 0, "precision": None},
        ]

    assert first == fixed | {
        "uptime_s": 0.0,
        "ticks": 0,
        "tick_rate_hz": 0.0,
        "receive_rate_hz": 0.0,
        "received": 1,
        "violations": 0,
        "inputs": inputs((None, None, False, 0), (False, 0.099, False, 1)),
        "events_dropped": 0,
    }
    assert second == fixed | {
        "uptime_s": 0.5,
        "ticks": 4,
        "tick_rate_hz": 8.0,
        "receive_rate_hz": 8.0,
        "received": 5,
        "violations": 1,
        "inputs": inputs((4.0, 0.496, False, 4), (False, 0.599, False, 1)),
        "events_dropped": 5,
    }
    assert third == fixed | {
        "uptime_s": 0.6,
        "ticks": 4,
        "tick_rate_hz": 0.0,
        "receive_rate_hz": 0.0,
        "received": 5,
        "violations": 1,
        "inputs": inputs((4.0, 0.596, True, 4), (False, 0.699, True, 1)),
        "events_dropped": 0,
    }


FLOAT32 = """\
component: R
step: {policy: on_message}
variables:
  f32: {type: double, topic: /f32, msg: std_msgs/msg/Float32}
  f64: {type: double, topic: /f64, msg: std_msgs/msg/Float64}
  nearest: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: ranges, reduce: min}
  first: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}
  mean: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: ranges, reduce: mean}
  count: {type: int64, topic: /n, msg: std_msgs/msg/Int64}
requirements:
  - id: r
    text: R shall always satisfy f32 + f64 + nearest + first + mean < 1.0 | count > 0
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
"""


def test_an_input_says_when_its_value_is_a_float32(tmp_path: Path):
    """A page shows a float32 field's value at float32 precision (0.8, not
    0.800000011920929): the document says which values are float32 as they came."""
    (tmp_path / "c.yaml").write_text(FLOAT32)
    project = project_for(tmp_path / "c.yaml", ros=False)
    session = build_session(project, compile_spec(project.spec(), tmp_path / "b"))
    board = StatusBoard("safety_supervisor")
    core = Core(session, MemoryLog(), lambda _request: None, warn=lambda _t: None)
    core.start(0)
    doc = board.document(
        core, now_ns=MS, reloads=0, recording=False, watchdog_s=None, control_socket=None
    )
    assert {i["name"]: i["precision"] for i in doc["inputs"]} == {
        "f32": "float32",
        "f64": None,
        "nearest": "float32",  # the min of float32s is one of them
        "first": "float32",
        "mean": None,  # computed in double
        "count": None,
    }


MARGINS = """\
component: lamp
step: {policy: periodic, period_ms: 20, margins: true}
variables:
  distance: {type: double, topic: /distance, msg: std_msgs/msg/Float64}
  uv_on: {type: bool, topic: /uv, msg: std_msgs/msg/Bool}
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
requirements:
  - id: keep_away
    text: lamp shall always satisfy uv_on -> distance >= 3.0
    on_violation: [note]
    predict: {horizon_ms: 1500, window_ms: 500, actions: [note]}
  - id: limit
    text: lamp shall always satisfy speed <= 2.0
    on_violation: [note]
  - id: lamp_on
    text: lamp shall always satisfy uv_on
    on_violation: [note]
mitigations:
  note: {log: {message: note}}
"""


def test_the_document_carries_each_margin_its_trend_unit_and_open_prediction(tmp_path: Path):
    (tmp_path / "c.yaml").write_text(MARGINS)
    project = project_for(tmp_path / "c.yaml", ros=False)
    assert project.ok, project.first_error()
    session = build_session(project, compile_spec(project.spec(), tmp_path / "b"))
    try:
        board = StatusBoard("safety_supervisor")
        core = Core(session, MemoryLog(), lambda _r: None, warn=lambda _t: None)

        def doc(t_ms: int, peek: bool = False) -> dict[str, dict[str, Any]]:
            d = board.document(core, now_ns=t_ms * MS, reloads=0, recording=False,
                               watchdog_s=None, control_socket=None, peek=peek)  # fmt: skip
            json.dumps(d)
            return {r["id"]: r["margin"] for r in d["requirements"]}

        core.start(0)
        assert doc(0) == {"keep_away": None, "limit": None, "lamp_on": None}  # no step yet
        core.fields([("uv_on", True), ("distance", 9.0), ("speed", 0.5)], 1 * MS)
        core.advance(100 * MS)
        first = doc(100)
        # limit: H (speed <= 2.0) with margins on: 2.0 - 0.5, the monitor's own; no
        # trend at the first document
        assert first["limit"]["value"] == 1.5 and first["limit"]["trend_per_s"] is None
        assert first["limit"]["unit"] == "speed" and first["limit"]["prediction"] is None
        assert first["lamp_on"]["value"] == "inf"  # a boolean atom's, written as json_safe does
        assert first["lamp_on"]["unit"] is None
        assert first["keep_away"]["value"] == 6.0 and first["keep_away"]["unit"] == "distance"
        core.fields([("speed", 1.5)], 101 * MS)
        core.advance(300 * MS)
        assert doc(300, peek=True)["limit"]["trend_per_s"] == pytest.approx(-1.0 / 0.2)
        second = doc(600)  # the peek left the previous document's margins as they were
        assert second["limit"]["value"] == 0.5
        assert second["limit"]["trend_per_s"] == pytest.approx(-1.0 / 0.5)
        assert second["limit"]["trend_from"] == "difference"
        # a walk in at 2 m/s: the predictor's slope, and the prediction while open
        for t_ms in range(620, 3000, 20):
            core.fields([("distance", 9.0 - 2.0 * (t_ms - 600) / 1000)], t_ms * MS + 1)
            m = doc(t_ms)["keep_away"]
            if m["prediction"] is not None:
                break
        assert m["trend_from"] == "predictor" and m["trend_per_s"] == pytest.approx(-2.0)
        assert m["value"] == pytest.approx(6.0 - 2.0 * (t_ms - 620) / 1000)
        ttv = m["prediction"]["ttv_ms"]
        assert ttv == pytest.approx(m["value"] / 2.0 * 1000, abs=25)
        assert 0 < ttv <= 1500 and m["prediction"]["since_ms"] <= 20
        # past the UI's bound (schema.MAX_MARGIN): its sign's infinity, the trend null
        core.fields([("speed", 5e12)], (t_ms + 20) * MS + 1)
        core.advance((t_ms + 40) * MS)
        far = doc(t_ms + 40)["limit"]
        assert far["value"] == "-inf" and far["trend_per_s"] is None, far
    finally:
        assert session.cleanup is not None
        session.cleanup()
