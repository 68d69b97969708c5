"""``safety-supervisor logs``: query, follow, summarize and verify violation logs.

The format and its hash chain are described in :mod:`mitigations.violationlog.format`;
reading and verification live in :mod:`mitigations.violationlog.reader`.  Options and
the accepted times: docs/reference/commands.md (logs) and docs/reference/log.md.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import signal
import struct
import sys
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from mitigations.violationlog.format import (
    EVENTS,
    HEADER,
    BadRecord,
    details,
    parse_record,
    sha256_hex,
)
from mitigations.violationlog.reader import (
    LogLines,
    VerifyResult,
    check_seq_gap,
    iter_records,
    parse_time,
    records_since,
    verify_file,
)
from monitors.errors import UserError
from monitors.untrusted import printable

FOLLOW_INTERVAL_S = 0.2  # polling, as tail -F does without inotify
FOLLOW_LINES = 10  # records shown before following, as tail -f and journalctl -f

# journalctl's time spans (systemd.time(7)), without months and years: their length varies.
_UNITS = {
    **dict.fromkeys(("us", "usec"), 1e-6),
    **dict.fromkeys(("ms", "msec"), 1e-3),
    **dict.fromkeys(("s", "sec", "secs", "second", "seconds"), 1.0),
    **dict.fromkeys(("m", "min", "mins", "minute", "minutes"), 60.0),
    **dict.fromkeys(("h", "hr", "hrs", "hour", "hours"), 3600.0),
    **dict.fromkeys(("d", "day", "days"), 86400.0),
    **dict.fromkeys(("w", "week", "weeks"), 604800.0),
}
_SPAN_PART = re.compile(r"(\d+(?:\.\d+)?)\s*([a-z]+)")
_SPAN = re.compile(r"(?:\s*\d+(?:\.\d+)?\s*[a-z]+)+\s*")
_DAYS = {"today": 0, "yesterday": -1, "tomorrow": 1}
TIME_FORMS = (
    "ISO 8601 (2026-11-21, 2026-11-21T14:00, ...Z, ...+01:00; UTC without a zone), "
    "now, today, yesterday, tomorrow (midnight UTC), or relative: -2h, -30min, "
    "'-1h 30min', +10s, '2 hours ago'"
)


def _now() -> datetime:
    """The time relative times count from (tests replace it)."""
    return datetime.now(UTC)


def _span(text: str) -> float | None:
    """Seconds in ``2h``, ``30min``, ``1h 30min``, ``2 hours``; None if not a span."""
    if not _SPAN.fullmatch(text):
        return None
    total = 0.0
    for number, unit in _SPAN_PART.findall(text):
        if unit not in _UNITS:
            return None
        total += float(number) * _UNITS[unit]
    return total


def parse_when(text: str, now: datetime) -> datetime:
    """``--since``/``--until``: an ISO time or one relative to ``now`` (journalctl's words)."""
    low = text.strip().lower()
    if low == "now":
        return now
    if low in _DAYS:
        midnight = now.astimezone(UTC).replace(hour=0, minute=0, second=0, microsecond=0)
        return midnight + timedelta(days=_DAYS[low])
    # Units are case-sensitive, as journalctl's: "M" would be months, not minutes.
    body, sign = text.strip(), 0
    if body[:1] in ("+", "-"):
        sign, body = (1 if body[0] == "+" else -1), body[1:]
    elif low.endswith(" ago"):
        sign, body = -1, body[: -len(" ago")]
    seconds = _span(body) if sign else None
    if seconds is not None:
        return now + timedelta(seconds=sign * seconds)
    try:
        return parse_time(text)
    except ValueError:
        raise ValueError(f"not a time: {text!r}; use {TIME_FORMS}") from None


def time_arg(text: str) -> datetime:
    """argparse type of ``--since``/``--until``: a malformed time is a one-line usage error."""
    try:
        return parse_when(text, _now())
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e


def verify_files(paths: list[str], out: Any = None) -> int:
    """Each file's chain and ``seq``, and the links between rotated files (printed:
    what a record says is escaped for the terminal, docs/reference/faults.md)."""
    status, lines, _ = verify_paths(paths)
    out = out or sys.stdout
    for line in lines:
        print(printable(line), file=out)
    return status


def verify_paths(paths: list[str]) -> tuple[int, list[str], list[VerifyResult]]:
    """``verify_files``' exit status, lines and each file's result."""
    results = [verify_file(p) for p in paths]
    by_last = {r.last_sha256: r for r in results if r.records}
    linked: dict[str, list[str]] = {}
    for r in results:
        for line, prev in r.links:
            old = by_last.get(prev)
            if old is None or old is r:
                continue
            linked.setdefault(r.path, []).append(
                f"{r.path}:{line}: continues {old.path} (rotation link intact)"
            )
            # seq runs on across rotation: the new file starts where the old one ended.
            first = r.first_seq
            if (
                old.last_seq is not None
                and first is not None
                and first not in (1, old.last_seq + 1)
            ):
                assert r.first is not None
                check_seq_gap(f"{r.path}:1", old.last_seq + 1, first - 1, r.first, r)
    status = 0
    out: list[str] = []
    for r in results:
        out += r.warnings + r.errors
        if r.broken:
            status = 1
            continue
        lost = f", {r.lost} records lost and accounted for (records_lost)" if r.lost else ""
        if r.missing:
            status = 1
            out.append(
                f"{r.path}: {r.records} records{lost}, {r.missing} records MISSING "
                "(the hash chain itself is unbroken)"
            )
        else:
            out.append(f"{r.path}: {r.records} records, chain intact{lost}")
        out += linked.get(r.path, [])
    return status, out, results


def _selected(rec: dict[str, Any], args: argparse.Namespace) -> bool:
    """The filters, all of which must hold (add a new one here)."""
    if args.since and rec["_ts"] < args.since:
        return False
    if args.until and rec["_ts"] > args.until:
        return False
    if args.requirement and rec.get("requirement") not in args.requirement:
        return False
    if args.event and rec.get("event") not in args.event:
        return False
    # ok false: a failed attempt, or a confirmation whose effect was not seen
    return not (args.failed and (rec.get("event") != "mitigation" or rec.get("ok") is True))


# ---------------------------------------------------------------- files in order


@dataclass
class LogFile:
    """One file's records (with ``_ts`` and ``_line``) and what orders it among the others."""

    path: str
    records: list[dict[str, Any]]
    last_sha256: str | None = None  # of its last line: what a newer file links to
    links_to: str | None = None  # previous_last_sha256 of its log_reopened record
    newer: list[LogFile] = field(default_factory=list)

    @classmethod
    def read(cls, path: str, err: Any = None) -> LogFile:
        records = list(iter_records(path, err, raw=True))
        f = cls(path, records)
        if records:
            f.last_sha256 = sha256_hex((records[-1]["_line"] + "\n").encode())
        f.links_to = next(
            (
                str(r["previous_last_sha256"])
                for r in records
                if r.get("event") == "supervisor" and r.get("previous_last_sha256")
            ),
            None,
        )
        return f

    @property
    def first_ts(self) -> datetime | None:
        return self.records[0]["_ts"] if self.records else None


def in_order(files: list[LogFile]) -> list[LogFile]:
    """Oldest first, whatever the command line's order: a file whose ``log_reopened``
    record names another's last line comes right after it (the rotation link), and
    the chains of files so linked are ordered by their first record's time (files
    without records last: a file just rotated in)."""
    by_last = {f.last_sha256: f for f in files if f.last_sha256}
    heads = []
    for f in files:
        older = by_last.get(f.links_to) if f.links_to else None
        if older is not None and older is not f and not older.newer:
            older.newer.append(f)
        else:
            heads.append(f)
    far = datetime.max.replace(tzinfo=UTC)
    heads.sort(key=lambda f: f.first_ts or far)
    out: list[LogFile] = []
    for f in heads:
        while f is not None and f not in out:
            out.append(f)
            f = f.newer[0] if f.newer else None
    return out + [f for f in files if f not in out]  # a cycle of links: never dropped


def refuse_foreign(path: str) -> None:
    """A file whose first line is not a record of this format is not a violation log
    (a README, another program's JSON lines): one located line and exit 1, instead of
    a warning for each of its lines.  A log with a damaged line further on is read as
    before, that line skipped and counted; ``--verify`` fails at such a first line too
    (docs/reference/log.md, "Reading logs")."""
    for line in LogLines(path):
        if not line.endswith(b"\n"):
            return  # the first record still being written (logs -f): judged when whole
        try:
            parse_record(line)
        except BadRecord as e:
            raise UserError(
                printable(f"not a violation log: its first line is not a log record ({e})"),
                file=path,
                line=1,
            ) from None
        return


def load(paths: list[str], err: Any = None) -> list[LogFile]:
    """The files' records, oldest file first; skipped lines and damage on ``err``."""
    for p in paths:
        refuse_foreign(p)
    return in_order([LogFile.read(p, err) for p in paths])


# ---------------------------------------------------------------- output


class Printer:
    """The selected records as a table (header first), every field escaped for the
    terminal, or, ``--json``, as stored."""

    def __init__(self, as_json: bool, width: int, out: Any = None) -> None:
        self.as_json = as_json
        self.width = max(len("REQUIREMENT"), width)
        self.out = out or sys.stdout
        self.header = not as_json

    def __call__(self, records: Iterable[dict[str, Any]]) -> None:
        lines = []
        if self.header:
            self.header = False
            w = self.width
            lines.append(f"{'TIME':<27}  {'EVENT':<10}  {'REQUIREMENT':<{w}}  DETAILS")
        for r in records:
            if self.as_json:
                lines.append(r["_line"])
            else:
                req = printable(str(r.get("requirement", "-")))
                head, more = human_details(r)
                lines.append(
                    printable(f"{r['ts']:<27}  {r['event']:<10}  ")
                    + f"{req:<{self.width}}  {printable(head)}"
                )
                indent = " " * (27 + 2 + 10 + 2 + self.width + 2)
                lines += [indent + printable(m) for m in more]
        if lines:
            self.out.write("\n".join(lines) + "\n")
            self.out.flush()  # a follower's reader (a pipe) sees each record when it comes


def _float32_exact(v: float) -> bool:
    try:
        return struct.unpack("f", struct.pack("f", v))[0] == v
    except OverflowError:
        return False


def number(v: float) -> str:
    """A float at its type's precision: a value a float32 carried (a ROS ``float32``
    field) in the fewest digits that give that float32 back (``0.8``, not
    ``0.800000011920929``), any other at a double's (Python's shortest repr).
    Never rounded past what tells it from its neighbour: a value just over a
    threshold still reads as over it."""
    if v != v or v in (float("inf"), float("-inf")) or not _float32_exact(v):
        return repr(v)
    for digits in range(1, 10):
        text = f"{v:.{digits}g}"
        if struct.unpack("f", struct.pack("f", float(text)))[0] == v:
            return repr(float(text)) if "e" not in text else text
    return repr(v)


def _word(v: Any) -> str:
    """One value of ``key=value`` (a list of scalars comma-joined)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return number(v)
    if isinstance(v, list) and all(not isinstance(x, dict | list) for x in v):
        return ",".join(_word(x) for x in v) if v else "[]"
    if isinstance(v, dict) and all(not isinstance(x, dict | list) for x in v.values()):
        return "{" + " ".join(f"{k}={_word(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):  # of objects: one {...} each, the first few
        shown = " ".join(_word(x) for x in v[:3])
        return f"[{shown}{f' ... {len(v) - 3} more' if len(v) > 3 else ''}]"
    if v is None:
        return "null"
    if isinstance(v, dict):
        return "{" + " ".join(f"{k}={_word(x)}" for k, x in v.items()) + "}"
    return str(v)


def human_details(rec: dict[str, Any]) -> tuple[str, list[str]]:
    """The DETAILS column of a record: its first line and any lines below it.

    A field that holds one object per name (the ``stop`` record's ``inputs``, a
    summary per input) gets a line per name under the record instead of one
    long line of JSON; floats are shown at their type's precision (:func:`number`).
    ``--json`` shows the records as stored."""
    ev = rec.get("event")
    if ev == "violation":
        parts = [f"tick={rec.get('tick')}"]
        parts += [f"{k}={_word(v)}" for k, v in (rec.get("inputs") or {}).items()]
        if rec.get("stale"):
            parts.append("stale=" + ",".join(map(str, rec["stale"])))
        if "predicted_ms" in rec:  # the lead time of the prediction it followed
            parts.append(f"predicted_ms={rec['predicted_ms']}")  # ms, not a float32
        return " ".join(parts), []
    if ev in ("mitigation", "reset", "prediction", "prediction_expired"):
        return details(rec), []
    skip = {*HEADER, "line_sha256", "what"}
    head, more = [str(rec.get("what"))], []
    for k, v in rec.items():
        if k in skip or k[:1] == "_":
            continue
        if isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()):
            more.append(f"{k}:")
            w = max(len(str(name)) for name in v)
            for name, fields in v.items():
                words = " ".join(f"{f}={_word(x)}" for f, x in fields.items())
                more.append(f"  {str(name):<{w}}  {words}")
        else:
            head.append(f"{k}={_word(v)}")
    return " ".join(head), more


def _summary_rows(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    rows: dict[str, dict[str, Any]] = {}
    for rec in records:
        req = rec.get("requirement")
        if not req or rec.get("event") not in ("violation", "mitigation"):
            continue
        row = rows.setdefault(
            req, {"violations": 0, "first": None, "last": None, "ok": 0, "failed": 0}
        )
        if rec["event"] == "violation":
            row["violations"] += 1
            row["first"] = rec["ts"] if row["first"] is None else row["first"]
            row["last"] = rec["ts"]
        elif rec.get("ok"):
            row["ok"] += 1
        else:
            row["failed"] += 1
    return dict(sorted(rows.items()))


def _summary(records: list[dict[str, Any]]) -> list[str]:
    rows = _summary_rows(records)
    w = max([len("REQUIREMENT")] + [len(k) for k in rows])
    out = [
        f"{'REQUIREMENT':<{w}}  {'VIOLATIONS':>10}  {'FIRST':<27}  {'LAST':<27}  "
        f"{'MIT_OK':>6}  {'MIT_FAILED':>10}"
    ]
    for req, r in rows.items():
        out.append(
            f"{req:<{w}}  {r['violations']:>10}  {r['first'] or '-':<27}  "
            f"{r['last'] or '-':<27}  {r['ok']:>6}  {r['failed']:>10}"
        )
    return [printable(line) for line in out]


def _summary_json(records: list[dict[str, Any]]) -> list[str]:
    return [
        json.dumps(
            {
                "requirement": req,
                "violations": r["violations"],
                "first": r["first"],
                "last": r["last"],
                "mitigations_ok": r["ok"],
                "mitigations_failed": r["failed"],
            }
        )
        for req, r in _summary_rows(records).items()
    ]


# ---------------------------------------------------------------- --follow


class Follower:
    """``tail -F`` on the live log, through the reader's ``records_since``.

    The file is held open and read through ``/proc/self/fd``, so a file renamed
    by logrotate is read to its end; once the path names another file (the
    daemon reopened it, docs/reference/log.md#rotation) the new one is read from
    its start.  The old one is read once more after the new one has a record,
    for what the daemon wrote there before it reopened.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self.skipped: list[str] = []  # lines that fail the schema, as records_since says
        self.fd: int | None = None
        self.offset = 0
        self.old: list[tuple[int, int]] = []  # (fd, offset) of rotated files still read
        self._open()

    def _open(self) -> None:
        try:
            self.fd = os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)
        except FileNotFoundError:
            self.fd = None  # between logrotate's rename and create; tried again
        self.offset = 0

    def _read(self, fd: int, offset: int) -> tuple[list[dict[str, Any]], int]:
        return records_since(f"/proc/self/fd/{fd}", offset, raw=True, skipped=self.skipped)

    def _rotated(self) -> bool:
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return False
        if self.fd is None:
            return True
        cur = os.fstat(self.fd)
        return (st.st_dev, st.st_ino) != (cur.st_dev, cur.st_ino)

    def poll(self) -> list[dict[str, Any]]:
        """The records appended since the last call, oldest first."""
        out: list[dict[str, Any]] = []
        for i, (fd, offset) in enumerate(self.old):
            recs, offset = self._read(fd, offset)
            self.old[i] = (fd, offset)
            out += recs
        if self.fd is not None:
            recs, self.offset = self._read(self.fd, self.offset)
            out += recs
        if self._rotated():
            if self.fd is not None:
                self.old.append((self.fd, self.offset))
            self._open()
            if self.fd is not None:
                recs, self.offset = self._read(self.fd, self.offset)
                out += recs
        if self.old and self.offset > 0:
            # The new file has a record: the daemon writes no more to the old ones.
            for fd, offset in self.old:
                out += self._read(fd, offset)[0]
                os.close(fd)
            self.old = []
        for why in self.skipped:
            print(printable(f"{self.path}: {why}"), file=sys.stderr)
        self.skipped.clear()
        return out

    def close(self) -> None:
        for fd in [fd for fd, _ in self.old] + ([self.fd] if self.fd is not None else []):
            os.close(fd)
        self.old, self.fd = [], None


def _follow(files: list[LogFile], args: argparse.Namespace, skipped: str) -> int:
    """Print the last ``--lines`` selected records, then the new ones until SIGTERM
    (exit 0) or Ctrl-C (130); the newest file is the one followed.  ``skipped``: what
    reading ``files`` said; the followed file's lines are the follower's to report."""
    live = next((f for f in reversed(files) if not f.path.endswith(".gz")), None)
    if live is None:
        raise UserError("--follow needs a log that is not compressed (.gz)")
    mine = (f"{printable(live.path)}:", f"{printable(live.path)} ")
    sys.stderr.writelines(s for s in skipped.splitlines(True) if not s.startswith(mine))
    stop = threading.Event()
    follower = Follower(live.path)
    old_handler = None
    if threading.current_thread() is threading.main_thread():
        old_handler = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        # The live file as the follower reads it: a line being written is left for later.
        history = [r for f in files if f is not live for r in f.records] + follower.poll()
        selected = [r for r in history if _selected(r, args)]
        lines = FOLLOW_LINES if args.lines is None else args.lines
        selected = selected[len(selected) - lines :] if lines else []
        printer = Printer(args.json, _width(history))
        printer(selected)
        while not stop.wait(FOLLOW_INTERVAL_S):
            printer(r for r in follower.poll() if _selected(r, args))
    except KeyboardInterrupt:
        return 130
    finally:
        follower.close()
        if old_handler is not None:
            signal.signal(signal.SIGTERM, old_handler)
    return 0


# ---------------------------------------------------------------- the command


def cmd_logs(args: argparse.Namespace) -> int:
    args.files = _files(args.files)
    if args.verify:
        return verify_files(args.files)
    if args.follow:
        said = io.StringIO()
        return _follow(load(args.files, said), args, said.getvalue())
    files = load(args.files)
    if args.why:
        return _why([r for f in files for r in f.records], args)
    records = [r for f in files for r in f.records if _selected(r, args)]
    if args.summary:
        for line in _summary_json(records) if args.json else _summary(records):
            print(line)
        return 0
    if args.lines is not None:
        records = records[len(records) - args.lines :] if args.lines else []
    Printer(args.json, _width(records))(records)
    return 0


def _files(paths: list[str]) -> list[str]:
    """A recording directory (demo --record) stands for its violation log's files."""
    from supervisor.tools.recording import is_recording_dir, recording_dir

    out: list[str] = []
    for p in paths:
        out += [str(f) for f in recording_dir(p, log=True).logs] if is_recording_dir(p) else [p]
    return out


def _width(records: list[dict[str, Any]]) -> int:
    """Of the REQUIREMENT column: the longest id as the terminal shows it."""
    return max((len(printable(str(r.get("requirement", "")))) for r in records), default=0)


def _why(records: list[dict[str, Any]], args: argparse.Namespace) -> int:
    """Each selected violation, and why it fired: the why-engine on the inputs its
    monitor judged, as far as the record's ``recent`` window shows them."""
    from supervisor.tools.why import mark_runs, why_of, windows_from_log

    mark_runs(records)
    windows = windows_from_log(records)
    chosen = [
        (i, r)
        for i, r in enumerate(records)
        if r.get("event") == "violation" and _selected(r, args)
    ]
    if args.lines is not None:
        chosen = chosen[len(chosen) - args.lines :] if args.lines else []
    out = []
    for i, r in chosen:
        why = why_of(r, windows.get(i))
        if args.json:
            out.append(
                json.dumps(
                    {
                        "ts": r.get("ts"),
                        "requirement": r.get("requirement"),
                        "tick": r.get("tick"),
                        "why": why.sentence or None,
                        "problem": why.problem,
                        "window": why.window.note if why.window else None,
                    }
                )
            )
        else:
            out.append(printable(f"{r['ts']}  {r['requirement']}  tick {r['tick']}"))
            out.append(
                printable(
                    f"  why: {why.sentence}" if why.sentence else f"  (no why: {why.problem})"
                )
            )
    if out:
        print("\n".join(out))
    return 0


def _lines_arg(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"not a number of records: {text!r}")
    return n


# Relative times start with "-" (--since -2h): argparse would take them for options.
_OPTION_LIKE_VALUE = re.compile(r"^-\d+$|^-\d*\.\d+$|^-\d+(?:\.\d+)?\s*[a-z]")


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "logs", help="read violation logs: filter, follow, summarize, verify the hash chain"
    )
    if hasattr(p, "_negative_number_matcher"):  # argparse's own test for "-5" values
        p._negative_number_matcher = _OPTION_LIKE_VALUE
    p.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="violation logs, rotated ones (.1, .2.gz) too, in any order; a recording "
        "directory (demo --record DIR) for its log",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--verify",
        action="store_true",
        help="check the hash chain and the records' seq; exit 1 at a broken line or missing records",
    )
    mode.add_argument(
        "--summary",
        action="store_true",
        help="per requirement: violations, first/last time, mitigations ok/failed",
    )
    mode.add_argument(
        "--why",
        action="store_true",
        help="each selected violation and why it fired: the inputs that decided it, "
        "judged by the reference interpreter over the record's recent ticks",
    )
    mode.add_argument(
        "-f",
        "--follow",
        action="store_true",
        help="print the selected records as they are appended, across rotation (Ctrl-C stops)",
    )
    when = "ISO 8601 (UTC if no zone), now, today, yesterday, or -2h, -30min, '2 hours ago'"
    p.add_argument("--since", type=time_arg, metavar="TIME", help=f"at or after: {when}")
    p.add_argument("--until", type=time_arg, metavar="TIME", help="at or before (as --since)")
    p.add_argument("--requirement", action="append", metavar="ID", help="repeatable")
    p.add_argument("--event", action="append", choices=EVENTS, help="repeatable")
    p.add_argument(
        "--failed",
        action="store_true",
        help="only mitigation records with ok false: failed attempts and confirmations "
        "that did not take effect",
    )
    p.add_argument("--json", action="store_true", help="the records as stored (JSON lines)")
    p.add_argument(
        "-n",
        "--lines",
        type=_lines_arg,
        metavar="N",
        help=f"only the last N selected records (--follow: {FOLLOW_LINES} before following)",
    )
