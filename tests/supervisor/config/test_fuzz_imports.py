"""The adversary of the FRET and OGMA importers, kept: random files where they enter.

Random JSON (deep, wrong types, huge or control-character strings, random names),
shaped like FRET's three exports and OGMA's database or not, and random bytes
(invalid UTF-8, cut short), written to files and loaded through the real config
loader.  Every outcome is a loaded config or one ``UserError`` line with no control
characters; never another exception, never exit 3 (docs/reference/faults.md, "Trust").
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.errors import UserError
from supervisor.cli import main as cli_main
from supervisor.config import load_config

LOCATED = re.compile(r"^\S+?(:\d+(:\d+)?)?: \S")
CONFIG = """\
component: c
step: {policy: periodic, period_ms: 100}
requirements_from: f.json
variables_from: db.json
requirements:
  - {id: mine, text: c shall always satisfy TRUE}
"""
FRET_KEYS = ["reqid", "fulltext", "rationale", "semantics", "component_name", "ptExpanded",
             "variable_name", "idType", "dataType", "copilotAssignment", "assignment",
             "modeRequirement", "name", "fretish", "ptLTL", "type", "assignmentCopilot",
             "assignmentLustre", "Requirements", "Internal_variables", "Other_variables",
             "requirements", "variables"]  # fmt: skip
OGMA_KEYS = ["inputs", "topics", "types", "name", "type", "connections", "scope", "topic",
             "field"]  # fmt: skip
ID_TYPES = ["Input", "Output", "Internal", "Mode", "Function", ""]
TYPES = ["boolean", "integer", "double", "bool", "real", "int64_t", "float", "string"]

names = st.one_of(
    st.sampled_from(["c", "r1", "x", "a-b", "a_b", "9", "assumption-1", "mine", "int", "true"]),
    st.text(min_size=0, max_size=12),
    st.text(st.characters(codec="ascii"), max_size=6),
)
strings = st.one_of(
    names,
    st.sampled_from(TYPES + ID_TYPES + ["ros/message", "/t", "c shall always satisfy x"]),
    st.text(st.characters(max_codepoint=0x9F), max_size=40),  # control characters
    st.builds(lambda n: "x" * n, st.sampled_from([10_001, 300_000])),
    st.builds(lambda w: f"c shall always satisfy {w}", names),
)
scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), strings)


def values(keys: list[str]) -> st.SearchStrategy[Any]:
    return st.recursive(
        scalars,
        lambda inner: st.one_of(
            st.lists(inner, max_size=4),
            st.dictionaries(st.one_of(st.sampled_from(keys), names), inner, max_size=5),
        ),
        max_leaves=20,
    )


def fret_shaped() -> st.SearchStrategy[Any]:
    """FRET's three shapes, each field random: reaches every field's check."""
    v = values(FRET_KEYS)
    req = st.fixed_dictionaries(
        {"reqid": st.one_of(names, v), "fulltext": st.one_of(strings, v)},
        optional={"rationale": v, "semantics": st.one_of(v, st.fixed_dictionaries(
            {}, optional={"component_name": st.one_of(names, v), "ptExpanded": v}))},
    )  # fmt: skip
    var = st.fixed_dictionaries(
        {"variable_name": st.one_of(names, v), "idType": st.one_of(st.sampled_from(ID_TYPES), v)},
        optional={k: st.one_of(strings, v) for k in
                  ("dataType", "component_name", "copilotAssignment", "modeRequirement")},
    )  # fmt: skip
    copilot_req = st.fixed_dictionaries(
        {"name": st.one_of(names, v), "fretish": st.one_of(strings, v)}, optional={"ptLTL": v}
    )
    copilot_var = st.fixed_dictionaries(
        {"name": st.one_of(names, v)},
        optional={"type": st.one_of(st.sampled_from(TYPES), v), "assignmentCopilot": v},
    )
    return st.one_of(
        st.lists(req, max_size=4),
        st.fixed_dictionaries(
            {"requirements": st.lists(req, max_size=4), "variables": st.lists(var, max_size=4)}
        ),
        st.fixed_dictionaries(
            {
                "cSpec": st.fixed_dictionaries(
                    {},
                    optional={
                        "Requirements": st.lists(copilot_req, max_size=4),
                        "Internal_variables": st.lists(copilot_var, max_size=3),
                        "Other_variables": st.one_of(st.lists(copilot_var, max_size=3), v),
                    },
                )
            }
        ),
        values(FRET_KEYS),
    )


def ogma_shaped() -> st.SearchStrategy[Any]:
    v = values(OGMA_KEYS)
    conn = st.fixed_dictionaries(
        {}, optional={"scope": st.one_of(st.just("ros/message"), v), "topic": v, "field": v}
    )
    item = st.fixed_dictionaries(
        {"name": st.one_of(names, v), "type": st.one_of(st.sampled_from(TYPES), v)},
        optional={"connections": st.one_of(st.lists(conn, max_size=2), v)},
    )
    topic = st.fixed_dictionaries({}, optional={"topic": v, "type": v})
    return st.one_of(
        st.fixed_dictionaries(
            {"inputs": st.one_of(st.lists(item, max_size=3), v)},
            optional={"topics": st.one_of(st.lists(topic, max_size=3), v)},
        ),
        values(OGMA_KEYS).map(lambda x: {"inputs": x}),
    )


def as_bytes(doc: Any, damage: st.DataObject) -> bytes:
    """The document's JSON, sometimes damaged: invalid UTF-8, deep nesting, cut short."""
    raw = json.dumps(doc, ensure_ascii=damage.draw(st.booleans())).encode()
    how = damage.draw(st.sampled_from(["none", "none", "utf8", "deep", "cut"]))
    if how == "utf8":
        at = damage.draw(st.integers(0, len(raw)))
        return (
            raw[:at] + damage.draw(st.sampled_from([b"\xff", b"\xc3", b"\xed\xa0\x80"])) + raw[at:]
        )
    if how == "deep":
        n = damage.draw(st.sampled_from([65, 5000, 200_000]))
        return b'{"inputs": ' + b"[" * n + b"]" * n + b', "requirements": []}'
    if how == "cut":
        return raw[: damage.draw(st.integers(0, len(raw)))]
    return raw


