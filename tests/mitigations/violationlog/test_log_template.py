"""A violation rendered from its requirement's template (ViolationLog.violation_template
and violation_from, the daemon's halt path: mitigations/violationlog/writer.py) is, byte
for byte and chained, the record ``violation`` writes from the same fields, whatever
the values: NaN, infinities, huge ints, strings with quotes and non-ASCII, extra fields
named like the header, ``recent`` rows with and without their pre-encoded JSON."""

from __future__ import annotations

import itertools
import json
import math
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mitigations.violationlog.writer as writer
from mitigations.violationlog.writer import Row, ViolationLog

CFG = "c0" * 32
PARAMETERS = {"requirement", "text", "formula", "tick", "inputs", "recent", "stale", "policy_state"}

scalars = st.one_of(
    st.booleans(),
    st.integers(),
    st.integers(min_value=-(10**40), max_value=10**40),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.none(),
)
names = st.one_of(
    st.sampled_from(["OpState", "halt", "tick", "seq", "ts", "event", "inputs", "recent"]),
    st.text(max_size=6),
)
rows = st.dictionaries(st.text(max_size=5), scalars, max_size=4).map(lambda d: {"tick": 1, **d})


@st.composite
def violations(draw: st.DrawFn) -> dict[str, Any]:
    recent = draw(st.lists(rows, max_size=12))
    as_rows = draw(st.booleans())  # the runtime's Rows, or plain dicts as replay keeps
    return {
        "tick": draw(st.one_of(st.integers(min_value=0), st.integers(), st.booleans())),
        "inputs": draw(st.dictionaries(names, scalars, max_size=8)),
        "recent": [Row.of(r) for r in recent] if as_rows else recent,
        "stale": draw(st.lists(st.text(max_size=6), max_size=3)),
        "policy_state": draw(
            st.one_of(st.none(), st.dictionaries(st.text(max_size=8), scalars, max_size=8))
        ),
    }


fixed = st.fixed_dictionaries(
    {
        "requirement": st.text(max_size=12),
        "text": st.text(max_size=40),
        "formula": st.text(max_size=40),
        # extra fields: any name but violation()'s own parameters (header names are
        # renamed, ``seq`` -> ``seq_``)
        "extra": st.dictionaries(
            st.one_of(
                st.sampled_from(["formula_inputs", "seq", "ts", "event", "line_sha256"]),
                st.text(max_size=6),
            ).filter(lambda k: k not in PARAMETERS),
            st.one_of(scalars, st.text()),
            max_size=3,
        ),
    }
)


@pytest.fixture
def restart_clock(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[], None]]:
    """Restarts the records' clock: both logs stamp the same times, so their files
    can be compared whole."""

    def restart() -> None:
        times = itertools.count()
        monkeypatch.setattr(writer, "_now", lambda: f"2026-11-27T23:00:00.{next(times):06d}Z")

    yield restart


def _write(path: Path, req: dict[str, Any], records: list[dict[str, Any]], templated: bool) -> bool:
    """The records, each followed by a mitigation record (the chain runs across);
    False when the template could not be made."""
    log = ViolationLog(path, "robot-1", CFG, echo=False)
    try:
        template = log.violation_template(
            req["requirement"], text=req["text"], formula=req["formula"], **req["extra"]
        )
        if templated and template is None:
            return False
        for i, r in enumerate(records):
            if i == 1:  # a reload: the records after it carry the new config's hash
                log.config_sha256 = "d1" * 32
            if templated:
                assert template is not None
                log.violation_from(template, **r)
            else:
                log.violation(
                    req["requirement"],
                    text=req["text"],
                    formula=req["formula"],
                    **r,
                    **req["extra"],
                )
            log.mitigation(
                req["requirement"], action="halt", kind="publish", ok=True, latency_ms=0.1
            )
    finally:
        log.close()
    return True


@settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(req=fixed, records=st.lists(violations(), min_size=1, max_size=3))
def test_templated_records_are_the_same_bytes(
    restart_clock: Callable[[], None], req: dict[str, Any], records: list[dict[str, Any]]
) -> None:
    with tempfile.TemporaryDirectory() as d:
        whole, templated = Path(d) / "whole.jsonl", Path(d) / "templated.jsonl"
        restart_clock()
        _write(whole, req, records, templated=False)
        restart_clock()
        if not _write(templated, req, records, templated=True):
            # only an extra field without a plain JSON form has no template
            with pytest.raises(ValueError):
                json.dumps(req["extra"], allow_nan=False)
            return
        want = whole.read_bytes()
        assert want.count(b"\n") == 2 * len(records)
        assert templated.read_bytes() == want


def test_a_template_is_made_once_per_requirement_and_the_slow_way_keeps_nan() -> None:
    """A record whose values have no plain JSON form (a NaN input) takes the whole
    rendering and keeps its NaN as "nan", as ``violation`` writes it."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "v.jsonl"
        log = ViolationLog(path, "robot-1", CFG, echo=False)
        try:
            template = log.violation_template("r1", text="t", formula="f", formula_inputs="x")
            assert template is not None
            assert log.violation_template("r1", text="t", formula="f", x=math.nan) is None
            log.violation_from(template, tick=3, inputs={"speed": math.nan}, recent=[])
            log.violation_from(
                template, tick=4, inputs={"speed": 1.5}, recent=[Row.of({"tick": 4})]
            )
        finally:
            log.close()
        first, second = (json.loads(x) for x in path.read_bytes().splitlines())
        assert first["inputs"] == {"speed": "nan"} and first["formula_inputs"] == "x"
        assert second["inputs"] == {"speed": 1.5} and second["recent"] == [{"tick": 4}]
        assert list(second)[:9] == [
            "ts",
            "event",
            "component",
            "config_sha256",
            "prev_sha256",
            "seq",
            "requirement",
            "text",
            "formula",
        ]


@settings(max_examples=300, deadline=None)
@given(
    before=st.binary(max_size=80),
    after=st.binary(max_size=3000),
    prev=st.text(alphabet="0123456789abcdef", min_size=64, max_size=64),
)
def test_a_line_is_sealed_as_seal_line_seals_it(before: bytes, after: bytes, prev: str) -> None:
    """The written line (its chain hash filled in, then sealed piece by piece) is
    seal_line's, byte for byte."""
    from mitigations.violationlog.format import ZERO_SHA256, seal_line
    from mitigations.violationlog.writer import _Entry

    body = b"{" + before + ZERO_SHA256.encode() + after + b"}"
    at = len(before) + 1
    entry = _Entry(1, "violation", "ts", body, at, True)
    assert entry.line(prev) == seal_line(body[:at] + prev.encode() + body[at + 64 :])


