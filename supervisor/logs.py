"""The violation log's on-disk format, its verification, and the ``logs`` command.

Format (written by :mod:`supervisor.log`): JSON lines, ASCII, one object per
line, ``\\n``-terminated.  Every record starts with ``ts``, ``event``,
``component``, ``config_sha256``, ``prev_sha256`` and ends with ``line_sha256``.

Hash chain, per file:

* ``prev_sha256`` is the SHA-256 (hex) of the previous line's bytes including
  its newline; the first line of a file carries the hash of the empty string.
  Each file therefore verifies on its own (logrotate may compress or delete
  older files without breaking the newer ones).
* ``line_sha256`` is the SHA-256 of the line itself (including the newline)
  with this field's value replaced by 64 zeros.  It lets ``--verify`` name the
  line that was edited, rather than the line after it.
* Across rotation the files are linked, not chained: after ``reopen()`` the
  writer's first record in the (new) file is a ``supervisor`` record
  ``what="log_reopened"`` whose ``previous_last_sha256`` is the hash of the
  last line written to the old file.  ``--verify old new`` reports the link.
* A line left incomplete by a crash or a full disk is terminated by the writer
  when it next writes, and the next record chains over it, so such a line in
  the middle of a file is a warning, not a break.  An incomplete *final* line
  cannot be told from a truncated file and fails verification.

What the chain cannot show: a file whose last whole lines were removed (unless
a later file's link names them), or a file rewritten from scratch by someone
who recomputes the hashes; it has no key.

Non-finite floats, which JSON lacks, are written as the strings ``"nan"``,
``"inf"`` and ``"-inf"``.

This module uses the standard library only, so the CLI stays quick to start.
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from monitors.errors import UserError

EMPTY_SHA256 = hashlib.sha256(b"").hexdigest()
ZERO_SHA256 = "0" * 64
EVENTS = ("violation", "mitigation", "reset", "supervisor")

_LINE_HASH_RE = re.compile(rb',"line_sha256":"([0-9a-f]{64})"\}\n\Z')
_PREV_RE = re.compile(rb'"prev_sha256":"([0-9a-f]{64})"')


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def seal_line(body: bytes) -> bytes:
    """Append ``line_sha256`` to a rendered JSON object ``{...}`` (no newline)."""
    assert body.endswith(b"}")
    placeholder = body[:-1] + b',"line_sha256":"' + ZERO_SHA256.encode() + b'"}\n'
    digest = sha256_hex(placeholder).encode()
    return placeholder[: -len(ZERO_SHA256) - 3] + digest + b'"}\n'


def line_seal_ok(line: bytes) -> bool | None:
    """True/False when the line carries a ``line_sha256``; None when it has none."""
    m = _LINE_HASH_RE.search(line)
    if m is None:
        return None
    zeroed = line[: m.start(1)] + ZERO_SHA256.encode() + line[m.end(1) :]
    return sha256_hex(zeroed) == m.group(1).decode()


# ------------------------------------------------------------------ formatting


def _fmt_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def details(rec: dict[str, Any]) -> str:
    """The event-specific part of a record, as ``key=value`` words."""
    ev = rec.get("event")
    if ev == "violation":
        parts = [f"tick={rec.get('tick')}"]
        parts += [f"{k}={_fmt_value(v)}" for k, v in (rec.get("inputs") or {}).items()]
        if rec.get("stale"):
            parts.append("stale=" + ",".join(map(str, rec["stale"])))
        return " ".join(parts)
    if ev == "mitigation":
        res = "ok" if rec.get("ok") else f"FAILED ({rec.get('error')})"
        return (
            f"{rec.get('kind')}:{rec.get('action')} {res} "
            f"latency_ms={rec.get('latency_ms')} attempt={rec.get('attempt')}"
        )
    if ev == "reset":
        return f"reason={rec.get('reason')}"
    skip = {"ts", "event", "component", "config_sha256", "prev_sha256", "line_sha256", "what"}
    extra = [f"{k}={_fmt_value(v)}" for k, v in rec.items() if k not in skip and k[:1] != "_"]
    return " ".join([str(rec.get("what"))] + extra)


def describe(rec: dict[str, Any]) -> str:
    """One human-readable line for a record (stderr/journald), e.g.
    ``VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2``."""
    label = str(rec.get("event", "?")).upper()
    req = rec.get("requirement")
    return f"{label} {req} {details(rec)}" if req else f"{label} {details(rec)}"


# ------------------------------------------------------------------ verification


@dataclass
class VerifyResult:
    path: str
    records: int = 0
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    last_sha256: str = EMPTY_SHA256
    links: list[tuple[int, str]] = field(default_factory=list)  # (line, previous_last_sha256)

    @property
    def intact(self) -> bool:
        return not self.errors


def _read_bytes(path: str) -> bytes:
    try:
        if path.endswith(".gz"):  # logrotate's compress
            with gzip.open(path, "rb") as f:
                return f.read()
        return Path(path).read_bytes()
    except (OSError, EOFError) as e:
        raise UserError(f"cannot read log: {getattr(e, 'strerror', None) or e}", file=path) from e


def _split_nl(data: bytes) -> list[bytes]:
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
    lines = _split_nl(data)
    expected = EMPTY_SHA256
    for i, line in enumerate(lines, 1):
        where = f"{path}:{i}"
        last = i == len(lines)
        if not line.endswith(b"\n"):
            res.errors.append(
                f"{where}: incomplete final line (writer interrupted or file "
                f"truncated); the {res.records} records before it are intact"
            )
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
            break
        seal = line_seal_ok(line)
        if seal is False:
            res.errors.append(f"{where}: hash chain broken: line was edited")
            break
        if rec["prev_sha256"] != expected:
            if seal is None:
                msg = "line was edited or a line before it was removed"
            elif i == 1:
                msg = "the file's first line(s) were removed (or this line was inserted)"
            else:
                msg = "line was inserted, or a line before it was removed or rewritten"
            res.errors.append(f"{where}: hash chain broken: {msg}")
            break
        res.records += 1
        if rec.get("event") == "supervisor" and rec.get("previous_last_sha256"):
            res.links.append((i, str(rec["previous_last_sha256"])))
        expected = sha256_hex(line)
    res.last_sha256 = expected
    return res


def verify_files(paths: list[str], out: Any = None) -> int:
    out = out or sys.stdout
    results = [verify_bytes(p, _read_bytes(p)) for p in paths]
    by_last = {r.last_sha256: r.path for r in results if r.records}
    status = 0
    for r in results:
        for w in r.warnings:
            print(w, file=out)
        for e in r.errors:
            print(e, file=out)
        if r.intact:
            print(f"{r.path}: {r.records} records, chain intact", file=out)
            for line, prev in r.links:
                if prev in by_last and by_last[prev] != r.path:
                    print(
                        f"{r.path}:{line}: continues {by_last[prev]} (rotation link intact)",
                        file=out,
                    )
        else:
            status = 1
    return status


# ------------------------------------------------------------------ reading


def parse_time(text: str) -> datetime:
    """ISO 8601; a time without a zone is UTC (the log is in UTC)."""
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError as e:
        raise argparse.ArgumentTypeError(
            f"not an ISO 8601 time: {text!r} (e.g. 2026-11-21T20:24:13Z or 2026-11-21)"
        ) from e
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def iter_records(path: str, err: Any = None) -> Iterator[dict[str, Any]]:
    err = err or sys.stderr
    for i, line in enumerate(_split_nl(_read_bytes(path)), 1):
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or "event" not in rec or "ts" not in rec:
                raise ValueError
            rec["_ts"] = parse_time(str(rec["ts"]))
        except (ValueError, argparse.ArgumentTypeError):
            print(f"{path}:{i}: warning: not a log record, skipped", file=err)
            continue
        yield rec


def _selected(rec: dict[str, Any], args: argparse.Namespace) -> bool:
    if args.since and rec["_ts"] < args.since:
        return False
    if args.until and rec["_ts"] > args.until:
        return False
    if args.requirement and rec.get("requirement") not in args.requirement:
        return False
    return not (args.event and rec.get("event") not in args.event)


def _summary(records: list[dict[str, Any]]) -> list[str]:
    rows: dict[str, dict[str, Any]] = {}
    for rec in records:
        req = rec.get("requirement")
        if not req or rec.get("event") not in ("violation", "mitigation"):
            continue
        row = rows.setdefault(req, {"v": 0, "first": None, "last": None, "ok": 0, "failed": 0})
        if rec["event"] == "violation":
            row["v"] += 1
            row["first"] = rec["ts"] if row["first"] is None else row["first"]
            row["last"] = rec["ts"]
        elif rec.get("ok"):
            row["ok"] += 1
        else:
            row["failed"] += 1
    w = max([len("REQUIREMENT")] + [len(k) for k in rows])
    out = [
        f"{'REQUIREMENT':<{w}}  {'VIOLATIONS':>10}  {'FIRST':<27}  {'LAST':<27}  "
        f"{'MIT_OK':>6}  {'MIT_FAILED':>10}"
    ]
    for req in sorted(rows):
        r = rows[req]
        out.append(
            f"{req:<{w}}  {r['v']:>10}  {r['first'] or '-':<27}  {r['last'] or '-':<27}  "
            f"{r['ok']:>6}  {r['failed']:>10}"
        )
    return out


def cmd_logs(args: argparse.Namespace) -> int:
    if args.verify:
        return verify_files(args.files)
    records = [r for p in args.files for r in iter_records(p) if _selected(r, args)]
    records.sort(key=lambda r: r["_ts"])  # several files (rotated ones) in time order
    if args.summary:
        for line in _summary(records):
            print(line)
        return 0
    w = max([len("REQUIREMENT")] + [len(str(r.get("requirement", ""))) for r in records])
    print(f"{'TIME':<27}  {'EVENT':<10}  {'REQUIREMENT':<{w}}  DETAILS")
    for r in records:
        print(f"{r['ts']:<27}  {r['event']:<10}  {r.get('requirement', '-'):<{w}}  {details(r)}")
    return 0


def add_parser(sub: Any) -> None:
    p = sub.add_parser("logs", help="read violation logs: filter, summarize, verify the hash chain")
    p.add_argument(
        "files", nargs="+", metavar="FILE", help="violation logs (.gz too), oldest first"
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="check the hash chain; exit 1 at the first broken line",
    )
    p.add_argument("--since", type=parse_time, metavar="TIME", help="ISO 8601, UTC if no zone")
    p.add_argument("--until", type=parse_time, metavar="TIME", help="ISO 8601, UTC if no zone")
    p.add_argument("--requirement", action="append", metavar="ID", help="repeatable")
    p.add_argument("--event", action="append", choices=EVENTS, help="repeatable")
    p.add_argument(
        "--summary",
        action="store_true",
        help="per requirement: violations, first/last time, mitigations ok/failed",
    )
