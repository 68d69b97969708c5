"""Config loading: the shipped configs, FRET/OGMA import, and line-numbered errors."""

import json
import textwrap
from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.config import load_config, load_fret_export, load_ogma_variables

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"

BASE = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements:
  - id: r1
    text: sw shall always satisfy p
    on_violation: [halt]
mitigations:
  halt: {publish: {topic: /halt, msg: std_msgs/msg/Bool, value: {data: true}}}
"""


def write(tmp_path, text, name="c.yaml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def error_of(tmp_path, text):
    with pytest.raises(UserError) as e:
        load_config(write(tmp_path, text))
    return e.value


def test_srobot_config_has_the_thesis_requirements():
    cfg = load_config(ROOT / "config" / "srobot.yaml")
    assert cfg.component == "sRobot"
    assert len(cfg.requirements) == 13
    assert [v.name for v in cfg.inputs] == [
        "classifier",
        "distance_to_target",
        "OpState",
        "alert",
        "halt",
        "slowdown",
        "turnoffUVC",
    ]
    assert {v.name for v in cfg.defines} == {"dgt_3", "dgt_7"}
    assert cfg.requirement("state_req103").on_violation == ["stop_robot", "uv_off"]
    assert cfg.requirement("classifier_assumption").assumption
    assert cfg.step.policy == "on_trigger" and cfg.step.trigger == "turnoffUVC"
    assert len(cfg.sha256) == 64


def test_fret_export_import():
    reqs, internal, other = load_fret_export(DATA / "sRobot-fret-export.json")
    assert len(reqs) == 13
    assert reqs[0].id == "classifier_assumption" and reqs[0].assumption
    assert reqs[9].fret_ptltl.startswith("(H ((classifier = 1)")
    assert {v["name"] for v in internal} == {"dgt_3", "dgt_7"}
    assert len(other) == 7


def test_ogma_old_line_format():
    vs = load_ogma_variables(DATA / "sRobot-ogma-variable-db.txt")
    by = {v["name"]: v for v in vs}
    assert by["distance_to_target"] == {
        "name": "distance_to_target",
        "type": "int64",
        "topic": "/scan",
        "msg": "std_msgs/msg/Int64",
        "field": "data",
        "line": 1,
    }
    assert by["halt"]["msg"] == "std_msgs/msg/Bool"


def test_ogma_json_format(tmp_path):
    db = {
        "inputs": [
            {
                "name": "speed",
                "type": "float64",
                "connections": [
                    {"scope": "ros/message", "topic": "/odom", "field": "twist.twist.linear.x"}
                ],
            }
        ],
        "topics": [{"scope": "ros/message", "topic": "/odom", "type": "nav_msgs::msg::Odometry"}],
        "types": [],
    }
    p = tmp_path / "db.json"
    p.write_text(json.dumps(db))
    [v] = load_ogma_variables(p)
    assert (
        v["msg"] == "nav_msgs/msg/Odometry"
        and v["field"] == "twist.twist.linear.x"
        and v["type"] == "double"
    )


def test_ogma_bad_line_is_located(tmp_path):
    p = tmp_path / "db.txt"
    p.write_text('("a","bool","/a","bool")\n("b","int64_t","/b")\n')
    with pytest.raises(UserError) as e:
        load_ogma_variables(p)
    assert str(e.value).startswith(f"{p}:2: ")


def test_config_from_fret_and_ogma_files():
    cfg = load_config(ROOT / "config" / "srobot-from-fret.yaml")
    assert len(cfg.requirements) == 13
    r = cfg.requirement("state_req103")
    assert r.on_violation == ["stop_robot", "uv_off"] and r.fret_ptltl
    assert cfg.requirement("state_req000").on_violation == ["record"]
    assert cfg.variables["OpState"].topic == "/sRobotState"


@pytest.mark.parametrize(
    ("edit", "line", "needle"),
    [
        (("  x: {type: int64", "  x: {typ: int64"), 5, "unknown key 'typ'"),
        (("    on_violation: [halt]", "    on_violation: [hlt]"), 9, "undefined mitigation 'hlt'"),
        (("  p: {type: bool", "  S: {type: bool"), 4, "reserved word"),
        (
            ("  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}", "  x: {type: int64}"),
            5,
            "has no topic",
        ),
        (("  x: {type: int64", "  x: {type: int32x"), 5, "unknown type 'int32x'"),
        (("step: {policy: periodic", "step: {policy: sometimes"), 2, "unknown step policy"),
        (
            ("  halt: {publish: {topic: /halt,", "  halt: {publish: {tpic: /halt,"),
            11,
            "needs 'topic'",
        ),
    ],
)
def test_config_errors_name_file_and_line(tmp_path, edit, line, needle):
    e = error_of(tmp_path, BASE.replace(*edit))
    assert e.line == line, str(e)
    assert needle in e.message
    assert str(e).startswith(f"{tmp_path / 'c.yaml'}:{line}")


def test_duplicate_requirement_id(tmp_path):
    text = BASE.replace(
        "mitigations:", "  - id: r1\n    text: sw shall always satisfy x > 0\nmitigations:"
    )
    e = error_of(tmp_path, text)
    assert "duplicate requirement id 'r1'" in e.message and e.line == 10


def test_duplicate_yaml_key(tmp_path):
    e = error_of(tmp_path, BASE.replace("  x: {type: int64", "  p: {type: int64"))
    assert "duplicate key 'p'" in e.message and e.line == 5


def test_malformed_yaml(tmp_path):
    e = error_of(tmp_path, BASE.replace("  p: {type: bool,", "  p: {type: bool,,]"))
    assert e.message.startswith("invalid YAML") and e.line == 4


def test_unknown_top_level_key_suggests(tmp_path):
    e = error_of(tmp_path, BASE.replace("mitigations:", "mitigation:"))
    assert "did you mean 'mitigations'" in str(e)


MITIGATION_BASE = """component: T
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
requirements:
  - {id: r, text: T shall always satisfy p, on_violation: [m]}