# The halt path's entry (violation_row): the step's own row gives the tick and the
# values, the policy state comes encoded.  Inputs are not named ``tick`` there (the
# core does not take that path then: supervisor/daemon/core.py).
plain_scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=False, allow_infinity=False),
)
step_rows = st.dictionaries(
    st.text(max_size=6).filter(lambda k: k != "tick"), plain_scalars, min_size=1, max_size=8
)


@st.composite
def steps(draw: st.DrawFn) -> dict[str, Any]:
    tick = draw(st.integers(min_value=0, max_value=2**40))
    inputs = draw(step_rows)
    before = draw(st.lists(st.builds(dict, step_rows), max_size=10))
    recent = [Row.of({"tick": tick - len(before) + k, **r}) for k, r in enumerate(before)]
    recent.append(Row.of({"tick": tick, **inputs}))
    return {
        "tick": tick,
        "inputs": inputs,
        "recent": recent,
        "stale": draw(st.lists(st.text(max_size=6), max_size=3)),
        "policy_state": draw(st.dictionaries(st.text(max_size=8), plain_scalars, max_size=8)),
    }


def _write_steps(path: Path, req: dict[str, Any], records: list[dict[str, Any]], row: bool) -> None:
    log = ViolationLog(path, "robot-1", CFG, echo=False)
    try:
        template = log.violation_template(req["requirement"], text=req["text"],
                                          formula=req["formula"])  # fmt: skip
        assert template is not None
        for i, r in enumerate(records):
            if i == 1:
                log.config_sha256 = "d1" * 32
            if row:
                written = log.violation_row(
                    template,
                    row=r["recent"][-1],
                    recent=r["recent"],
                    stale=r["stale"],
                    policy_state=writer.encode_fragment(r["policy_state"]),
                )
                assert written is True
            else:
                log.violation_from(template, **r)
            log.mitigation(req["requirement"], action="halt", kind="publish", ok=True,
                           latency_ms=0.1)  # fmt: skip
            if i == 0:
                log.flush()  # the chain's last hash made (the loop does it each turn)
    finally:
        log.close()


@settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(req=fixed, records=st.lists(steps(), min_size=1, max_size=3))
def test_a_record_from_the_steps_row_is_the_same_bytes(
    restart_clock: Callable[[], None], req: dict[str, Any], records: list[dict[str, Any]]
) -> None:
    with tempfile.TemporaryDirectory() as d:
        want, got = Path(d) / "from.jsonl", Path(d) / "row.jsonl"
        restart_clock()
        _write_steps(want, req, records, row=False)
        restart_clock()
        _write_steps(got, req, records, row=True)
        assert got.read_bytes() == want.read_bytes()
        assert want.read_bytes().count(b"\n") == 2 * len(records)


def test_a_row_without_plain_json_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    log = ViolationLog(tmp_path / "v.jsonl", "robot-1", CFG, echo=False)
    template = log.violation_template("R1", text="t", formula="f")
    assert template is not None
    nan = Row.of({"tick": 3, "x": math.nan})
    plain = [{"tick": 3, "x": 1.0}]
    assert log.violation_row(template, row=nan, recent=[nan], stale=[], policy_state="{}") is None
    assert log.violation_row(template, row=plain[0], recent=plain, stale=[],  # type: ignore[arg-type]
                             policy_state="{}") is None  # fmt: skip
    log.close()
    assert (tmp_path / "v.jsonl").read_bytes() == b""


def test_a_file_changed_behind_the_writer_is_chained_over(
    restart_clock: Callable[[], None], tmp_path: Path
) -> None:
    """Another writer's line between two records: the row's line is chained to it,
    as violation_from's is (the line made ahead is not used)."""
    out = {}
    for way in ("from", "row"):
        restart_clock()
        path = tmp_path / f"{way}.jsonl"
        log = ViolationLog(path, "robot-1", CFG, echo=False)
        template = log.violation_template("R1", text="t", formula="f")
        assert template is not None
        log.supervisor("start")
        log.flush()
        with open(path, "ab") as f:
            f.write(b'{"someone":"else"}\n')
        row = Row.of({"tick": 1, "x": 2.5})
        if way == "row":
            assert log.violation_row(template, row=row, recent=[row], stale=[],
                                     policy_state='{"a":1}') is True  # fmt: skip
        else:
            log.violation_from(template, tick=1, inputs={"x": 2.5}, recent=[row],
                               policy_state={"a": 1})  # fmt: skip
        log.close()
        out[way] = path.read_bytes()
    assert out["row"] == out["from"]
    last = json.loads(out["row"].splitlines()[-1])
    assert last["prev_sha256"] == writer.sha256_hex(b'{"someone":"else"}\n')
