"""Reading violation logs: records in order, and verification of the hash chain.

The one reader of the format defined in :mod:`mitigations.violationlog.format`;
rotated files compressed by logrotate (``.gz``) are read as they are, inflated as
they are read within a bound.  A log is untrusted input (its chain has no key): every
line is checked against the format's schema (``parse_record``) where it is read, and
a line that fails is skipped with one located line and counted, never used
(docs/reference/faults.md, "Trust").
"""

from __future__ import annotations

import gzip
import json
import os
import re
import stat
import sys
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import IO, Any

from mitigations.violationlog.format import (
    _PREV_RE,
    EMPTY_SHA256,
    MAX_LINE,
    BadRecord,
    line_seal_ok,
    parse_record,
    sha256_hex,
)
from monitors.errors import UserError
from monitors.untrusted import printable

# A rotated .gz inflates to at most this: logrotate rotates at 100 MB (the shipped
# snippet's maxsize), so past it the file is not one of ours (a gzip bomb).
MAX_INFLATED = 1 << 30
_HEADER_RE = re.compile(rb'"prev_sha256":"([0-9a-f]{64})","seq":(\d{1,19})[,}]')
SHOWN_SKIPS = 20  # located lines per file for records skipped; the rest are counted


class LogLines:
    """The lines of one file, with their newline, each of at most ``MAX_LINE`` bytes;
    a ``.gz`` is inflated while it is read, at most ``MAX_INFLATED`` bytes.  Reading
    ends at damage (a line too long, a compressed stream that is broken or too
    large): ``damage`` then says so in one located line."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.damage: str | None = None
        try:
            # O_NONBLOCK: a FIFO opens at once, to be refused, where a plain open waits
            # for a writer (and a log is opened more than once: its first line, its
            # chain, its records); on a regular file the flag changes nothing
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as e:
            raise UserError(f"cannot read log: {e.strerror or e}", file=path) from e
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise UserError("cannot read log: not a regular file", file=path)
        self._raw = os.fdopen(fd, "rb")
        self._file: IO[bytes] = (
            gzip.GzipFile(fileobj=self._raw) if path.endswith(".gz") else self._raw
        )

    def __iter__(self) -> Iterator[bytes]:
        total = n = 0
        cap = MAX_INFLATED if self.path.endswith(".gz") else None
        with self._raw, self._file as f:  # a GzipFile leaves its file open
            while True:
                try:
                    line = f.readline(MAX_LINE + 1)
                except (OSError, EOFError, zlib.error) as e:
                    self._damaged(n + 1, f"{getattr(e, 'strerror', None) or e}")
                    return
                if not line:
                    return
                n += 1
                total += len(line)
                if len(line) > MAX_LINE:
                    self._damaged(n, f"a line longer than {MAX_LINE} bytes")
                    return
                if cap is not None and total > cap:
                    self._damaged(n, f"inflates to more than {cap} bytes")
                    return
                yield line

    def _damaged(self, line: int, why: str) -> None:
        self.damage = printable(f"{self.path}:{line}: damaged: {why}; read up to there")


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
    """The whole file (inflated), within :class:`LogLines`' bounds; damage is an error."""
    src = LogLines(path)
    data = b"".join(src)
    if src.damage:
        raise UserError(src.damage)
    return data


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
    return verify_lines(path, split_lines(data))


def verify_file(path: str) -> VerifyResult:
    """The file's chain, read line by line (memory: one line); damage is an error."""
    src = LogLines(path)
    res = verify_lines(path, src)
    if src.damage and not res.broken:
        res.errors.append(src.damage)
        res.broken = True
    return res


def _header(line: bytes) -> dict[str, Any] | None:
    """The chain fields of a line too deep to parse, where the writer puts them (the
    header comes first, and inside a JSON string a quote is escaped)."""
    m = _HEADER_RE.search(line)
    return None if m is None else {"prev_sha256": m[1].decode(), "seq": int(m[2])}


def verify_lines(path: str, lines: Iterable[bytes]) -> VerifyResult:
    res = VerifyResult(path)
    expected = EMPTY_SHA256
    seq: int | None = None  # of the last record; seq restarts at 1 with each writer
    ahead = iter(lines)
    nxt = next(ahead, None)
    i = 0
    while nxt is not None:
        line, nxt = nxt, next(ahead, None)
        i += 1
        where = f"{path}:{i}"
        if not line.endswith(b"\n"):
            res.errors.append(
                f"{where}: incomplete final line (writer interrupted or file "
                f"truncated); the {res.records} records before it are intact"
            )
            res.broken = True
            break
        rec = _record(line)
        if rec is None:
            if _continued_after(line, nxt, expected):
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
        broken = _chain_break(line, rec, expected, i)
        if broken is not None:
            res.errors.append(f"{where}: hash chain broken: {broken}")
            res.broken = True
            break
        res.records += 1
        if res.first is None:
            res.first = rec
        seq = _follow_seq(where, rec, seq, res)
        if rec.get("event") == "supervisor" and rec.get("previous_last_sha256"):
            res.links.append((i, str(rec["previous_last_sha256"])))
        expected = sha256_hex(line)
    res.last_sha256 = expected
    return res


