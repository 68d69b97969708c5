"""verify_bytes on hand-chained lines: the paths the writer's own logs do not take
(unsealed lines, records nested past the parser, non-record JSON, seq going back).
Each result is compared whole (docs/reference/log.md)."""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from mitigations.violationlog.format import EMPTY_SHA256, sha256_hex
from mitigations.violationlog.reader import VerifyResult, verify_bytes


def _chain(*extras: dict[str, Any]) -> list[bytes]:
    """Unsealed records (no line_sha256), each chained to the one before."""
    lines: list[bytes] = []
    prev = EMPTY_SHA256
    for extra in extras:
        line = json.dumps({"prev_sha256": prev, **extra}, separators=(",", ":")).encode() + b"\n"
        lines.append(line)
        prev = sha256_hex(line)
    return lines


def _result(data: bytes) -> dict[str, Any]:
    res = verify_bytes("v.log", data)
    assert isinstance(res, VerifyResult)
    return asdict(res)


def test_unsealed_line_with_another_prev_is_edited_or_after_a_removal() -> None:
    lines = _chain({"seq": 1}, {"seq": 2})
    bad = lines[1].replace(lines[1][16:20], b"0000")
    assert bad != lines[1]
    got = _result(lines[0] + bad)
    assert got == asdict(
        VerifyResult(
            "v.log",
            records=1,
            errors=["v.log:2: hash chain broken: line was edited or a line before it was removed"],
            last_sha256=sha256_hex(lines[0]),
            broken=True,
            first_seq=1,
            last_seq=1,
            first={"prev_sha256": EMPTY_SHA256, "seq": 1},
        )
    )


def test_record_nested_past_the_parser_is_read_by_its_header() -> None:
    deep = b"[" * 200_000 + b"]" * 200_000
    line = b'{"prev_sha256":"' + EMPTY_SHA256.encode() + b'","seq":1,"x":' + deep + b"}\n"
    got = _result(line)
    assert got == asdict(
        VerifyResult(
            "v.log",
            records=1,
            last_sha256=sha256_hex(line),
            first_seq=1,
            last_seq=1,
            first={"prev_sha256": EMPTY_SHA256, "seq": 1},
        )
    )


def test_json_that_is_no_record_breaks_the_chain() -> None:
    lines = _chain({"seq": 1})
    for other in (b"[1]\n", b'{"seq":2}\n'):
        got = _result(lines[0] + other)
        assert got["errors"] == [
            "v.log:2: hash chain broken: not a log record (line was edited or inserted)"
        ]
        assert (got["records"], got["broken"], got["last_sha256"]) == (
            1,
            True,
            sha256_hex(lines[0]),
        )


def test_seq_going_back_is_out_of_order_and_the_chain_goes_on() -> None:
    lines = _chain({"seq": 1}, {"seq": 2}, {"seq": 2}, {"seq": 3})
    got = _result(b"".join(lines))
    assert got == asdict(
        VerifyResult(
            "v.log",
            records=4,
            errors=[
                "v.log:3: seq 2 after seq 2: out of order (a record was duplicated or moved, "
                "or the writer was changed)"
            ],
            last_sha256=sha256_hex(lines[3]),
            first_seq=1,
            last_seq=3,
            first={"prev_sha256": EMPTY_SHA256, "seq": 1},
            missing=1,
        )
    )


def test_an_interrupted_record_is_passed_over_only_where_it_followed_the_chain() -> None:
    first = _chain({"seq": 1})[0]
    for prev, intact in ((sha256_hex(first), True), ("0" * 64, False)):
        cut = b'{"prev_sha256":"' + prev.encode() + b'","seq":2,"x":\n'
        text = json.dumps({"prev_sha256": sha256_hex(cut), "seq": 3}, separators=(",", ":"))
        after = text.encode() + b"\n"
        got = _result(first + cut + after)
        if intact:
            assert (got["warnings"], got["errors"], got["records"]) == (
                [
                    "v.log:2: warning: incomplete record (writer interrupted); "
                    "the writer continued the chain after it"
                ],
                [
                    "v.log:3: 1 records missing (seq 2) before this line: no records_lost "
                    "record accounts for them (removed, or the writer was changed)"
                ],
                2,
            )
        else:
            assert (got["warnings"], got["errors"], got["records"]) == (
                [],
                ["v.log:2: hash chain broken: not a log record (line was edited or inserted)"],
                1,
            )
