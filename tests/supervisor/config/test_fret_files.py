"""FRET's and OGMA's real files (tests/data/fret, tests/data/ogma), imported end to end.

Every shape FRET writes is read by content; OGMA's JSON databases map every C and ROS
type name; imported variables no requirement uses are notes and are left out.
"""

import json
import textwrap
from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.cli import main as cli_main
from supervisor.config import load_config, load_fret_export, load_ogma_variables
from supervisor.config.ogma import OGMA_TYPES, ogma_type
from supervisor.pipeline import project_for

DATA = Path(__file__).resolve().parents[2] / "data"
LM = DATA / "fret" / "LM_reqts_and_vars.json"
LPC = DATA / "fret" / "LPC_mini_reqts_and_vars.json"
LM_OUTPUTS = {
    "stirring_motor",
    "timer_120sec_start",
    "timer_60sec_start",
    "valve_0",
    "valve_1",
    "valve_2",
}
LPC_TOPICS = """\
variables:
  hover_control_mode: {topic: /vehicle/hover, msg: std_msgs/msg/Bool}
  kgs: {topic: /vehicle/kgs, msg: std_msgs/msg/Float64}
  kias: {topic: /vehicle/kias, msg: std_msgs/msg/Float64}
  lift_mode: {topic: /vehicle/lift_mode, msg: std_msgs/msg/Int64}
"""
# FRET's own functions our FRETISH does not know yet (docs/reference/fretish.md):
# these sentences are expected to be refused, and named here so that the test
# notices when they are accepted.


