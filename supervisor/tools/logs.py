"""``safety-supervisor logs``: filter, summarize and verify violation logs.

The format and its hash chain are described in :mod:`mitigations.violationlog.format`;
reading and verification live in :mod:`mitigations.violationlog.reader`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from mitigations.violationlog.format import EVENTS, details
from mitigations.violationlog.reader import (
    check_seq_gap,
    iter_records,
    parse_time,
    read_bytes,
    verify_bytes,
)


def time_arg(text: str) -> Any:
    """``--since``/``--until``: parse_time with argparse's error message."""
    try:
        return parse_time(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e


def verify_files(paths: list[str], out: Any = None) -> int:
    """Each file's chain and ``seq``, and the links between rotated files."""
    out = out or sys.stdout
    results = [verify_bytes(p, read_bytes(p)) for p in paths]
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
    for r in results:
        for w in r.warnings:
            print(w, file=out)
        for e in r.errors:
            print(e, file=out)
        if r.broken:
            status = 1
            continue
        lost = f", {r.lost} records lost and accounted for (records_lost)" if r.lost else ""
        if r.missing:
            status = 1
            print(
                f"{r.path}: {r.records} records{lost}, {r.missing} records MISSING "
                "(the hash chain itself is unbroken)",
                file=out,
            )
        else:
            print(f"{r.path}: {r.records} records, chain intact{lost}", file=out)
        for text in linked.get(r.path, []):
            print(text, file=out)
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
        help="check the hash chain and the records' seq; exit 1 at a broken line or missing records",
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
