"""``safety-supervisor logs``: filter, summarize and verify violation logs.

The format and its hash chain are described in :mod:`mitigations.violationlog.format`;
reading and verification live in :mod:`mitigations.violationlog.reader`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from mitigations.violationlog.format import EVENTS, details
from mitigations.violationlog.reader import iter_records, parse_time, read_bytes, verify_bytes


def time_arg(text: str) -> Any:
    """``--since``/``--until``: parse_time with argparse's error message."""
    try:
        return parse_time(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e


def verify_files(paths: list[str], out: Any = None) -> int:
    out = out or sys.stdout
    results = [verify_bytes(p, read_bytes(p)) for p in paths]
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
    p.add_argument("--since", type=time_arg, metavar="TIME", help="ISO 8601, UTC if no zone")
    p.add_argument("--until", type=time_arg, metavar="TIME", help="ISO 8601, UTC if no zone")
    p.add_argument("--requirement", action="append", metavar="ID", help="repeatable")
    p.add_argument("--event", action="append", choices=EVENTS, help="repeatable")
    p.add_argument(
        "--summary",
        action="store_true",
        help="per requirement: violations, first/last time, mitigations ok/failed",
    )