def write(tmp_path: Path, text: str, name: str = "c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_requirements_and_variables_export():
    reqs, internal, other = load_fret_export(LM)
    # FRET's names are mapped to C identifiers, each kept for display
    assert len(reqs) == 12 and reqs[0].id == "LM_012" and reqs[0].display == "LM-012"
    assert reqs[0].text.startswith("when emergency_button the liquid_mixer shall")
    assert all(r.fret_ptltl and "<b>" not in r.fret_ptltl for r in reqs)
    assert internal == []
    # The Simulink model's ports (entries without idType) declare nothing.
    assert len(other) == 12
    assert {v["name"] for v in other if v["role"] == "output"} == LM_OUTPUTS
    assert {v["type"] for v in other} == {"bool"}


def test_internal_variables_become_defines():
    _reqs, internal, other = load_fret_export(LPC)
    assert {v["name"]: (v["type"], v["define"]) for v in internal} == {
        "semi_thrust_borne": ("int64", "1"),
        "semi_wing_borne": ("int64", "2"),
        "thrust_borne": ("int64", "0"),
        "wing_borne": ("int64", "3"),
    }
    assert {v["name"]: v["type"] for v in other} == {
        "hover_control_mode": "bool",
        "kgs": "double",
        "kias": "double",
        "lift_mode": "int64",
    }


def test_requirements_export_is_a_list(tmp_path):
    # FRET's requirements-only export is the list the other export calls "requirements".
    p = tmp_path / "fretRequirements.json"
    p.write_text(json.dumps(json.loads(LM.read_text())["requirements"]))
    reqs, internal, other = load_fret_export(p)
    assert [r.id for r in reqs] == [r.id for r in load_fret_export(LM)[0]]
    assert internal == [] and other == []


def test_copilot_export_from_ogma():
    reqs, internal, other = load_fret_export(DATA / "ogma" / "fcs-3-small.json")
    assert [(r.id, r.text) for r in reqs] == [
        ("testCopilot_001", "test_component shall satisfy (input_signal <= 5)")
    ]
    assert reqs[0].fret_ptltl == "(O (( input_signal <= 5 )))"
    assert internal == [] and other == [{"name": "input_signal", "type": "double"}]


@pytest.mark.parametrize(
    "content",
    ['{"a": 1, "b": 2}', "[1, 2]", '{"Spec": {"Requirements": 3}}', '"text"'],
)
def test_unknown_shape_names_the_shapes_we_read(tmp_path, content):
    p = tmp_path / "x.json"
    p.write_text(content)
    with pytest.raises(UserError) as e:
        load_fret_export(p)
    assert str(e.value).startswith(f"{p}: not a FRET file: expected the Copilot component export")
    assert "requirements export" in str(e.value) and "requirements and variables" in str(e.value)


def test_unknown_fret_data_type_is_an_error(tmp_path):
    data = json.loads(LPC.read_text())
    data["variables"][0]["dataType"] = "string"
    p = tmp_path / "x.json"
    p.write_text(json.dumps(data))
    with pytest.raises(UserError, match="FRET data type 'string', which has no monitor type"):
        load_fret_export(p)


def test_ogma_json_databases():
    vs = load_ogma_variables(DATA / "ogma" / "vars-db.json")
    assert [(v["name"], v["type"], v["topic"], v["msg"]) for v in vs] == [
        ("input_signal", "int64", "/demo/topic", "std_msgs/msg/Int64"),
        ("input_signal_float", "double", "/demo/topicf", "std_msgs/msg/Float32"),
        ("input_signal_double", "double", "/demo/topicd", "std_msgs/msg/Float64"),
    ]
    [v] = load_ogma_variables(DATA / "ogma" / "ros2-001-db.json")
    assert (v["name"], v["type"], v["msg"]) == ("input_value", "int64", "std_msgs/msg/Int32")


@pytest.mark.parametrize(
    ("ctype", "expected"),
    [
        *[(f"{u}int{n}_t", "int64") for u in ("", "u") for n in (8, 16, 32, 64)],
        *[(f"{u}int{n}", "int64") for u in ("", "u") for n in (8, 16, 32, 64)],
        ("std::uint8_t", "int64"),
        ("byte", "int64"),
        ("char", "int64"),
        ("int", "int64"),
        ("bool", "bool"),
        ("float", "double"),
        ("double", "double"),
        ("float32", "double"),
        ("float64", "double"),
        ("string", None),
        ("std_msgs::msg::Header", None),
    ],
)
def test_every_c_and_ros_type_is_mapped(ctype, expected):
    assert ogma_type(ctype) == expected


def test_every_mapped_type_reads_from_a_json_database(tmp_path):
    inputs = [
        {"name": f"v{i}", "type": t, "connections": [{"scope": "ros/message", "topic": f"/t{i}"}]}
        for i, t in enumerate(OGMA_TYPES)
    ]
    p = tmp_path / "db.json"
    p.write_text(json.dumps({"inputs": inputs, "topics": [], "types": []}))
    assert [v["type"] for v in load_ogma_variables(p)] == list(OGMA_TYPES.values())
    inputs[0]["type"] = "string"
    p.write_text(json.dumps({"inputs": inputs, "topics": [], "types": []}))
    with pytest.raises(UserError, match="'v0' has type 'string', which is not a C or ROS"):
        load_ogma_variables(p)


def test_old_line_format_takes_every_std_msgs_width(tmp_path):
    p = tmp_path / "db.txt"
    p.write_text('("x","uint16_t","/x","UInt16_t")\n("y","float","/y","float")\n')
    assert [(v["type"], v["msg"]) for v in load_ogma_variables(p)] == [
        ("int64", "std_msgs/msg/UInt16"),
        ("double", "std_msgs/msg/Float32"),
    ]


def test_check_on_fret_liquid_mixer(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli_main(["check", str(DATA / "fret" / "liquid_mixer.yaml")]) == 0
    out = capsys.readouterr().out
    assert "12 requirements ok, monitor compiled" in out
    assert "differs from FRET" not in out


def test_check_on_ogma_examples_notes_unused_variables(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli_main(["check", str(DATA / "ogma" / "test_component.yaml")]) == 0
    out = capsys.readouterr().out + capsys.readouterr().err
    assert "1 requirements ok, monitor compiled" in out
    for name in ("input_signal_float", "input_signal_double"):
        assert f"note: variable '{name}' from vars-db.json is not used" in out
    cfg = project_for(DATA / "ogma" / "test_component.yaml").config
    assert list(cfg.variables) == ["input_signal"]
    assert cfg.variables["input_signal"].type == "int64"  # OGMA's type refines FRET's Double


def test_fret_formulas_agree_with_ours_and_defines_come_from_fret(tmp_path):
    # check cross-checks each requirement with FRET's exported ptExpanded on random
    # traces, the imported Internal variables expanded: a difference is a warning.
    cfg = write(
        tmp_path,
        f"component: vehicle\nstep: {{policy: periodic, period_ms: 100}}\n"
        f"requirements_from: {LPC}\n{LPC_TOPICS}",
    )
    project = project_for(cfg)
    assert {v.name: v.define_text for v in project.config.defines} == {
        "semi_thrust_borne": "1",
        "semi_wing_borne": "2",
        "thrust_borne": "0",
        "wing_borne": "3",
    }
    assert project.config.variables["lift_mode"].role == "output"  # FRET's Output
    # every one, LPC_KIAS_DERIVATIVE's preReal included, and each agrees with FRET
    assert [str(r.error) for r in project.requirements if not r.ok] == []
    assert len(project.requirements) == 19
    warnings = [w for r in project.requirements for w in r.warnings]
    assert not [w for w in warnings if "FRET" in w], warnings


def test_used_fret_variable_without_topic_is_an_error(tmp_path):
    cfg = write(
        tmp_path,
        f"component: vehicle\nstep: {{policy: periodic, period_ms: 100}}\n"
        f"requirements_from: {LPC}\n"
        "variables:\n  hover_control_mode: {topic: /h, msg: std_msgs/msg/Bool}\n",
    )
    project = project_for(cfg)
    messages = [str(e) for e in project.errors]
    assert any(f"variable 'kias' from {LPC} has no topic" in m for m in messages), messages


def test_config_variables_override_fret(tmp_path):
    cfg = load_config(
        write(
            tmp_path,
            f"""\
            component: vehicle
            step: {{policy: periodic, period_ms: 100}}
            requirements_from: {LPC}
            variables:
              kias: {{type: int64, topic: /kias, msg: std_msgs/msg/Int64}}
              thrust_borne: {{type: int64, define: "5"}}
            """,
        )
    )
    assert cfg.variables["kias"].type == "int64"
    assert cfg.variables["kias"].imported_from is None  # declared: unused is an error
    assert cfg.variables["thrust_borne"].define_text == "5"
    assert cfg.variables["wing_borne"].define_text == "3"


def test_only_the_components_variables_are_imported(tmp_path):
    # A project's export holds every component's variables; another component's
    # 'kias' (here an Internal with a Lustre assignment) is not this one's.
    data = json.loads(LPC.read_text())
    other = dict(data["variables"][2], component_name="autopilot", idType="Internal")
    data["variables"].append({**other, "assignment": "x -> pre kias", "dataType": "integer"})
    p = tmp_path / "project.json"
    p.write_text(json.dumps(data))
    _reqs, internal, others = load_fret_export(p, "vehicle")
    assert "kias" not in {v["name"] for v in internal}
    assert ("kias", "double") in {(v["name"], v["type"]) for v in others}
    _reqs, internal, _others = load_fret_export(p)
    assert "kias" in {v["name"] for v in internal}
    cfg = load_config(
        write(
            tmp_path,
            f"component: vehicle\nstep: {{policy: periodic, period_ms: 100}}\n"
            f"requirements_from: {p}\n{LPC_TOPICS}",
        )
    )
    assert cfg.variables["kias"].type == "double" and cfg.variables["kias"].define is None


def test_modes_become_defines_and_functions_nothing(tmp_path):
    data = json.loads(LPC.read_text())
    base = {"project": "LPC_mini", "component_name": "vehicle", "assignment": ""}
    data["variables"] += [
        {
            **base,
            "variable_name": "hovering",
            "idType": "Mode",
            "dataType": "boolean",
            "modeRequirement": "lift_mode = thrust_borne & kgs <= 20.0",
        },
        {**base, "variable_name": "absReal", "idType": "Function", "dataType": ""},
    ]
    p = tmp_path / "modes.json"
    p.write_text(json.dumps(data))
    _reqs, internal, others = load_fret_export(p, "vehicle")
    assert {
        "name": "hovering",
        "type": "bool",
        "define": "lift_mode = thrust_borne & kgs <= 20.0",
    } in internal
    assert "absReal" not in {v["name"] for v in internal + others}


def project_export(tmp_path: Path, parent: bool = False) -> Path:
    """A FRET project's export holding two components' requirements and variables:
    FRET's Liquid Mixer (liquid_mixer) and Lift+Cruise (vehicle) files combined
    (tests/data/fret/README.md).  With ``parent``, a parent requirement (no text)
    of the liquid mixer's, as FRET writes one that groups others."""
    lm, lpc = json.loads(LM.read_text()), json.loads(LPC.read_text())
    requirements = lm["requirements"] + lpc["requirements"]
    if parent:
        requirements.insert(0, {**lm["requirements"][0], "reqid": "LM-000", "fulltext": ""})
    p = tmp_path / "project_reqts_and_vars.json"
    p.write_text(
        json.dumps({"requirements": requirements, "variables": lm["variables"] + lpc["variables"]})
    )
    return p


def mixer_config(tmp_path: Path, export: Path) -> Path:
    text = (DATA / "fret" / "liquid_mixer.yaml").read_text()
    return write(tmp_path, text.replace("LM_reqts_and_vars.json", str(export)))


def test_a_project_export_keeps_the_components_requirements(tmp_path):
    p = project_export(tmp_path)
    notes: list[str] = []
    reqs, _internal, other = load_fret_export(p, "liquid_mixer", notes)
    assert {r.id for r in reqs} == {f"LM_{i:03}" for i in range(1, 13)}
    assert notes[0] == (
        "19 requirements of other components left out: 'vehicle' (19); "
        "this config is for 'liquid_mixer'"
    )
    assert notes[1].startswith(
        "12 requirement names are not C identifiers, so the ids are: 'LM-012' -> 'LM_012', "
    ) and notes[1].endswith(" and 2 more (other characters as '_'); refine them by these ids")
    assert len(notes) == 2
    assert "kias" not in {v["name"] for v in other}
    notes = []
    reqs, _internal, _other = load_fret_export(p, "vehicle", notes)
    assert len(reqs) == 19 and notes[0].startswith("12 requirements of other components")
    reqs, _internal, _other = load_fret_export(p)  # no component: everything
    assert len(reqs) == 31


def test_check_on_a_project_export_notes_the_other_components(tmp_path, monkeypatch, capsys):
    cfg = mixer_config(tmp_path, project_export(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert cli_main(["check", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "12 requirements ok, monitor compiled" in out
    assert (
        f"{cfg}:6: note: {tmp_path / 'project_reqts_and_vars.json'}: 19 requirements of "
        "other components left out: 'vehicle' (19)"
    ) in out
    assert "error" not in out and "LPC_" not in out
    spec = project_for(cfg).spec()
    assert {r.id for r in spec.requirements} == {f"LM_{i:03}" for i in range(1, 13)}
    assert not {"kias", "lift_mode"} & {v.name for v in spec.inputs}


def test_a_requirement_without_text_is_a_note(tmp_path, monkeypatch, capsys):
    # FRET's parent requirements group others and have no text of their own.
    export = project_export(tmp_path, parent=True)
    notes: list[str] = []
    reqs, _internal, _other = load_fret_export(export, "liquid_mixer", notes)
    assert "LM_000" not in {r.id for r in reqs}
    assert "requirement 'LM-000' has no text (a parent requirement in FRET); left out" in notes
    monkeypatch.chdir(tmp_path)
    assert cli_main(["check", str(mixer_config(tmp_path, export))]) == 0
    out = capsys.readouterr().out
    assert "note: " in out and "requirement 'LM-000' has no text" in out
    assert "12 requirements ok, monitor compiled" in out


def test_an_import_for_another_component_says_which_it_holds(tmp_path):
    cfg = write(
        tmp_path,
        f"component: rover\nstep: {{policy: periodic, period_ms: 100}}\nrequirements_from: {LM}\n",
    )
    with pytest.raises(UserError) as e:
        load_config(cfg)
    assert "no requirements" in str(e.value)
    assert "12 requirements of other components left out: 'liquid_mixer' (12)" in str(e.value)


# Rows of tests/data/fret/forms.jsonl, one per form real projects write: FRET's
# formula (for the sentence, or for the one FRET was given) is the export's
# ptExpanded, which check cross-checks against ours on random traces.
FORM_ROWS = (
    "persisted3_in_resp",
    "occurred3_after_whenever",
    "persisted3_onlyBefore_upon",
    "persisted3_edge_2_2_null",
    "abs_roll_hold_AP-003B",
    "abs_eb",
    "min_max_cond",
    "trailing_comma_dot",
)
FORM_TYPES = {"Bool": "bool", "Float64": "double"}
FORM_VARIABLES = {
    **dict.fromkeys("hot x fan cruise takeoff landing p q r roll_hold ridge_on".split(), "Bool"),
    **dict.fromkeys(
        "roll_angle roll_hold_reference det_B_BT eps12 eps6 check_1_1 a b c".split(), "Float64"
    ),
}


def test_check_takes_the_fret_forms_real_projects_write(tmp_path, monkeypatch, capsys):
    rows = {
        d["id"]: d
        for d in map(json.loads, (DATA / "fret" / "forms.jsonl").read_text().splitlines())
    }
    export = [
        {
            "reqid": rid,
            # one component, as a config monitors one
            "fulltext": rows[rid]["fretish"].replace("RollAutopilot", "sw").replace("EB ", "sw "),
            "semantics": {"ptExpanded": rows[rid]["pt"]},
        }
        for rid in FORM_ROWS
    ]
    (tmp_path / "forms.json").write_text(json.dumps(export))
    variables = "".join(
        f"  {n}: {{topic: /forms/{n}, msg: std_msgs/msg/{t}, type: {FORM_TYPES[t]}}}\n"
        for n, t in FORM_VARIABLES.items()
    )
    cfg = write(
        tmp_path,
        "component: sw\nstep: {policy: periodic, period_ms: 100}\n"
        # the analyses of these forms: tests/monitors/frontend/test_fret_forms.py
        "analysis: {enabled: false}\n"
        "requirements_from: forms.json\n"
        f"variables:\n{variables}",
    )
    monkeypatch.chdir(tmp_path)
    code = cli_main(["check", str(cfg)])
    out = capsys.readouterr()
    assert code == 0, out
    assert f"{len(FORM_ROWS)} requirements ok, monitor compiled" in out.out
    assert "differs from FRET" not in out.out + out.err and "not cross-checked" not in out.out
