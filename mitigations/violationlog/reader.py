"""Reading violation logs: records in order, and verification of the hash chain.

The one reader of the format defined in :mod:`mitigations.violationlog.format`;
rotated files compressed by logrotate (``.gz``) are read as they are.
"""

from __future__ import annotations

import gzip
import json
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mitigations.violationlog.format import _PREV_RE, EMPTY_SHA256, line_seal_ok, sha256_hex
from monitors.errors import UserError


@dataclass
class VerifyResult:
    path: str
    records: int = 0
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    last_sha256: str = EMPTY_SHA256
    links: list[tuple[int, str]] = field(default_factory=list)  # (line, previous_last_sha256)
    broken: bool = False  # the hash chain itself is broken (else errors are seq gaps)
    first_seq: int | None = None  # of the file's first record, for the rotation link
    last_seq: int | None = None
    first: dict[str, Any] | None = None  # the file's first record
    lost: int = 0  # records a records_lost record accounts for
    missing: int = 0  # records missing from the seq with nothing to account for them

    @property
    def intact(self) -> bool:
        return not self.errors


def check_seq_gap(where: str, lo: int, hi: int, rec: dict[str, Any], res: VerifyResult) -> None:
    """Records ``lo``..``hi`` are missing before ``rec``: the writer accounts for a
    gap with a ``records_lost`` record right where the records would have been."""
    n = hi - lo + 1
    span = f"{lo}" if lo == hi else f"{lo}-{hi}"
    named: set[int] = set()
    if rec.get("event") == "supervisor" and rec.get("what") == "records_lost":
        for r in rec.get("lost") or []:
            if isinstance(r, list) and len(r) == 2 and all(isinstance(x, int) for x in r):
                named.update(range(r[0], r[1] + 1))
    if named == set(range(lo, hi + 1)):
        res.lost += n
        res.warnings.append(
            f"{where}: warning: {n} records (seq {span}) were never written: "
            f"{rec.get('reason')} (records_lost; they went to the journal only)"
        )
        return
    res.missing += n
    why = (
        f"the records_lost record there names seq {_ranges_text(rec.get('lost'))}"
        if named
        else "no records_lost record accounts for them"
    )
    res.errors.append(
        f"{where}: {n} records missing (seq {span}) before this line: {why} "
        "(removed, or the writer was changed)"
    )


def _ranges_text(ranges: Any) -> str:
    try:
        return ",".join(f"{a}" if a == b else f"{a}-{b}" for a, b in ranges)
    except (TypeError, ValueError):
        return repr(ranges)


def read_bytes(path: str) -> bytes:
    try:
        if path.endswith(".gz"):  # logrotate's compress
            with gzip.open(path, "rb") as f:
                return f.read()
        return Path(path).read_bytes()
    except (OSError, EOFError) as e:
        raise UserError(f"cannot read log: {getattr(e, 'strerror', None) or e}", file=path) from e


def split_lines(data: bytes) -> list[bytes]:
    """Lines with their newline; a final line without one is kept as it is.
    (Not bytes.splitlines: the chain is defined on \\n only.)"""
    out, start = [], 0
    while start < len(data):
        end = data.find(b"\n", start)
        end = len(data) if end < 0 else end + 1
        out.append(data[start:end])
        start = end
    return out


