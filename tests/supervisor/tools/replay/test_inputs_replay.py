"""``replay`` of the new input kinds over real rosbag2 bags written with rosbags:
a LaserScan's first range and the age and receive rate of its stamps (with a
stretch of frozen stamps and a gap), the worst level of /diagnostics, an action's
goal states and a service's responses (std_srvs/srv/Trigger_Event, which rosbags'
typestore does not know: registered from its definition's text).  The violations
are checked tick by tick against a timeline worked out by hand."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from inproc import cli_main
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from mitigations.violationlog.reader import iter_records

MS = 1_000_000
T0 = 1_000 * 10**9  # the recording's first receive time (ns)
TS = get_typestore(Stores.ROS2_JAZZY)

# std_srvs/srv/Trigger's event type, as ROS 2 generates it for service introspection.
TRIGGER = {
    "std_srvs/srv/Trigger_Request": "uint8 structure_needs_at_least_one_member\n",
    "std_srvs/srv/Trigger_Response": "bool success\nstring message\n",
    "std_srvs/srv/Trigger_Event": (
        "service_msgs/ServiceEventInfo info\n"
        "std_srvs/srv/Trigger_Request[<=1] request\n"
        "std_srvs/srv/Trigger_Response[<=1] response\n"
    ),
}


def _srv_names(x: Any) -> Any:
    """rosbags' msg parser puts every type under msg/ ('std_srvs/srv/msg/Trigger_Event'):
    the service types' names back where ROS 2 has them."""
    if isinstance(x, str):
        return x.replace("std_srvs/srv/msg/", "std_srvs/srv/")
    if isinstance(x, list | tuple):
        return type(x)(_srv_names(i) for i in x)
    return x


for _name, _text in TRIGGER.items():
    TS.register({_srv_names(k): _srv_names(v) for k, v in get_types_from_msg(_text, _name).items()})

EVENT = "std_srvs/srv/Trigger_Event"
# rosbags cannot write a msg definition of a type under srv/ (its generator asserts
# '/msg/' in every name), so the bag's definition is given: in IDL, as rosbag2 also
# stores definitions, or in .msg form (rosbag2's ros2msg encoding).
TRIGGER_IDL = """\
module std_srvs {
  module srv {
    struct Trigger_Request {
      uint8 structure_needs_at_least_one_member;
    };
    struct Trigger_Response {
      boolean success;
      string message;
    };
    struct Trigger_Event {
      service_msgs::msg::ServiceEventInfo info;
      sequence<std_srvs::srv::Trigger_Request, 1> request;
      sequence<std_srvs::srv::Trigger_Response, 1> response;
    };
  };
};
"""
SEP = "=" * 80 + "\n"


def event_msgdef(encoding: str) -> str:
    if encoding == "idl":
        return f"{SEP}IDL: {EVENT}\n{TRIGGER_IDL}"
    info, _ = TS.generate_msgdef("service_msgs/msg/ServiceEventInfo", ros_version=2)
    return (
        TRIGGER[EVENT].replace("std_srvs/srv/", "std_srvs/")
        + f"{SEP}MSG: service_msgs/ServiceEventInfo\n{info}"
        + f"{SEP}MSG: std_srvs/Trigger_Request\n{TRIGGER['std_srvs/srv/Trigger_Request']}"
        + f"{SEP}MSG: std_srvs/Trigger_Response\n{TRIGGER['std_srvs/srv/Trigger_Response']}"
    )


CONFIG = """\
component: base
step: {policy: periodic, period_ms: 100}
variables:
  front:      {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}
  scan_age:   {type: double, age_of: front}
  scan_hz:    {type: double, rate_of: front, window_ms: 500}
  diag_level: {type: int64, topic: /diagnostics, msg: diagnostic_msgs/msg/DiagnosticArray,
               field: "status[].level", reduce: max}
  nav_active: {type: bool, action: /navigate, status: [accepted, executing]}
  docked:     {type: bool, service: /dock, srv: std_srvs/srv/Trigger, call: response,
               field: success, initial: false}
requirements:
  - id: fresh_scan
    text: base shall always satisfy scan_age < 250
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: scan_rate
    text: base shall always satisfy scan_hz >= 8
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: clear_front
    text: base shall always satisfy front > 0.5
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: diag_ok
    text: base shall always satisfy diag_level < 2
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: undocked_to_navigate
    text: base shall always satisfy nav_active -> !docked
    on_violation: [note]
    policy: {reset: after_mitigation}
mitigations:
  note: {log: {message: violated}}
"""
IDS = ["fresh_scan", "scan_rate", "clear_front", "diag_ok", "undocked_to_navigate"]