def assert_one_clean_line(message: str) -> None:
    assert "\n" not in message and LOCATED.match(message), message
    # every imported string reaches the terminal escaped (monitors.untrusted.printable)
    assert message.isprintable(), message


def load_once(tmp: Path, fret: bytes, ogma: bytes) -> None:
    (tmp / "c.yaml").write_text(CONFIG)
    (tmp / "f.json").write_bytes(fret)
    (tmp / "db.json").write_bytes(ogma)
    try:
        cfg = load_config(tmp / "c.yaml")
    except UserError as e:
        assert_one_clean_line(str(e))
        return
    for r in cfg.requirements:  # accepted: every id is a C identifier
        assert re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", r.id), r
    for note in cfg.notes:
        assert note.isprintable(), note


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(fret=fret_shaped(), ogma=ogma_shaped(), data=st.data())
def test_random_fret_and_ogma_files_load_cleanly(tmp_path_factory, fret, ogma, data) -> None:
    tmp = tmp_path_factory.mktemp("imp")
    load_once(tmp, as_bytes(fret, data), as_bytes(ogma, data))


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(fret=fret_shaped(), data=st.data())
def test_random_fret_files_through_check(tmp_path_factory, fret, data) -> None:
    """The whole of ``check`` in-process (the CLI's exit codes): 0 or 1, never 3."""
    tmp = tmp_path_factory.mktemp("chk")
    (tmp / "c.yaml").write_text(CONFIG.replace("variables_from: db.json\n", ""))
    (tmp / "f.json").write_bytes(as_bytes(fret, data))
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = cli_main(["check", str(tmp / "c.yaml")])
    assert code in (0, 1), err.getvalue()[-2000:]
    if err.getvalue().strip():
        assert_one_clean_line(err.getvalue().strip())


def test_check_smoke_in_a_subprocess(tmp_path: Path) -> None:
    """The installed command on a FRET file of every kind of bad at once."""
    (tmp_path / "c.yaml").write_text(CONFIG.replace("variables_from: db.json\n", ""))
    for raw, said in [
        (b"[" * 200_000, "f.json: nested more than 64 levels"),
        (b'[{"reqid": "\xff"}]', "f.json:1: not UTF-8 (byte 12)"),
        (b'{"cSpec": {"Requirements": [{"name": "r", "fretish": 5}]}}',
         "f.json: requirement 'r': 'fretish' must be text, not a number"),
    ]:  # fmt: skip
        (tmp_path / "f.json").write_bytes(raw)
        out = subprocess.run(
            [sys.executable, "-m", "supervisor", "check", "c.yaml"],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            timeout=120,
        )
        assert out.returncode == 1 and out.stderr.strip() == said, out.stderr[-2000:]


@pytest.mark.slow
@settings(max_examples=1500, deadline=None, suppress_health_check=list(HealthCheck))
@given(fret=fret_shaped(), ogma=ogma_shaped(), data=st.data())
def test_many_random_fret_and_ogma_files_load_cleanly(tmp_path_factory, fret, ogma, data) -> None:
    tmp = tmp_path_factory.mktemp("imp")
    load_once(tmp, as_bytes(fret, data), as_bytes(ogma, data))
