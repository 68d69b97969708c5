"""``safety-supervisor replay``: its arguments, and running it.

One config over recordings (records in the violation log's schema), or two
(``--compare``): per requirement, the violations only one of them reports and
how much earlier or later the first detection comes (docs/reference/commands.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from monitors.errors import UserError

EXIT_OK, EXIT_FAIL = 0, 1


def add_parser(sub: Any) -> None:
    """Add the ``replay`` subcommand to the CLI's subparsers."""
    p = sub.add_parser(
        "replay",
        help="run a config's monitor and policies over recorded bags or traces",
        description="Replay rosbag2 bags (sqlite3 or MCAP), the daemon's own recordings "
        "(run --record) and JSON-lines traces through the config's monitor, step policy, "
        "stale rules and mitigation policies, on the recorded receive times. Mitigations "
        "are not executed: they are recorded with dry_run: true.",
    )
    p.add_argument("config")
    p.add_argument("bags", nargs="+", metavar="BAG", help="bag directories, .mcap/.db3, .jsonl")
    p.add_argument("-o", "--output", default=None, metavar="OUT.jsonl", help="write the records")
    p.add_argument(
        "--compare",
        default=None,
        metavar="OTHER_CONFIG",
        help="also replay OTHER_CONFIG and report where their violations differ",
    )
    p.add_argument("--json", action="store_true", help="the summary as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument(
        "--exact",
        action="store_true",
        help="every message through the core one by one, no bulk stepping (same records, slower)",
    )


def cmd_replay(args: argparse.Namespace) -> int:
    # The pipeline, rosbags and numpy load only when replay runs: the CLI imports
    # this module for its parser at every start.
    from supervisor.tools.replay.session import compare, replay_files

    progress = None if args.quiet or args.json else _progress
    if args.compare:
        if args.output:
            raise UserError("-o writes one config's records; give it without --compare")
        result = compare(
            Path(args.config), Path(args.compare), _paths(args.bags), progress, fast=not args.exact
        )
        _show(result, args.json, _compare_lines)
        return EXIT_FAIL if result.get("error") else EXIT_OK
    result = replay_files(
        Path(args.config),
        _paths(args.bags),
        Path(args.output) if args.output else None,
        progress,
        fast=not args.exact,
    )
    _show(result, args.json, _summary_lines)
    return EXIT_FAIL if result.get("error") else EXIT_OK


def _paths(names: list[str]) -> list[Path]:
    paths = [Path(n) for n in names]
    for p in paths:
        if not p.exists():
            raise UserError("no such bag or trace", file=str(p))
    return paths


def _progress(done: int, total: int | None) -> None:
    text = f"{done:,} messages" + (f" of {total:,} ({100 * done / total:.0f} %)" if total else "")
    print(f"\rreplay: {text}", end="", file=sys.stderr, flush=True)


def _show(
    result: dict[str, Any], as_json: bool, lines: Callable[[dict[str, Any]], list[str]]
) -> None:
    if as_json:
        print(json.dumps(result, sort_keys=True))
    else:
        if sys.stderr.isatty():
            print(file=sys.stderr)
        for line in lines(result):
            print(line)
    if result.get("error"):
        print(f"safety-supervisor: {result['error']}", file=sys.stderr, flush=True)


def _summary_lines(r: dict[str, Any]) -> list[str]:
    out = [
        f"replayed {r['messages']:,} messages, {r['ticks']:,} ticks, "
        f"{r['seconds_recorded']:.3f} s of recording in {r['seconds']:.2f} s "
        f"({r['rate']:,.0f} messages/s)"
    ]
    out += r["notes"]
    width = max([len(q["id"]) for q in r["requirements"]] + [11])
    out.append(f"{'requirement':<{width}}  violations  first tick  first at (s)")
    for q in r["requirements"]:
        first = "-" if q["first_tick"] is None else str(q["first_tick"])
        at = "-" if q["first_s"] is None else f"{q['first_s']:.3f}"
        out.append(f"{q['id']:<{width}}  {q['violations']:>10}  {first:>10}  {at:>12}")
    if r.get("output"):
        out.append(f"records: {r['output']}")
    return out


def _compare_lines(r: dict[str, Any]) -> list[str]:
    a, b = r["configs"]
    out = [f"A = {a}", f"B = {b}", f"over {r['messages']:,} messages, {r['ticks']:,} ticks"]
    out += r["notes"]
    width = max([len(q["id"]) for q in r["requirements"]] + [11])
    out.append(
        f"{'requirement':<{width}}  {'A':>6}  {'B':>6}  {'only A':>6}  {'only B':>6}  first detection"
    )
    for q in r["requirements"]:
        out.append(
            f"{q['id']:<{width}}  {_n(q['a'])}  {_n(q['b'])}  {len(q['only_a']):>6}  "
            f"{len(q['only_b']):>6}  {q['first']}"
        )
    return out


def _n(v: int | None) -> str:
    return f"{'-' if v is None else v:>6}"