# ------------------------------------------------------------ the timeline (ms after T0)
# /scan: one every 100 ms at +10 ms, stamped 5 ms before its receipt; none at k = 22..25
# (a gap); k = 15..19 carry k = 14's stamp (a frozen driver republishing); k = 3's
# stamp is 3 ms after its receipt (a clock ahead); k = 8 sees 0.3 m in front; k = 14
# has no ranges at all (ranges[0] gives no value).
GAP = range(22, 26)
FROZEN = range(15, 20)
SCANS: list[tuple[int, int, list[float]]] = []  # (received, stamp, ranges)
for k in range(30):
    if k in GAP:
        continue
    received = 10 + 100 * k
    stamp = received - 5
    if k in FROZEN:
        stamp = 10 + 100 * 14 - 5
    if k == 3:
        stamp = received + 3
    ranges = [0.3, 2.0] if k == 8 else [] if k == 14 else [1.0, 2.0, math.nan]
    SCANS.append((received, stamp, ranges))
# /diagnostics: (received, levels); the first message starts the replay at T0
DIAGNOSTICS = [(0, [0, 1]), (1205, [0, 2]), (1605, [1]), (2005, [1, 0, 1]), (3005, [0])]
# /navigate/_action/status: (received, [(goal, status)])
ACCEPTED, EXECUTING, SUCCEEDED = 1, 2, 4
GOALS = [(705, [(1, ACCEPTED)]), (1505, [(1, EXECUTING)]), (2105, [(1, SUCCEEDED)])]
# /dock/_service_event: (received, event_type, success); the server and the client
# both publish the response; a request in between is not a response
REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = 1, 2, 3
CALLS = [
    (1005, RESPONSE_SENT, True),
    (1006, RESPONSE_RECEIVED, True),
    (1805, REQUEST_RECEIVED, None),
    (1905, RESPONSE_SENT, False),
]
END = 3005  # the last message: ticks at +0, +100, ... +3000

# Worked out by hand.  The grid is +0, +100, ...; a tick sees the messages received
# before it.  Every input has a value from +10 (the first scan), but the rate is known
# only a whole window (500 ms) after its first scan (+10): tick 0 is at +600, tick n at
# +600+100n.
# - fresh_scan (age >= 250 ms): the frozen stamp (+1405) is 295 ms old at +1700 and
#   stays so until the fresh stamp of +2010: +1700..+2000; after the gap's last scan
#   (+2110, stamped +2105): +2400..+2600 -> ticks 11..14, 18..20
# - scan_rate (< 8/s: at most 3 scans in (t - 500, t]): +2400..+2900 -> ticks 18..23
# - clear_front: the scan of +810 -> +900 -> tick 3 (the empty scan of +1410 keeps 1.0)
# - diag_ok (worst level 2 from +1205 to +1605): +1300..+1600 -> ticks 7..10
# - undocked_to_navigate: a goal accepted or executing from +705 to +2105, docked
#   from +1005 to +1905: +1100..+1900 -> ticks 5..13
EXPECTED = {
    "fresh_scan": [11, 12, 13, 14, 18, 19, 20],
    "scan_rate": [18, 19, 20, 21, 22, 23],
    "clear_front": [3],
    "diag_ok": [7, 8, 9, 10],
    "undocked_to_navigate": [5, 6, 7, 8, 9, 10, 11, 12, 13],
}
TICKS = 25  # +600 .. +3000


