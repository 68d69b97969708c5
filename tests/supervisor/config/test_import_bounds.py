"""What a FRET export, an OGMA database or a config can carry, and how far it gets.

Each file is read within bounds (size, UTF-8, JSON nesting, requirement text length)
and checked field by field where it enters; anything else is one located line and
exit 1 (docs/reference/config.md, "Limits"; docs/reference/faults.md, "Trust").
Requirement ids are C identifiers: FRET's names are mapped to one, the original kept
for display.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from monitors.errors import UserError
from supervisor.cli import main as cli_main
from supervisor.config import load_config, load_fret_export, load_ogma_variables
from supervisor.config.limits import MAX_CONFIG_BYTES, MAX_TEXT_CHARS

DATA = Path(__file__).resolve().parents[2] / "data"
LM = DATA / "fret" / "LM_reqts_and_vars.json"
LOCATED = re.compile(r"^\S+?(:\d+(:\d+)?)?: \S")

CONFIG = """\
component: test_component
step: {policy: periodic, period_ms: 100}
requirements_from: f.json
variables:
  input_signal: {type: double, topic: /x, msg: std_msgs/msg/Float64}
"""
OGMA_CONFIG = """\
component: test_component
step: {policy: periodic, period_ms: 100}
variables_from: db.json
requirements:
  - {id: r1, text: test_component shall always satisfy input_signal > 1}
