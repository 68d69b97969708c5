"""The config's error and warning lines for paths the other config tests leave
out: requirement items, variable sources and defines (docs/reference/config.md).
Each line is compared whole, so a change of wording, line or hint shows."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.pipeline import project_for

HEAD = "component: sw\nstep: {policy: periodic, period_ms: 100}\n"
MIT = "mitigations:\n  halt: {log: {message: x}}\n"
VAR_P = "variables:\n  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}\n"


def _req(text: str) -> str:
    return f"requirements:\n  - id: r1\n    text: {text}\n    on_violation: [halt]\n"


REQ_P = _req("sw shall always satisfy p")

RAISED = {
    "unknown key in requirement_defaults": (
        HEAD + "requirement_defaults:\n  on_violaton: [halt]\n" + VAR_P + REQ_P + MIT,
        "{f}:4: unknown key 'on_violaton' in requirement_defaults "
        "(hint: did you mean 'on_violation'?)",
    ),
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
    "step trigger read by no requirement": (
        "component: sw\nstep: {policy: on_trigger, trigger: t}\n"
        + VAR_P
        + "  t: {type: bool, topic: /t, msg: std_msgs/msg/Bool}\n"
        + REQ_P
        + MIT,
        [],
        [],
    ),
    "input read by no requirement": (
        HEAD + VAR_P + "  t: {type: bool, topic: /t, msg: std_msgs/msg/Bool}\n" + REQ_P + MIT,
        [
            "{f}:5: variable 't' is declared but no requirement uses it "
            "(hint: remove it, or it may be a typo in a requirement)"
        ],
        [],
    ),
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


LPC = Path(__file__).resolve().parents[2] / "data" / "fret" / "LPC_mini_reqts_and_vars.json"
LPC_HEAD = f"""\
component: vehicle
step: {{policy: periodic, period_ms: 100}}
requirements_from: {LPC}
requirement_defaults:
  on_violation: [halt]
  policy: {{cooldown_ms: 500}}
"""
LPC_VARS = """\
variables:
  hover_control_mode: {topic: /vehicle/hover, msg: std_msgs/msg/Bool}
  kgs: {topic: /vehicle/kgs, msg: std_msgs/msg/Float64}
  kias: {topic: /vehicle/kias, msg: std_msgs/msg/Float64}
  lift_mode: {topic: /vehicle/lift_mode, msg: std_msgs/msg/Int64}
"""


def _fields(entry: Any) -> tuple[Any, ...]:
    return (
        entry.text,
        entry.file,
        entry.line,
        entry.col,
        entry.id_line,
        entry.rationale,
        entry.on_violation,
        entry.on_violation_line,
        dict(entry.policy),
        entry.policy_line,
        entry.assumption,
        entry.fret_ptltl,
    )


def test_requirement_entries_take_the_defaults_and_a_refinement_keeps_the_import(
    tmp_path: Path,
) -> None:
    imported = tmp_path / "imported.yaml"
    imported.write_text(LPC_HEAD + LPC_VARS + MIT)
    base = {e.id: e for e in load_config(imported).requirements}
    first = base["LPC_TB_STAY_ON_NEXT"]
    assert first.on_violation == ["halt"] and first.policy == {"cooldown_ms": 500}
    assert (first.id_line, first.line, first.fret_ptltl is not None) == (3, None, True)

    refined = tmp_path / "refined.yaml"
    refined.write_text(
        LPC_HEAD
        + LPC_VARS
        + "requirements:\n"
        + "  - id: LPC_TB_STAY_ON_NEXT\n    rationale: why\n"
        + "  - id: new_assumption\n    text: vehicle shall always satisfy kgs <= 20.0\n"
        + "  - id: other\n    text: vehicle shall always satisfy kias <= 20.0\n"
        + "    on_violation: []\n    policy: {latch: true}\n    assumption: 'True'\n"
        + MIT
    )
    got = {e.id: e for e in load_config(refined).requirements}
    assert list(got)[: len(base)] == list(base)
    path = str(refined)
    assert _fields(got["LPC_TB_STAY_ON_NEXT"]) == (
        first.text,
        first.file,
        None,
        1,
        13,
        "why",
        ["halt"],
        13,
        {"cooldown_ms": 500},
        6,
        False,
        first.fret_ptltl,
    )
    assert _fields(got["new_assumption"]) == (
        "vehicle shall always satisfy kgs <= 20.0",
        path,
        16,
        11,
        15,
        "",
        ["halt"],
        15,
        {"cooldown_ms": 500},
        6,
        True,
        None,
    )
    assert _fields(got["other"]) == (
        "vehicle shall always satisfy kias <= 20.0",
        path,
        18,
        11,
        17,
        "",
        [],
        19,
        {"latch": True},
        20,
        True,
        None,
    )


OGMA = Path(__file__).resolve().parents[2] / "data" / "sRobot-ogma-variable-db.txt"


def test_a_yaml_entry_refining_an_ogma_variable_keeps_its_topic_msg_and_field(
    tmp_path: Path,
) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(
        "component: sRobot\nstep: {policy: periodic, period_ms: 100}\n"
        f"variables_from: {OGMA}\n"
        "variables:\n  alert: {type: bool, depth: 3}\n"
        "requirements:\n  - id: r1\n    text: sRobot shall always satisfy alert\n" + MIT
    )
    v = load_config(path).variables["alert"]
    assert (v.topic, v.msg, v.field, v.depth) == ("/sRobotAlert", "std_msgs/msg/Bool", "data", 3)


def test_fret_parent_requirements_are_left_out_with_a_note_each(tmp_path: Path) -> None:
    export = tmp_path / "fret.json"
    export.write_text(
        json.dumps(
            {
                "requirements": [
                    {"reqid": "", "fulltext": ""},
                    {"reqid": "P", "fulltext": "", "semantics": {}},
                    {"reqid": "r1", "fulltext": "sw shall always satisfy p", "semantics": {}},
                ],
                "variables": [],
            }
        )
    )
    path = tmp_path / "c.yaml"
    path.write_text(
        f"component: sw\nstep: {{policy: periodic, period_ms: 100}}\nrequirements_from: {export}\n"
        + VAR_P
        + MIT
    )
    cfg = load_config(path)
    assert [e.id for e in cfg.requirements] == ["r1"]
    assert cfg.notes == [
        f"{path}:3: note: {export}: requirement '{name}' has no text (a parent requirement "
        "in FRET); left out"
        for name in ("(no id)", "P")
    ]
