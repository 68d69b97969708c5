"""The violation log's records, rendered in one encoder call on the halt's path
(mitigations/violationlog/writer.py), are byte for byte what the structlog processor
chain renders: each line written to a real file is rebuilt through the chain from
its header and fields, sealed and chained, and compared; the file verifies with
``safety-supervisor logs --verify``."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import structlog

from mitigations.violationlog.format import EMPTY_SHA256, ZERO_SHA256, seal_line, sha256_hex
from mitigations.violationlog.writer import Row, ViolationLog, _processors

REPO = Path(__file__).resolve().parents[3]
CFG = "c0" * 32
HEADER_KEYS = ("ts", "event", "component", "config_sha256", "prev_sha256", "seq")


def write_records(path: Path) -> None:
    log = ViolationLog(path, "robot-1", CFG, echo=False)
    try:
        log.violation(
            "state_req103",
            text="While OpState = 3 sRobot shall always satisfy halt",
            formula="G (OpState = 3 -> halt)",
            tick=42,
            inputs={"OpState": 3, "halt": False, "speed": 0.25, "label": 'a "quoted" é'},
            recent=[{"tick": t, "OpState": 3, "halt": False, "speed": t / 3} for t in range(10)],
            stale=["battery"],
            policy_state={"latched": False, "violations": 1, "cooldown": "ok"},
            formula_inputs={"OpState": "/state.data"},
        )
        log.mitigation(
            "state_req103", action="halt", kind="publish", ok=True, latency_ms=0.042, stage="v"
        )
        log.mitigation(
            "state_req103", action="ssh", kind="ssh", ok=False, latency_ms=1.5, error="refused"
        )
        log.reset("state_req103", reason="after_mitigation", tick=42)
        # extras named like the header or a fixed field are renamed (seq_, event_, ok_)
        log.supervisor("start", seq=9, event="x", ok=[1, (2, 3)], nested={"a": {"b": None}})
        log.supervisor("input_nan", value=math.nan, big=10**30, flag=True)
    finally:
        log.close()


def chain_line(record: dict[str, Any], prev: str) -> bytes:
    """The line the structlog chain renders for ``record``'s header and fields."""
    fields = {k: v for k, v in record.items() if k not in (*HEADER_KEYS, "line_sha256")}
    chain = structlog.BoundLogger(
        structlog.ReturnLogger(), _processors(safe=False), {"component": record["component"]}
    )
    text = chain.msg(
        record["event"],
        ts=record["ts"],
        config_sha256=record["config_sha256"],
        prev_sha256=ZERO_SHA256,
        seq=record["seq"],
        **fields,
    )
    body = text.encode("ascii").replace(ZERO_SHA256.encode(), prev.encode(), 1)
    return seal_line(body)


def test_written_lines_are_the_structlog_chains(tmp_path: Path) -> None:
    path = tmp_path / "violations.jsonl"
    write_records(path)
    lines = path.read_bytes().splitlines(keepends=True)
    assert len(lines) == 6
    prev = EMPTY_SHA256
    compared = 0
    for line in lines:
        record = json.loads(line)
        assert record["prev_sha256"] == prev
        if record.get("what") != "input_nan":  # NaN: the safe chain, as before
            assert line == chain_line(record, prev), line
            compared += 1
        prev = sha256_hex(line)
    assert compared == 5
    nan = json.loads(lines[-1])
    assert nan["value"] == "nan" and nan["big"] == 10**30
    start = json.loads(lines[4])
    assert list(start)[: len(HEADER_KEYS)] == list(HEADER_KEYS)
    assert (start["seq_"], start["event_"], start["ok"]) == (9, "x", [1, [2, 3]])
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", "logs", "--verify", str(path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def _same_but_hashes_and_ts(line: bytes) -> bytes:
    return re.sub(rb'"(ts|prev_sha256|line_sha256)":"[^"]*"', rb'"\1":""', line)


def _violations(path: Path, rows: list[dict[str, Any]]) -> None:
    log = ViolationLog(path, "robot-1", CFG, echo=False)
    try:
        for recent in (rows, rows[:1], [], [*rows[:3], {"tick": 3, "OpState": 2}]):
            log.violation(
                "state_req103",
                text='While "OpState" = 3 \\ é',
                formula="G (OpState = 3 -> halt)",
                tick=42,
                inputs={"recent": [], "speed": 0.25},
                recent=recent,
                stale=[],
                policy_state={"latched": True},
                formula_inputs={"OpState": "/state.data"},
                recent_=1,
            )
        nan = {"tick": 11, "speed": math.nan}
        recent = [*rows, Row.of(nan) if isinstance(rows[0], Row) else nan]
        log.violation("r", text="t", formula="f", tick=12, inputs={}, recent=recent)
    finally:
        log.close()


def test_pre_encoded_recent_rows_give_the_same_bytes(tmp_path: Path) -> None:
    """The daemon's runtime keeps each tick of ``recent`` as a Row with its JSON made
    when stepped; the record joined from those is, byte for byte, the one encoded
    whole from plain rows (and the chain's), and a row with no plain JSON form (NaN)
    sends the record the safe way, as before."""
    plain = [{"tick": t, "OpState": 3, "halt": False, "speed": t / 3} for t in range(10)]
    rows = [Row.of(r) for r in plain]
    assert all(r.json is not None for r in rows) and Row.of({"x": math.nan}).json is None
    _violations(tmp_path / "rows.jsonl", rows)
    _violations(tmp_path / "plain.jsonl", plain)
    lines = (tmp_path / "rows.jsonl").read_bytes().splitlines(keepends=True)
    want = (tmp_path / "plain.jsonl").read_bytes().splitlines(keepends=True)
    assert len(lines) == len(want) == 5
    assert [_same_but_hashes_and_ts(x) for x in lines] == [_same_but_hashes_and_ts(x) for x in want]
    prev = EMPTY_SHA256
    for line in lines[:4]:
        assert line == chain_line(json.loads(line), prev), line
        prev = sha256_hex(line)
    assert [len(json.loads(x)["recent"]) for x in lines] == [10, 1, 0, 4, 11]
    assert json.loads(lines[4])["recent"][-1] == {"tick": 11, "speed": "nan"}


def test_record_times_are_utc_to_the_microsecond(tmp_path: Path) -> None:
    """Each record's ``ts``: UTC, six digits of microseconds even when they are
    zeros, between the clock read before and after the write."""
    from datetime import UTC, datetime

    path = tmp_path / "violations.jsonl"
    before = datetime.now(UTC).replace(tzinfo=None)
    log = ViolationLog(path, "robot-1", CFG, echo=False)
    try:
        for _ in range(50):
            log.supervisor("start")
    finally:
        log.close()
    after = datetime.now(UTC).replace(tzinfo=None)
    for line in path.read_bytes().splitlines():
        ts = json.loads(line)["ts"]
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{6}Z", ts), ts
        assert before <= datetime.strptime(ts, "%Y-%m-%dT%H:%M:%S.%fZ") <= after, ts