def _record(line: bytes) -> dict[str, Any] | None:
    """The line's chain fields, or None when it is not a log record."""
    # the chain only: the schema is the readers' (a record of the wrong shape
    # written by the writer, or chained by anyone, still verifies)
    try:
        try:
            rec = json.loads(line)
        except RecursionError:  # nested deeper than the parser goes: the header
            rec = _header(line)
    except ValueError:
        return None
    if not isinstance(rec, dict) or "prev_sha256" not in rec:
        return None
    return rec


def _continued_after(line: bytes, nxt: bytes | None, expected: str) -> bool:
    """Whether a line that is no record is an interrupted write the writer chained
    the next line to (and that itself followed the chain, where it says so)."""
    follows = None if nxt is None else _PREV_RE.search(nxt)
    m = _PREV_RE.search(line)
    return (
        follows is not None
        and follows.group(1).decode() == sha256_hex(line)
        and (m is None or m.group(1).decode() == expected)
    )


def _chain_break(line: bytes, rec: dict[str, Any], expected: str, i: int) -> str | None:
    """What broke the chain at record ``rec`` (line ``i``), or None where it holds."""
    seal = line_seal_ok(line)
    if seal is False:
        return "line was edited"
    if rec["prev_sha256"] != expected:
        if seal is None:
            return "line was edited or a line before it was removed"
        if i == 1:
            return "the file's first line(s) were removed (or this line was inserted)"
        return "line was inserted, or a line before it was removed or rewritten"
    return None


def _follow_seq(where: str, rec: dict[str, Any], seq: int | None, res: VerifyResult) -> int | None:
    """Checks the record's seq against the previous one (gaps and reorders go to
    ``res``); returns the seq to compare the next record with."""
    n = rec.get("seq")
    if not isinstance(n, int) or isinstance(n, bool):
        return seq
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
    res.last_seq = n
    return n


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
    """The file's records that pass the schema, with ``_ts`` (their time, parsed);
    ``raw``: also ``_line``, the line as stored without its newline (``logs --json``,
    rotation links).  On ``err``: ``FILE:LINE: skipped: why`` for each line that does
    not pass (the first ``SHOWN_SKIPS``), their count, and damage."""
    err = err or sys.stderr
    src = LogLines(path)
    skipped = 0
    for i, line in enumerate(src, 1):
        try:
            rec = parse_record(line)
        except BadRecord as e:
            skipped += 1
            if skipped <= SHOWN_SKIPS:
                print(printable(f"{path}:{i}: skipped: {e}"), file=err)
            elif skipped == SHOWN_SKIPS + 1:
                print(printable(f"{path}: more lines skipped: counted only"), file=err)
            continue
        if raw:
            rec["_line"] = line.rstrip(b"\n").decode("utf-8")
        yield rec
    if skipped:
        s = "" if skipped == 1 else "s"
        print(printable(f"{path}: {skipped} line{s} skipped (not a log record)"), file=err)
    if src.damage:
        print(src.damage, file=err)


def records_since(
    path: str | os.PathLike[str],
    offset: int,
    *,
    raw: bool = False,
    skipped: list[str] | None = None,
) -> tuple[list[dict[str, Any]], int]:
    """The records appended after byte ``offset``, and the offset to read from next time.

    For following a log while the daemon writes it: a last line without its newline
    is still being written and is left for the next call; a missing file has no
    records yet; a file shorter than ``offset`` was rotated and is read from its start.
    Lines that are not records (an interrupted write, or a record that fails the
    schema) are skipped; ``skipped`` collects ``byte N: skipped: why`` for each.  ``raw``:
    each record also carries ``_line``, the line as stored without its newline.
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
    at = offset
    for line in data[:complete].split(b"\n")[:-1]:
        try:
            rec = parse_record(line)
        except BadRecord as e:
            if skipped is not None:
                skipped.append(f"byte {at}: skipped: {e}")
        else:
            if raw:
                rec["_line"] = line.decode("utf-8")
            out.append(rec)
        at += len(line) + 1
    return out, offset + complete
