"""The config's error and warning lines for paths the other config tests leave
out: requirement items, variable sources and defines (docs/reference/config.md).
Each line is compared whole, so a change of wording, line or hint shows."""

from __future__ import annotations

from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.pipeline import project_for

HEAD = "component: sw\nstep: {policy: periodic, period_ms: 100}\n"
MIT = "mitigations:\n  halt: {log: {message: x}}\n"
VAR_P = "variables:\n  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}\n"


def _req(text: str) -> str:
    return f"requirements:\n  - id: r1\n    text: {text}\n    on_violation: [halt]\n"


REQ_P = _req("sw shall always satisfy p")

RAISED = {
    "requirements not a list": (
        HEAD + VAR_P + "requirements: {a: 1}\n" + MIT,
        "{f}:5: 'requirements' must be a list of {{id, text, ...}}",
    ),
    "requirement not a mapping": (
        HEAD + VAR_P + "requirements:\n  - just text\n" + MIT,
        "{f}:6: each requirement must be a mapping with id and text",
    ),
    "control character in text": (
        HEAD
        + VAR_P
        + 'requirements:\n  - id: r1\n    text: "sw shall always \\u0007 satisfy p"\n'
        + MIT,
        "{f}:7:12: requirement 'r1': its text holds a control character (\\x07) at character 17",
    ),
    "requirement without text": (
        HEAD + VAR_P + "requirements:\n  - id: r1\n    on_violation: [halt]\n" + MIT,
        "{f}:6: requirement 'r1' has no text (hint: add text: <FRETISH sentence>)",
    ),
    "topic without msg": (
        HEAD + "variables:\n  p: {type: bool, topic: /p}\n" + REQ_P + MIT,
        "{f}:4: variable 'p' needs msg: the ROS 2 message type of /p",
    ),
    "service of no service type": (
        HEAD
        + "variables:\n  p: {type: bool, service: /s, srv: notatype, call: request, field: x}\n"
        + REQ_P
        + MIT,
        "{f}:4: variable 'p': 'notatype' is not a ROS 2 service type "
        "(hint: write it as package/srv/Name)",
    ),
    "service reduce without field": (
        HEAD + "variables:\n  p: {type: bool, service: /s, srv: std_srvs/srv/SetBool, "
        "call: request, event: true, reduce: any}\n" + REQ_P + MIT,
        "{f}:4: variable 'p': reduce needs a field:",
    ),
    "age_of not a name": (
        HEAD + VAR_P + "  a: {type: double, age_of: [p]}\n" + REQ_P + MIT,
        "{f}:5: variable 'a': age_of names an input variable",
    ),
}


@pytest.mark.parametrize("case", sorted(RAISED))
def test_config_error_is_one_line_at_its_place(tmp_path: Path, case: str) -> None:
    text, expected = RAISED[case]
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(UserError) as e:
        project_for(path, ros=False)
    assert str(e.value) == expected.format(f=path)


CHECKED = {
    "define reads an undeclared variable": (
        HEAD
        + VAR_P
        + "  d: {type: bool, define: p & q}\n"
        + _req("sw shall always satisfy d")
        + MIT,
        ["{f}:5: define of 'd' uses undeclared variable 'q' (hint: declare it under 'variables:')"],
        [],
    ),
    "define reads an internal variable": (
        HEAD
        + VAR_P
        + "  e: {type: bool, define: p}\n  d: {type: bool, define: e}\n"
        + _req("sw shall always satisfy d & e")
        + MIT,
        ["{f}:6: define of 'd' uses internal variable 'e'; write it in terms of inputs"],
        [],
    ),
    "define of another type": (
        HEAD
        + "variables:\n  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}\n"
        + "  d: {type: bool, define: x + 1}\n"
        + _req("sw shall always satisfy d")
        + MIT,
        ["{f}:5: 'd' is declared bool but its define is int64"],
        [],
    ),
    "synchronized without max_skew_ms": (
        "component: sw\nstep: {policy: synchronized}\n" + VAR_P + REQ_P + MIT,
        [],
        [
            "{f}:2: step.policy synchronized without max_skew_ms: one partial round (a lost "
            "or late message) shifts every later step by one topic; set max_skew_ms below "
            "the robot's publishing period"
        ],
    ),
}


@pytest.mark.parametrize("case", sorted(CHECKED))
def test_check_reports_each_variable_problem_at_its_line(tmp_path: Path, case: str) -> None:
    text, errors, warnings = CHECKED[case]
    path = tmp_path / "c.yaml"
    path.write_text(text)
    project = project_for(path, ros=False)
    assert [str(e) for e in project.errors] == [e.format(f=path) for e in errors]
    assert project.warnings == [w.format(f=path) for w in warnings]