"""


def copilot_export(*reqs: dict[str, Any]) -> dict[str, Any]:
    return {
        "test_componentSpec": {
            "Requirements": list(reqs),
            "Other_variables": [{"name": "input_signal", "type": "real"}],
        }
    }


def req(name: Any = "r1", fretish: Any = None) -> dict[str, Any]:
    if fretish is None:
        fretish = "test_component shall always satisfy input_signal > 1"
    return {"name": name, "fretish": fretish}


def check_in_process(
    tmp_path: Path, export: bytes | str | Any, capsys: pytest.CaptureFixture[str]
) -> tuple[int, str, str]:
    """``check`` through the real CLI on a config importing ``export``."""
    (tmp_path / "c.yaml").write_text(CONFIG)
    raw = export if isinstance(export, bytes | str) else json.dumps(export)
    (tmp_path / "f.json").write_bytes(raw.encode() if isinstance(raw, str) else raw)
    capsys.readouterr()
    code = cli_main(["check", str(tmp_path / "c.yaml")])
    out, err = capsys.readouterr()
    return code, out, err


def one_located_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and LOCATED.match(lines[0]), err[-2000:]
    assert "Traceback" not in err and "internal error" not in err
    return lines[0]


# ---------------------------------------------------------------- FRET's files


def test_fret_json_nested_200k_deep_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _out, err = check_in_process(tmp_path, "[" * 200_000 + "]" * 200_000, capsys)
    line = one_located_line(err)
    assert code == 1 and line == f"{tmp_path / 'f.json'}: nested more than 64 levels", line


def test_fret_invalid_utf8_names_the_byte(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _out, err = check_in_process(tmp_path, b'{\n"a": "\xff"}', capsys)
    line = one_located_line(err)
    assert code == 1 and line == f"{tmp_path / 'f.json'}:2: not UTF-8 (byte 8)", line


def test_fret_syntax_error_has_line_and_column(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _out, err = check_in_process(tmp_path, '{\n  "a": ,\n}', capsys)
    line = one_located_line(err)
    assert code == 1 and line.startswith(f"{tmp_path / 'f.json'}:2:8: invalid JSON: "), line


@pytest.mark.parametrize(
    ("export", "message"),
    [
        (copilot_export(req(fretish=5)), "requirement 'r1': 'fretish' must be text, not a number"),
        (copilot_export(req(name=["x"])), "requirement 1: 'name' must be text, not a list"),
        (copilot_export(req(), "x"), "requirement 2: must be an object, not text"),
        (
            copilot_export({**req(), "ptLTL": {"a": 1}}),
            "requirement 'r1': 'ptLTL' must be text, not an object",
        ),
        (
            {"test_componentSpec": {"Requirements": [req()], "Other_variables": {"a": 1}}},
            "'test_componentSpec': 'Other_variables' must be a list, not an object",
        ),
        (
            {"test_componentSpec": {"Requirements": [req()], "Other_variables": [{"name": 3}]}},
            "variable 1: 'name' must be text, not a number",
        ),
        (
            [{"reqid": "a", "fulltext": "x shall satisfy y", "semantics": []}],
            "requirement 'a': 'semantics' must be an object, not a list",
        ),
        (
            [{"reqid": "a", "fulltext": True}],
            "requirement 'a': 'fulltext' must be text, not true",
        ),
        (
            {"requirements": [], "variables": [{"variable_name": "v", "idType": 7}]},
            "variable 'v': 'idType' must be text, not a number",
        ),
    ],
)
def test_fret_wrong_types_name_the_field_and_requirement(
    tmp_path, capsys, monkeypatch, export, message
):
    monkeypatch.chdir(tmp_path)
    code, _out, err = check_in_process(tmp_path, export, capsys)
    line = one_located_line(err)
    assert code == 1 and line == f"{tmp_path / 'f.json'}: {message}", line


def test_fret_file_over_the_cap_is_refused_before_reading(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    big = tmp_path / "f.json"
    (tmp_path / "c.yaml").write_text(CONFIG)
    with big.open("wb") as f:  # sparse: the size alone must refuse it
        f.truncate(200 << 20)
    assert cli_main(["check", str(tmp_path / "c.yaml")]) == 1
    line = one_located_line(capsys.readouterr().err)
    # at the config's line that names the file, with the name as written there
    where = re.escape(f"{tmp_path / 'c.yaml'}:")
    assert re.match(
        rf"{where}\d+: requirements_from 'f.json': cannot read FRET file: larger than ", line
    ), line


def test_fret_file_that_is_not_a_regular_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    os.mkfifo(tmp_path / "f.json")  # a FIFO nobody writes: must not hang
    assert cli_main(["check", str(tmp_path / "c.yaml")]) == 1
    line = one_located_line(capsys.readouterr().err)
    where = re.escape(f"{tmp_path / 'c.yaml'}:")
    assert re.fullmatch(
        rf"{where}\d+: requirements_from 'f.json': cannot read FRET file: not a regular file", line
    ), line


def test_fret_text_over_the_cap_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = "test_component shall always satisfy " + " & ".join(["input_signal > 1"] * 2000)
    code, _out, err = check_in_process(tmp_path, copilot_export(req(fretish=text)), capsys)
    line = one_located_line(err)
    assert code == 1
    assert line == (
        f"{tmp_path / 'f.json'}: requirement 'r1': 'fretish' is longer than "
        f"{MAX_TEXT_CHARS} characters"
    ), line


# ------------------------------------------------------------------- the ids


def test_fret_names_become_c_identifiers_without_collisions(tmp_path):
    names = ["a-b", "a_b", "a b", "a-b", "9lives", "r\x1b[31m1\n*/", "", "ünï"]
    p = tmp_path / "f.json"
    p.write_text(json.dumps(copilot_export(*(req(n) for n in names if n))))
    with pytest.raises(UserError, match="duplicate requirement 'a-b'"):
        load_fret_export(p)
    names = [n for i, n in enumerate(names) if n and i != 3]
    p.write_text(json.dumps(copilot_export(*(req(n) for n in names))))
    notes: list[str] = []
    reqs, _i, _o = load_fret_export(p, notes=notes)
    ids = [r.id for r in reqs]
    # a name that is one already keeps it; the others are mapped in file order
    assert ids == ["a_b_2", "a_b", "a_b_3", "r_9lives", "r__31m1___", "_n_"], ids
    assert [r.display for r in reqs] == names
    assert all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", i) for i in ids)
    [note] = notes
    assert (
        "\x1b" not in note and "\n" not in note and "'r\\x1b[31m1\\x0a*/' -> 'r__31m1___'" in note
    )
    # the same file maps the same way, whatever else the config holds
    assert [r.id for r in load_fret_export(p)[0]] == ids


def test_fret_ids_of_real_exports_are_mapped(tmp_path, capsys, monkeypatch):
    reqs, _i, _o = load_fret_export(LM)
    assert reqs[0].id == "LM_012" and reqs[0].display == "LM-012"


def test_control_characters_in_a_fret_name_reach_no_output(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    evil = "r\x1b[31m1\n*/ int pwned; /*\u202e"
    (tmp_path / "c.yaml").write_text(CONFIG)
    (tmp_path / "f.json").write_text(json.dumps(copilot_export(req(evil))))
    assert cli_main(["check", str(tmp_path / "c.yaml")]) == 0
    out, err = capsys.readouterr()
    assert "\x1b" not in out + err and "\u202e" not in out + err
    # the name is shown escaped, as FRET wrote it, beside its id
    assert "'r\\x1b[31m1\\x0a*/ int pwned; /*\\u202e' -> 'r__31m1____int_pwned_____'" in out
    assert cli_main(["compile", str(tmp_path / "c.yaml"), "-o", str(tmp_path / "build")]) == 0
    c = (tmp_path / "build" / "monitor.c").read_text()
    assert "pwned;" not in c and "\x1b" not in c
    manifest = json.loads((tmp_path / "build" / "manifest.json").read_text())
    assert "r__31m1____int_pwned_____" in json.dumps(manifest)


@pytest.mark.parametrize(
    ("rid", "shown"),
    [('"a\\n"', "a\\x0a"), ('"a\\e[2J"', "a\\x1b[2J"), ("a-b", "a-b"), ("x" * 300, "x" * 300)],
)
def test_config_id_that_is_not_a_c_identifier_is_located(tmp_path, rid, shown):
    p = tmp_path / "c.yaml"
    p.write_text(
        "component: c\nstep: {policy: periodic, period_ms: 1}\nrequirements:\n"
        f"  - {{id: {rid}, text: c shall always satisfy x}}\n"
    )
    with pytest.raises(UserError) as e:
        load_config(p)
    assert e.value.line == 4 and str(e.value).startswith(
        f"{p}:4: requirement id '{shown}' must be a C identifier"
    ), str(e.value)
    assert "\n" not in str(e.value) and "\x1b" not in str(e.value)


# ------------------------------------------------------------ OGMA's databases


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (b'{"a":' + b"[" * 100_000, "nested more than 64 levels"),
        (b'{"inputs": [{"name": "x\xc3"}]}', ":1: not UTF-8 (byte 23)"),
        (b'{"inputs": 3}', ": 'inputs' must be a list, not a number"),
        (b'{"inputs": [{"name": 3}]}', ": variable 1: 'name' must be text, not a number"),
        (
            b'{"inputs": [{"name": "x", "type": "int", "connections": {"a": 1}}]}',
            ": variable 'x': 'connections' must be a list, not an object",
        ),
        (
            b'{"inputs": [{"name": "x", "type": "int", "connections": [{"scope": "ros", "topic": 1}]}]}',
            ": variable 'x': connection 1: 'topic' must be text, not a number",
        ),
        (b'{"inputs": [], "topics": [{"topic": "/x", "type": null}]}', None),
        (b'("a","bool","/a","bool")\n\xff\n', ":2: not UTF-8 (byte 25)"),
    ],
)
def test_ogma_database_bad_input_is_one_line(tmp_path, capsys, monkeypatch, raw, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(OGMA_CONFIG)
    (tmp_path / "db.json").write_bytes(raw)
    code = cli_main(["check", str(tmp_path / "c.yaml")])
    _out, err = capsys.readouterr()
    if message is None:  # accepted: the database declares nothing
        assert load_ogma_variables(tmp_path / "db.json") == []
        return
    line = one_located_line(err)
    expected = f"{tmp_path / 'db.json'}" + (message if message[0] == ":" else ": " + message)
    assert code == 1 and line == expected, line


# ------------------------------------------------------------- the YAML config


def test_config_over_the_size_cap_is_refused_before_parsing(tmp_path, capsys):
    p = tmp_path / "c.yaml"
    with p.open("wb") as f:
        f.truncate(MAX_CONFIG_BYTES + 1)
    assert cli_main(["check", str(p)]) == 1
    line = one_located_line(capsys.readouterr().err)
    assert line.startswith(f"{p}: cannot read config: larger than {MAX_CONFIG_BYTES} bytes"), line


def test_config_invalid_utf8_is_located_not_replaced(tmp_path, capsys):
    p = tmp_path / "c.yaml"
    p.write_bytes(b"component: a\nstep: {policy: periodic, period_ms: 1}\n# caf\xe9\n")
    assert cli_main(["check", str(p)]) == 1
    line = one_located_line(capsys.readouterr().err)
    assert line == f"{p}:3: not UTF-8 (byte 57)", line


def test_requirement_text_over_the_cap_is_located_at_its_line(tmp_path):
    p = tmp_path / "c.yaml"
    text = "test_component shall always satisfy " + "x" * MAX_TEXT_CHARS
    p.write_text(
        OGMA_CONFIG.replace("variables_from: db.json\n", "").replace(
            "{id: r1, text: test_component shall always satisfy input_signal > 1}",
            f"{{id: r1, text: {text}}}",
        )
    )
    with pytest.raises(UserError) as e:
        load_config(p)
    assert str(e.value).startswith(
        f"{p}:4:20: requirement 'r1': its text is longer than {MAX_TEXT_CHARS} characters"
    ), str(e.value)


@pytest.mark.parametrize("value", ["5", "[a, b]", "{a: 1}"])
def test_requirement_text_must_be_text(tmp_path, value):
    p = tmp_path / "c.yaml"
    p.write_text(
        "component: c\nstep: {policy: periodic, period_ms: 1}\n"
        f"requirements:\n  - id: r1\n    text: {value}\n"
    )
    with pytest.raises(UserError) as e:
        load_config(p)
    assert str(e.value).startswith(f"{p}:5: requirement 'r1': text must be a FRETISH sentence")


def test_sixty_megabyte_requirement_text_is_refused_fast(tmp_path):
    """The attack's 60 MB text: refused from the file's size, with no YAML parsed
    (before: past 120 s and 1.6 GB).  Run as the real CLI; time and peak memory are
    printed for docs/BENCHMARKS.md, the memory bounded here."""
    p = tmp_path / "c.yaml"
    with p.open("w") as f:
        f.write("component: c\nstep: {policy: periodic, period_ms: 1}\nrequirements:\n")
        f.write("  - id: r1\n    text: c shall always satisfy " + "x" * (60 << 20) + "\n")
    limit = 1 << 30  # a child over this is killed: a bound on what the refusal costs
    # A child's ru_maxrss starts at the size of the process it was forked from (the
    # kernel keeps the old image's high-water mark at exec), so a small wrapper runs
    # the command and writes the peak of its own child.
    code = (
        "import resource, subprocess, sys;"
        "resource.setrlimit(resource.RLIMIT_CPU, (60, 60));"
        f"resource.setrlimit(resource.RLIMIT_DATA, ({limit}, {limit}));"
        "rc = subprocess.call([sys.executable, '-m', 'supervisor', *sys.argv[2:]]);"
        "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss));"
        "sys.exit(rc)"
    )
    start = time.monotonic()
    child = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "peak"), "check", str(p)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    elapsed = time.monotonic() - start
    stderr = child.stderr
    peak = int((tmp_path / "peak").read_text()) * 1024
    print(f"60 MB text: exit {child.returncode} in {elapsed:.2f} s, peak RSS {peak / 2**20:.0f} MB")
    assert child.returncode == 1, stderr[-2000:]
    line = one_located_line(stderr)
    assert line.startswith(f"{p}: cannot read config: larger than"), line
    assert peak < limit, peak


# ------------------------------------------------- the generated code's comments

EVIL_ID = "x*\\\n/ int pwned; /*\x1b"  # a spliced '*/', then code


def evil_spec() -> Any:
    from monitors.ir.formula import parse_formula
    from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl

    return MonitorSpec(
        "c\n-- pwned",
        (VarDecl("a", "bool"),),
        (RequirementSpec(EVIL_ID, parse_formula("H a")),),
    )


def test_no_text_ends_a_c_comment(tmp_path):
    """The monitors package is a compiler of its own: whatever a requirement id
    holds stays inside its comment (gcc's preprocessor drops comments)."""
    from monitors.backends.c99 import write_c

    c_file, _h = write_c(evil_spec(), tmp_path)
    pre = subprocess.run(
        ["gcc", "-std=c99", "-E", "-I", str(tmp_path), str(c_file)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "int pwned;" not in pre and "\x1b" not in c_file.read_text()


def test_no_text_ends_a_haskell_comment():
    from monitors.backends.copilot import generate_haskell

    hs = generate_haskell(evil_spec())
    assert "\x1b" not in hs
    for line in hs.splitlines():
        if " pwned" in line:  # not in a name: C names are mangled
            assert line.lstrip().startswith("--"), line


def test_yaml_aliases_that_expand_past_the_cap_are_located(tmp_path, capsys):
    """A "billion laughs": nine lines whose id, printed in its error, fills memory."""
    lines = ["  a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"  a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    p = tmp_path / "c.yaml"
    p.write_text(
        "analysis:\n" + "\n".join(lines) + "\ncomponent: c\nstep: {policy: periodic, "
        "period_ms: 1}\nrequirements: [{id: *a8, text: c shall always satisfy x}]\n"
    )
    assert cli_main(["check", str(p)]) == 1
    line = one_located_line(capsys.readouterr().err)
    assert line == f"{p}:7:57: expands to more than 1000000 values (YAML aliases)", line


def test_control_characters_in_a_fret_text_are_refused_where_they_enter(
    tmp_path, capsys, monkeypatch
):
    """The parser would quote them back to the terminal."""
    monkeypatch.chdir(tmp_path)
    text = "test_component shall always satisfy input_signal > 1 \x1b[31m"
    code, out, err = check_in_process(tmp_path, copilot_export(req(fretish=text)), capsys)
    assert "\x1b" not in out + err
    line = one_located_line(err)
    assert code == 1 and line == (
        f"{tmp_path / 'f.json'}: requirement 'r1': 'fretish' holds a control character "
        "(\\x1b) at character 54"
    ), line


@pytest.mark.parametrize(
    "key,what", [("requirements_from", "FRET file"), ("variables_from", "OGMA variable database")]
)
def test_a_missing_imported_file_is_an_error_at_the_line_naming_it(
    tmp_path, capsys, monkeypatch, key, what
):
    # found by test_fuzz_config: a cut line left `variables_from: s`, and the error
    # named the missing file without any line of the config
    monkeypatch.chdir(tmp_path)
    text = "component: c\nstep: {policy: periodic, period_ms: 100}\n"
    text += f"{key}: nothere.json\n"
    text += "requirements:\n  - {id: r1, text: c shall always satisfy p}\n"
    text += "variables:\n  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}\n"
    (tmp_path / "c.yaml").write_text(text)
    assert cli_main(["check", str(tmp_path / "c.yaml")]) == 1
    line = one_located_line(capsys.readouterr().err)
    expected = f"{tmp_path / 'c.yaml'}:3: {key} 'nothere.json': cannot read {what}: "
    assert line == expected + "No such file or directory", line