mitigations:
  m: MITIGATION
"""


@pytest.mark.parametrize(
    ("mitigation", "expected"),
    [
        ("{command: {argv: [/bin/true], retries: 2, backoff_s: 0.1}}", None),
        ("{command: {argv: [/bin/true], timeout_s: 0}}", "'timeout_s' must be positive"),
        ("{command: {argv: [/bin/true], env: [A]}}", "'env' must be a mapping"),
        (
            "{ssh: {host: h, user: u, key: k, known_hosts: kh, command: c, port: '22'}}",
            "'port' must be a port number",
        ),
        (
            "{ssh: {host: h, user: u, key: k, known_hosts: kh, command: c, retries: 0}}",
            "'retries' must be a whole number",
        ),
        (
            "{ssh: {host: h, user: u, key: k, known_hosts: kh, command: c, backoff_s: -1}}",
            "'backoff_s' must not be negative",
        ),
        (
            "{ssh: {host: '', user: u, key: k, known_hosts: kh, command: c}}",
            "'host' must be a non-empty string",
        ),
        ("{publish: {topic: /h, msg: std_msgs/msg/Bool, qos: sticky}}", "unknown qos 'sticky'"),
    ],
)
def test_mitigation_settings(tmp_path: Path, mitigation: str, expected: str | None) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(MITIGATION_BASE.replace("MITIGATION", mitigation))
    if expected is None:
        load_config(path)
        return
    with pytest.raises(UserError) as e:
        load_config(path)
    assert expected in str(e.value) and ":7:" in str(e.value)


def test_publish_value_checked_against_the_message(tmp_path: Path) -> None:
    from supervisor.pipeline import project_for

    path = tmp_path / "c.yaml"
    path.write_text(
        MITIGATION_BASE.replace(
            "MITIGATION", "{publish: {topic: /h, msg: std_msgs/msg/Bool, value: {dat: true}}}"
        )
    )
    errors = [str(e) for e in project_for(path).errors]
    assert any(":7:" in e and "mitigation 'm'" in e and "no field 'dat'" in e for e in errors), (
        errors
    )