def oracle() -> tuple[dict[str, list[int]], dict[int, dict[str, Any]]]:
    """The violations and every tick's inputs, walked along the grid from the timeline."""
    out: dict[str, list[int]] = {i: [] for i in IDS}
    inputs: dict[int, dict[str, Any]] = {}
    tick = 0
    for j in range(END // 100 + 1):
        g = 100 * j
        scans = [s for s in SCANS if s[0] < g]
        readable = [s for s in scans if s[2]]
        diags = [d for d in DIAGNOSTICS if d[0] < g]
        if not readable or not diags or g - SCANS[0][0] < 500:
            continue
        goals = [m for m in GOALS if m[0] < g]
        calls = [c for c in CALLS if c[0] < g and c[1] in (RESPONSE_SENT, RESPONSE_RECEIVED)]
        v = {
            "front": readable[-1][2][0],
            "scan_age": float(g - scans[-1][1]),
            "scan_hz": len([s for s in scans if g - 500 < s[0] <= g]) / 0.5,
            "diag_level": max(diags[-1][1]),
            "nav_active": bool(goals) and any(s in (1, 2) for _, s in goals[-1][1]),
            "docked": bool(calls) and bool(calls[-1][2]),
        }
        inputs[tick] = v
        holds = {
            "fresh_scan": v["scan_age"] < 250,
            "scan_rate": v["scan_hz"] >= 8,
            "clear_front": v["front"] > 0.5,
            "diag_ok": v["diag_level"] < 2,
            "undocked_to_navigate": not v["nav_active"] or not v["docked"],
        }
        for rid, ok in holds.items():
            if not ok:
                out[rid].append(tick)
        tick += 1
    return out, inputs


def test_the_hand_worked_timeline_is_the_oracle():
    got, inputs = oracle()
    assert got == EXPECTED and len(inputs) == TICKS
    assert inputs[11]["scan_age"] == 295.0 and inputs[18]["scan_hz"] == 6.0


# ------------------------------------------------------------ the bag


def _time(ms: float) -> Any:
    ns = T0 + int(ms * MS)
    return TS.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def _header(ms: float) -> Any:
    return TS.types["std_msgs/msg/Header"](stamp=_time(ms), frame_id="laser")


def scan(stamp_ms: int, ranges: list[float]) -> Any:
    return TS.types["sensor_msgs/msg/LaserScan"](
        header=_header(stamp_ms), angle_min=0.0, angle_max=1.0, angle_increment=0.5,
        time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=30.0,
        ranges=np.array(ranges, dtype=np.float32), intensities=np.array([], dtype=np.float32),
    )  # fmt: skip


def diagnostics(ms: int, levels: list[int]) -> Any:
    status = TS.types["diagnostic_msgs/msg/DiagnosticStatus"]
    kv = TS.types["diagnostic_msgs/msg/KeyValue"]
    return TS.types["diagnostic_msgs/msg/DiagnosticArray"](
        header=_header(ms),
        status=[
            status(level=level, name=f"part{n}", message="", hardware_id="base",
                   values=[kv(key="k", value=str(n))] * n)
            for n, level in enumerate(levels)
        ],
    )  # fmt: skip


def goal_statuses(ms: int, goals: list[tuple[int, int]]) -> Any:
    t = TS.types
    return t["action_msgs/msg/GoalStatusArray"](
        status_list=[
            t["action_msgs/msg/GoalStatus"](
                goal_info=t["action_msgs/msg/GoalInfo"](
                    goal_id=t["unique_identifier_msgs/msg/UUID"](
                        uuid=np.array([n] * 8 + [255 - n] * 8, dtype=np.uint8)
                    ),
                    stamp=_time(ms),
                ),
                status=status,
            )
            for n, status in goals
        ]
    )


def service_event(ms: int, event_type: int, success: bool | None) -> Any:
    t = TS.types
    info = t["service_msgs/msg/ServiceEventInfo"](
        event_type=event_type,
        stamp=_time(ms),
        client_gid=np.arange(16, dtype=np.uint8),
        sequence_number=1,
    )
    request = [t["std_srvs/srv/Trigger_Request"](structure_needs_at_least_one_member=0)]
    response = (
        [] if success is None else [t["std_srvs/srv/Trigger_Response"](success=success, message="")]
    )
    return t[EVENT](info=info, request=request, response=response)


def write_bag(
    path: Path,
    plugin: StoragePlugin,
    encoding: str = "idl",
    diagnostic: list[tuple[int, list[int]]] = DIAGNOSTICS,
) -> Path:
    msgs: list[tuple[int, str, str, Any]] = []
    for received, stamp, ranges in SCANS:
        msgs.append((received, "/scan", "sensor_msgs/msg/LaserScan", scan(stamp, ranges)))
    for received, levels in diagnostic:
        msgs.append((received, "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray",
                     diagnostics(received, levels)))  # fmt: skip
    for received, goals in GOALS:
        msgs.append((received, "/navigate/_action/status", "action_msgs/msg/GoalStatusArray",
                     goal_statuses(received, goals)))  # fmt: skip
    for received, kind, success in CALLS:
        msgs.append(
            (received, "/dock/_service_event", EVENT, service_event(received, kind, success))
        )
    msgs.sort(key=lambda m: m[0])
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns: dict[str, Any] = {}
        for received, topic, typ, msg in msgs:
            if topic not in conns:
                if typ == EVENT:
                    conns[topic] = w.add_connection(
                        topic, typ, msgdef=event_msgdef(encoding), rihs01="RIHS01_" + "0" * 64
                    )
                else:
                    conns[topic] = w.add_connection(topic, typ, typestore=TS)
            w.write(conns[topic], T0 + received * MS, bytes(TS.serialize_cdr(msg, typ)))
    return path


def test_the_service_event_serialises_as_rclpy_reads_it():
    """The registered Trigger_Event is ROS 2's: rclpy reads rosbags' bytes back."""
    from rclpy.serialization import deserialize_message
    from std_srvs.srv import Trigger_Event

    data = bytes(TS.serialize_cdr(service_event(5, RESPONSE_SENT, True), EVENT))
    back = deserialize_message(data, Trigger_Event)
    assert back.info.event_type == RESPONSE_SENT and list(back.info.client_gid) == list(range(16))
    assert len(back.request) == 1 and back.response[0].success is True


def run_replay(tmp_path: Path, bag: Path) -> tuple[subprocess.CompletedProcess, list[dict]]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(CONFIG)
    out = tmp_path / "out.jsonl"
    run = cli_main("replay", cfg, bag, "-o", out, "--quiet")  # in-process: tests/support/inproc.py
    records = list(iter_records(str(out))) if out.exists() else []
    return run, records


@pytest.mark.parametrize(
    "plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3], ids=["mcap", "sqlite3"]
)
def test_replay_reports_exactly_the_hand_worked_violations(tmp_path, plugin):
    bag = write_bag(tmp_path / "bag", plugin)
    run, records = run_replay(tmp_path, bag)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    violations = [r for r in records if r["event"] == "violation"]
    got = {rid: [r["tick"] for r in violations if r["requirement"] == rid] for rid in IDS}
    assert got == EXPECTED
    # each violation saw the inputs of the timeline at its tick
    _, inputs = oracle()
    for r in violations:
        want = inputs[r["tick"]]
        assert r["inputs"]["front"] == pytest.approx(want["front"]), r
        assert r["inputs"]["scan_age"] == pytest.approx(want["scan_age"]), r
        assert r["inputs"]["scan_hz"] == pytest.approx(want["scan_hz"]), r
        assert r["inputs"]["diag_level"] == want["diag_level"], r
        assert r["inputs"]["nav_active"] is want["nav_active"], r
        assert r["inputs"]["docked"] is want["docked"], r
    # the scan stamped after its receipt is said once
    future = [r for r in records if r.get("what") == "input_future_stamp"]
    assert [r.get("input") for r in future] == ["scan_age"]
    # the summary: every message replayed, the ticks of the grid
    assert run.stdout.split()[1] == str(len(SCANS) + len(DIAGNOSTICS) + len(GOALS) + len(CALLS))
    assert f" {TICKS} ticks" in run.stdout


def test_replay_reads_a_service_event_defined_in_msg_form(tmp_path):
    bag = write_bag(tmp_path / "bag", StoragePlugin.MCAP, encoding="msg")
    run, records = run_replay(tmp_path, bag)
    assert run.returncode == 0, run.stderr
    violations = [r for r in records if r["event"] == "violation"]
    got = {rid: [r["tick"] for r in violations if r["requirement"] == rid] for rid in IDS}
    assert got == EXPECTED


def test_replay_rejects_the_max_of_no_status_for_an_int64_as_the_daemon_does(tmp_path):
    empty = sorted([*DIAGNOSTICS, (1705, [])])  # the worst level of nothing: -inf
    bag = write_bag(tmp_path / "bag", StoragePlugin.MCAP, diagnostic=empty)
    run, records = run_replay(tmp_path, bag)
    assert run.returncode == 0, run.stderr
    violations = [r for r in records if r["event"] == "violation"]
    got = {rid: [r["tick"] for r in violations if r["requirement"] == rid] for rid in IDS}
    assert got == EXPECTED  # the rejected value leaves level 1 of +1605 in place
    rejected = [r for r in records if r.get("what") == "input_rejected"]
    # as the daemon logs them: the scan without ranges (k = 14) has no ranges[0],
    # and -inf is no int64
    assert [r.get("input") for r in rejected] == ["front", "diag_level"]
    assert "0 elements" in rejected[0]["detail"] and "inf" in rejected[1]["detail"]


def test_replay_logs_an_element_past_the_end_as_the_daemon_does(tmp_path):
    bag = write_bag(tmp_path / "bag", StoragePlugin.SQLITE3)
    run, records = run_replay(tmp_path, bag)
    assert run.returncode == 0, run.stderr
    rejected = [r for r in records if r.get("what") == "input_rejected"]
    assert [r.get("input") for r in rejected] == ["front"]
