"""Config loading: the shipped configs, FRET/OGMA import, and line-numbered errors."""

import json
import textwrap
from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.config import load_config, load_fret_export, load_ogma_variables

ROOT = Path(__file__).resolve().parents[3]
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


def test_keyword_like_and_spaced_names_are_variables(tmp_path):
    # FRET takes them quoted; formula text writes them as FRET does (docs/reference/config.md).
    text = BASE.replace("  p: {type: bool", "  T: {type: bool").replace(
        "  x: {type: int64", "  left wheel: {type: int64"
    )
    text = text.replace("satisfy p", 'satisfy "T" | "left wheel" > 2')
    cfg = load_config(write(tmp_path, text))
    assert {"T", "left wheel"} <= set(cfg.variables)


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
        (("  p: {type: bool", "  _DQT_p_DQT_: {type: bool"), 4, "not a usable variable name"),
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
step: {policy: periodic, period_ms: 100}
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


# ------------------------------------------------------------------ numbers and nesting
# Every number is finite and in range at its own line, whichever section holds
# it (docs/reference/config.md, Limits); a config that loads never fails later
# on a number.

MS_KEYS = {  # a config with KEY set to VALUE, and the line the key is on
    "step.period_ms": (BASE.replace("period_ms: 100", "period_ms: VALUE"), 2),
    "step.stale_after_ms": (
        BASE.replace("period_ms: 100}", "period_ms: 100, stale_after_ms: VALUE}"),
        2,
    ),
    "variable stale_after_ms": (
        BASE.replace(
            "msg: std_msgs/msg/Bool}", "msg: std_msgs/msg/Bool, stale_after_ms: VALUE}", 1
        ),
        4,
    ),
    "policy cooldown_ms": (
        BASE.replace(
            "    on_violation: [halt]\n",
            "    on_violation: [halt]\n    policy: {cooldown_ms: VALUE}\n",
        ),
        10,
    ),
    "ros.heartbeat_ms": (BASE + "ros: {heartbeat_ms: VALUE}\n", 12),
}
BAD_NUMBERS = {
    ".nan": "finite",
    "-.inf": "finite",
    ".inf": "finite",
    "'nan'": "finite",
    "'1e999'": "finite",
    "1" + "0" * 400: "number",
    "1" + "0" * 5000: "too long",
    "1.0e+300": "at most",
    "-5": "negative",
    "true": "number",
    "fast": "number",
}


@pytest.mark.parametrize("key", sorted(MS_KEYS))
@pytest.mark.parametrize("value", sorted(BAD_NUMBERS))
def test_every_duration_is_finite_and_in_range_at_its_line(tmp_path, key, value):
    text, line = MS_KEYS[key]
    e = error_of(tmp_path, text.replace("VALUE", value))
    assert e.line == line, str(e)
    assert BAD_NUMBERS[value] in str(e) or "positive" in str(e), str(e)


def test_every_yaml_number_is_finite_wherever_it_is(tmp_path):
    text = BASE.replace("value: {data: true}", "value: {data: .nan}")
    assert error_of(tmp_path, text).line == 11
    text = BASE + "analysis: {timeout_s: .inf}\n"
    assert error_of(tmp_path, text).line == 12


@pytest.mark.parametrize("value", ["0", "-5", "1.5", "4294967296", "lots", "[1]"])
def test_the_resource_limit_is_a_whole_number_of_z3_units_at_its_line(tmp_path, value):
    e = error_of(tmp_path, BASE + f"analysis:\n  k: 4\n  rlimit: {value}\n")
    assert e.line == 14 and "analysis.rlimit must be a whole number" in str(e), str(e)


def test_the_resource_limit_is_read_and_defaults_to_the_analyses(tmp_path):
    from monitors.verify.analysis import DEFAULT_RLIMIT

    path = tmp_path / "c.yaml"
    path.write_text(BASE + "analysis: {rlimit: 1234}\n")
    assert load_config(path).analysis.rlimit == 1234
    path.write_text(BASE)
    assert load_config(path).analysis.rlimit == DEFAULT_RLIMIT


