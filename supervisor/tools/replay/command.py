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
from supervisor.progress import Line

EXIT_OK, EXIT_FAIL = 0, 1


class _Intermixed(argparse.ArgumentParser):
    """replay's parser: BAGs may come after options (``replay CONFIG --compare OTHER
    BAG``) though none is required (``replay DIR``), which argparse parses only
    intermixed: a ``*`` positional otherwise takes nothing before the first option."""

    _inside = False

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        if self._inside:  # parse_known_intermixed_args calls back here
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


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
    p.__class__ = _Intermixed  # subparsers make every parser of one class
    p.add_argument(
        "config",
        help="the config; or a recording directory (demo --record DIR): its config and bags",
    )
    p.add_argument(
        "bags",
        nargs="*",
        metavar="BAG",
        help="bag directories, .mcap/.db3, .jsonl (none: CONFIG is a recording directory)",
    )
    p.add_argument("-o", "--output", default=None, metavar="OUT.jsonl", help="write the records")
    p.add_argument(
        "--compare",
        default=None,
        metavar="OTHER_CONFIG",
        help="also replay OTHER_CONFIG and report where their violations differ",
    )
    p.add_argument(
        "--namespace",
        default=None,
        metavar="NS",
        help="the robot's namespace in the bag: /robot1/scan is the config's /scan "
        "(default: the config's ros.namespace)",
    )
    p.add_argument(
        "--require-all-topics",
        action="store_true",
        help="a config topic in none of the recordings is an error (exit 1), not a warning",
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
    from supervisor.tools.recording import is_recording_dir, recording_dir
    from supervisor.tools.replay.session import compare, replay_files

    if is_recording_dir(args.config):
        rec = recording_dir(args.config, config=True, bag=not args.bags)
        assert rec.config is not None
        args.config, args.bags = str(rec.config), args.bags or [str(rec.path)]
    elif not args.bags:
        print(
            "safety-supervisor replay: error: give the recordings (BAG ...) after the config, "
            "or a recording directory instead of both",
            file=sys.stderr,
        )
        return 2  # a usage error, as argparse's
    namespace = checked_namespace(args.namespace, "replay")
    # progress is for a person at a terminal: never in a log file or a CI's output
    line = Line("replay", on=False if args.quiet or args.json else None)
    progress = line.messages if line.on else None
    try:
        if args.compare:
            if args.output:
                raise UserError("-o writes one config's records; give it without --compare")
            result = compare(
                Path(args.config),
                Path(args.compare),
                _paths(args.bags),
                progress,
                fast=not args.exact,
                namespace=namespace,
            )
            lines = _compare_lines
        else:
            result = replay_files(
                Path(args.config),
                _paths(args.bags),
                Path(args.output) if args.output else None,
                progress,
                fast=not args.exact,
                namespace=namespace,
                require_all_topics=args.require_all_topics,
            )
            lines = _summary_lines
    finally:
        line.end()  # whatever comes next starts on its own line
    _show(result, args.json, lines)
    return EXIT_FAIL if result.get("error") else EXIT_OK


def checked_namespace(given: str | None, command: str) -> str | None:
    """``--namespace`` of replay or report, checked as the config checks
    ``ros.namespace``."""
    if given is None:
        return None
    from supervisor.config.ros import NAMESPACE

    if not NAMESPACE.fullmatch(given):
        raise UserError(
            f"--namespace {given!r} is not a ROS namespace "
            "(absolute, like /robot1 or /fleet/robot1)",
            file=command,
        )
    return given


def _paths(names: list[str]) -> list[Path]:
    paths = [Path(n) for n in names]
    for p in paths:
        if not p.exists():
            raise UserError("no such bag or trace", file=str(p))
    return paths


def _show(
    result: dict[str, Any], as_json: bool, lines: Callable[[dict[str, Any]], list[str]]
) -> None:
    if as_json:
        print(json.dumps(result, sort_keys=True))
    else:
        for line in lines(result):
            print(line)
        # last, after the table, where a person reading the summary ends: a
        # replay that judged only part of its config must not look complete
        for warning in result.get("missing", []):
            print(warning)
    sys.stdout.flush()
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
    # predictions beside the violations, when a requirement predicts
    more = "  predictions  expired  predicted  min lead (ms)" if r.get("predicting") else ""
    out.append(f"{'requirement':<{width}}  violations  first tick  first at (s){more}")
    for q in r["requirements"]:
        first = "-" if q["first_tick"] is None else str(q["first_tick"])
        at = "-" if q["first_s"] is None else f"{q['first_s']:.3f}"
        line = f"{q['id']:<{width}}  {q['violations']:>10}  {first:>10}  {at:>12}"
        if more:
            lead = "-" if q["min_lead_ms"] is None else f"{q['min_lead_ms']:.0f}"
            line += f"  {q['predictions']:>11}  {q['expired']:>7}  {q['predicted']:>9}  {lead:>13}"
        out.append(line)
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
