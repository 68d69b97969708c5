"""Event variables (``event: true``): true only at the tick at which their message
arrived, for messages whose arrival is the fact (an estop button, std_msgs/Empty).
The runtime, the config's checks, replay, and the daemon over real DDS."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path
from typing import Any

import pytest

from monitors.backends.load import compile_spec
from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.daemon.runtime import InputSpec, Runtime
from supervisor.daemon.testing import RecordingMonitor
from supervisor.pipeline import project_for
from supervisor.tools.replay.session import replay_files

MS = 1_000_000

CONFIG = """\
component: base
step: {policy: periodic, period_ms: 20, stale_after_ms: 300}
variables:
  estop: {type: bool, topic: /estop, msg: std_msgs/msg/Empty, event: true}
  halt:  {type: bool, topic: /halt, msg: std_msgs/msg/Bool}
requirements:
  - id: estop_halts
    text: upon estop base shall within 10 ticks satisfy halt
    on_violation: [note]
    policy: {reset: after_mitigation}
mitigations:
  note: {log: {message: estop not followed by halt}}
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(textwrap.dedent(text))
    return p


@pytest.mark.parametrize("policy", ["periodic", "on_message"])
def test_an_event_is_true_at_one_step_only(policy):
    mon = RecordingMonitor(1)
    rt = Runtime(
        [InputSpec("button", "bool", event=True), InputSpec("x", "int64")],
        mon,
        policy=policy,
        period_ns=10 * MS if policy == "periodic" else None,
    )
    assert rt.ready is False  # x has no value yet; the event never blocks
    rt.on_message("x", 1, 1 * MS)
    assert rt.ready
    rt.on_message("button", None, 2 * MS)  # the message's content is not read
    if policy == "periodic":
        rt.on_timer(5 * MS)  # the grid starts here: the press is seen at this step
        rt.on_timer(15 * MS)
        rt.on_timer(25 * MS)
        assert [v[0] for v in mon.ticks] == [True, False, False]
    else:
        rt.on_message("x", 2, 3 * MS)
        assert [v[0] for v in mon.ticks[-3:]] == [False, True, False]


def test_an_event_is_not_stale_for_being_silent():
    rt = Runtime(
        [InputSpec("button", "bool", event=True)], RecordingMonitor(1), policy="on_message"
    )
    rt.on_message("button", None, 1 * MS)
    assert rt.check_stale(10_000 * MS, 100 * MS) == []  # the step's limit is not its own
    own = Runtime(
        [InputSpec("button", "bool", event=True, stale_after_ns=100 * MS)],
        RecordingMonitor(1),
        policy="on_message",
    )
    own.on_message("button", None, 1 * MS)
    assert [e.what for e in own.check_stale(200 * MS, None)] == ["input_stale"]


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (("type: bool, topic: /estop", "type: int64, topic: /estop"), "an event is bool"),
        (("event: true}", "event: true, field: data}"), "reads no field"),
        (("event: true}", "event: yes please}"), "event must be true or false"),
    ],
)
def test_bad_event_variables_are_located(tmp_path, edit, needle):
    p = write(tmp_path, CONFIG.replace(*edit))
    with pytest.raises(UserError) as e:
        load_config(p)
    assert needle in e.value.message and e.value.line == 4


def test_check_accepts_an_empty_message_type(tmp_path):
    project = project_for(write(tmp_path, CONFIG))
    assert project.ok, project.first_error()
    spec = project.spec()
    compile_spec(spec, tmp_path / "b")  # an event is a bool input of the monitor


def test_replay_of_presses_with_and_without_a_halt(tmp_path):
    """A JSON-lines trace: the press at 100 ms is followed by a halt within 10
    ticks, the one at 500 ms is not: exactly one violation, 10 ticks after it."""
    lines = []
    for k in range(60):
        t = 10**9 + k * 20 * MS
        lines.append({"t_ns": t + 1, "name": "halt", "value": 120 <= k * 20 <= 200})
    lines += [
        {"t_ns": 10**9 + 100 * MS + 5, "name": "estop", "value": True},
        {"t_ns": 10**9 + 500 * MS + 5, "name": "estop", "value": True},
    ]
    lines.sort(key=lambda x: x["t_ns"])
    trace = tmp_path / "t.jsonl"
    trace.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    result = replay_files(write(tmp_path, CONFIG), [trace], tmp_path / "out.jsonl", None)
    row = next(r for r in result["requirements"] if r["id"] == "estop_halts")
    assert row["violations"] == 1
    # Steps every 20 ms from the first message; the one at that instant comes before
    # any value (no step), so the step at 20 k ms is tick k - 1. The press at 500 ms
    # is seen at 520 ms (tick 25); 10 ticks later: 35
    assert row["first_tick"] == 35


@pytest.mark.ros
def test_an_estop_without_halt_is_caught_over_dds(tmp_path: Path, robot_node: Any):
    from rosutil import Daemon, StatusWatch, messages, wait_matched
    from std_msgs.msg import Bool, Empty

    # A status document every 20 ms (one a tick): what the daemon has seen, awaited.
    d = Daemon(tmp_path, write(tmp_path, CONFIG + "ros: {status_ms: 20}\n"))
    try:
        d.wait_notify("READY=1", timeout=30)
        status = StatusWatch(robot_node)
        estop = robot_node.create_publisher(Empty, "/estop", 10)
        halt = robot_node.create_publisher(Bool, "/halt", 10)
        wait_matched([estop, halt])
        halt.publish(Bool(data=False))
        status.until("halt=False received", lambda doc: messages(doc, "halt") == 1)
        estop.publish(Empty())  # a press, and a halt in time: no violation
        halt.publish(Bool(data=True))
        both = status.until(
            "the press and the halt received",
            lambda doc: messages(doc, "estop") == 1 and messages(doc, "halt") == 2,
        )
        # 11 ticks later the press's 10 ticks are all judged
        status.until("the press's window judged", lambda doc: doc["ticks"] > both["ticks"] + 10)
        assert not [r for r in d.records() if r["event"] == "violation"]
        halt.publish(Bool(data=False))
        status.until("halt=False received again", lambda doc: messages(doc, "halt") == 3)
        estop.publish(Empty())  # a press and no halt: caught within 10 ticks
        v = d.wait_record(lambda r: r["event"] == "violation", "the estop violation", timeout=5)
        assert v["requirement"] == "estop_halts" and v["inputs"]["halt"] is False
        d.terminate()
    finally:
        d.close()