def verify_bytes(path: str, data: bytes) -> VerifyResult:
    res = VerifyResult(path)
    lines = split_lines(data)
    expected = EMPTY_SHA256
    seq: int | None = None  # of the last record; seq restarts at 1 with each writer
    for i, line in enumerate(lines, 1):
        where = f"{path}:{i}"
        last = i == len(lines)
        if not line.endswith(b"\n"):
            res.errors.append(
                f"{where}: incomplete final line (writer interrupted or file "
                f"truncated); the {res.records} records before it are intact"
            )
            res.broken = True
            break
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or "prev_sha256" not in rec:
                raise ValueError("not a record")
        except ValueError:
            nxt = None if last else _PREV_RE.search(lines[i])
            m = _PREV_RE.search(line)
            if (
                nxt is not None
                and nxt.group(1).decode() == sha256_hex(line)
                and (m is None or m.group(1).decode() == expected)
            ):
                res.warnings.append(
                    f"{where}: warning: incomplete record (writer interrupted); "
                    "the writer continued the chain after it"
                )
                expected = sha256_hex(line)
                continue
            res.errors.append(
                f"{where}: hash chain broken: not a log record (line was edited or inserted)"
            )
            res.broken = True
            break
        seal = line_seal_ok(line)
        if seal is False:
            res.errors.append(f"{where}: hash chain broken: line was edited")
            res.broken = True
            break
        if rec["prev_sha256"] != expected:
            if seal is None:
                msg = "line was edited or a line before it was removed"
            elif i == 1:
                msg = "the file's first line(s) were removed (or this line was inserted)"
            else:
                msg = "line was inserted, or a line before it was removed or rewritten"
            res.errors.append(f"{where}: hash chain broken: {msg}")
            res.broken = True
            break
        res.records += 1
        if res.first is None:
            res.first = rec
        n = rec.get("seq")
        if isinstance(n, int) and not isinstance(n, bool):
            if seq is None:
                res.first_seq = n
            elif n > seq + 1 and n != 1:
                check_seq_gap(where, seq + 1, n - 1, rec, res)
            elif n <= seq and n != 1:
                res.missing += 1
                res.errors.append(
                    f"{where}: seq {n} after seq {seq}: out of order (a record was "
                    "duplicated or moved, or the writer was changed)"
                )
            seq = res.last_seq = n
        if rec.get("event") == "supervisor" and rec.get("previous_last_sha256"):
            res.links.append((i, str(rec["previous_last_sha256"])))
        expected = sha256_hex(line)
    res.last_sha256 = expected
    return res


def parse_time(text: str) -> datetime:
    """ISO 8601; a time without a zone is UTC (the log is in UTC)."""
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError as e:
        raise ValueError(
            f"not an ISO 8601 time: {text!r} (e.g. 2026-11-21T20:24:13Z or 2026-11-21)"
        ) from e
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def iter_records(path: str, err: Any = None, *, raw: bool = False) -> Iterator[dict[str, Any]]:
    """The file's records with ``_ts`` (their time, parsed); ``raw``: also ``_line``,
    the line as stored without its newline (``logs --json``, rotation links)."""
    err = err or sys.stderr
    for i, line in enumerate(split_lines(read_bytes(path)), 1):
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or "event" not in rec or "ts" not in rec:
                raise ValueError
            rec["_ts"] = parse_time(str(rec["ts"]))
        except ValueError:
            print(f"{path}:{i}: warning: not a log record, skipped", file=err)
            continue
        if raw:
            rec["_line"] = line.rstrip(b"\n").decode("utf-8", "replace")
        yield rec


def records_since(
    path: str | Path, offset: int, *, raw: bool = False
) -> tuple[list[dict[str, Any]], int]:
    """The records appended after byte ``offset``, and the offset to read from next time.

    For following a log while the daemon writes it: a last line without its newline
    is still being written and is left for the next call; a missing file has no
    records yet; a file shorter than ``offset`` was rotated and is read from its start.
    Lines that are not records (an interrupted write) are skipped.  ``raw``: each
    record also carries ``_line``, the line as stored without its newline.
    """
    try:
        with open(path, "rb") as f:
            if os.fstat(f.fileno()).st_size < offset:
                offset = 0
            f.seek(offset)
            data = f.read()
    except FileNotFoundError:
        return [], offset
    complete = data.rfind(b"\n") + 1
    out = []
    for line in data[:complete].split(b"\n"):
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict) and "event" in rec:
            if raw:
                rec["_line"] = line.decode("utf-8", "replace")
            out.append(rec)
    return out, offset + complete