@pytest.mark.parametrize(
    ("range_", "needle"),
    [("[2, 0]", "is empty"), ("[a, 1]", "must be a number"), ("['nan', 1]", "finite")],
)
def test_a_range_is_two_ordered_finite_numbers(tmp_path, range_, needle):
    text = BASE.replace("Int64}", f"Int64, range: {range_}}}")
    e = error_of(tmp_path, text)
    assert e.line == 5 and needle in str(e), str(e)


@pytest.mark.parametrize(
    ("initial", "ok"),
    [("9223372036854775807", True), ("9223372036854775808", False), ("'1' * 5000", False)],
)
def test_an_int64_initial_fits_in_int64(tmp_path, initial, ok):
    value = "1" * 5000 if initial.startswith("'1'") else initial
    text = BASE.replace("Int64}", f"Int64, initial: '{value}'}}")
    if ok:
        assert load_config(write(tmp_path, text)).variables["x"].initial == int(value)
    else:
        assert error_of(tmp_path, text).line == 5


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        ("depth: " + "9" * 30, "depth must be a whole number"),
        ("depth: 0", "depth must be a whole number"),
    ],
)
def test_whole_numbers_are_bounded(tmp_path, edit, needle):
    e = error_of(tmp_path, BASE.replace("Int64}", f"Int64, {edit}}}"))
    assert e.line == 5 and needle in str(e)
    e = error_of(tmp_path, BASE + "logging: {recent: 99999999999999999999}\n")
    assert e.line == 12 and "recent must be a whole number" in str(e)


@pytest.mark.parametrize("open_, close", [("[", "]"), ("{a: ", "}")])
def test_deep_yaml_is_refused_at_its_line(tmp_path, open_, close):
    text = BASE + "analysis: " + open_ * 10000 + "1" + close * 10000 + "\n"
    e = error_of(tmp_path, text)
    assert e.line == 12 and "nested more than 50 levels" in str(e)


def test_a_date_like_value_is_text(tmp_path):
    # PyYAML would build a date (and fail with no line on 2001-13-45); no key takes one.
    for date in ("2001-12-14", "2001-13-45"):
        cfg = load_config(write(tmp_path, BASE.replace("component: sw", f"component: {date}")))
        assert cfg.component == date


def test_no_step_section_is_an_error_not_a_default_without_a_period(tmp_path):
    e = error_of(tmp_path, BASE.replace("step: {policy: periodic, period_ms: 100}\n", ""))
    assert "no 'step:' section" in str(e) and e.line is not None


def test_a_variable_read_only_by_a_policy_confirmation_is_used(tmp_path):
    from supervisor.pipeline import project_for

    text = BASE.replace(
        "    on_violation: [halt]\n",
        "    on_violation: [halt]\n    policy: {confirm: {variable: x, equals: 1, within_ms: 200}}\n",
    )
    project = project_for(write(tmp_path, text))
    assert project.ok, [str(e) for e in project.errors]
    unused = project_for(write(tmp_path, BASE))
    assert any("'x' is declared but no requirement uses it" in str(e) for e in unused.errors)


@pytest.mark.parametrize("value", ["[1, 2]", "7", "text"])
def test_every_section_must_be_a_mapping(tmp_path, value):
    e = error_of(tmp_path, BASE + f"analysis: {value}\n")
    assert e.line == 12 and "analysis must be a mapping" in str(e)


@pytest.mark.parametrize("value", ["1" + "0" * 400, "1.0e+300", "10000000"])
def test_mitigation_seconds_are_bounded(tmp_path, value):
    path = tmp_path / "c.yaml"
    path.write_text(
        MITIGATION_BASE.replace(
            "MITIGATION", f"{{command: {{argv: [/bin/true], timeout_s: {value}}}}}"
        )
    )
    with pytest.raises(UserError, match="must be at most 1e\\+06 seconds") as e:
        load_config(path)
    assert e.value.line == 7  # mitigations: m: {...}


@pytest.mark.parametrize("k", ["0", "1" + "0" * 400, "100001"])
def test_analysis_k_is_bounded(tmp_path, k):
    with pytest.raises(UserError, match="from 1 to 100000") as e:
        load_config(write(tmp_path, BASE + f"analysis: {{k: {k}}}\n"))
    assert e.value.line == 12
