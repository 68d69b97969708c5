"""``safety-supervisor inject``: its arguments, and running it."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from monitors.errors import UserError
from supervisor.tools.inject.errors import InjectError

EXIT_FAIL = 1


def add_parser(sub: Any) -> None:
    """Add the ``inject`` subcommand to the CLI's subparsers."""
    p = sub.add_parser(
        "inject",
        help="publish a computed state that violates one requirement and only it",
        description="Compute (z3) a short trace that violates REQ while every other "
        "requirement holds, and publish it on the configured topics for a running "
        "supervisor. Stop the robot's own controller first: it publishes on the same topics.",
    )
    p.add_argument("config")
    p.add_argument("requirement", nargs="?", metavar="REQ")
    p.add_argument("--dry-run", action="store_true", help="compute and print only (no ROS)")
    p.add_argument(
        "--all",
        action="store_true",
        help="inject every requirement in turn and compare with the supervisor's log",
    )
    p.add_argument(
        "--log", default=None, metavar="FILE", help="--all: the supervisor's violation log"
    )
    p.add_argument(
        "--wait-s",
        type=float,
        default=15.0,
        metavar="S",
        help="how long to wait for the supervisor's subscriptions (default 15)",
    )
    p.add_argument(
        "--gap-ms", type=float, default=20.0, help="before the trigger / between messages (20)"
    )
    p.add_argument("--tick-ms", type=float, default=50.0, help="between injected ticks (50)")
    p.add_argument(
        "--hold-s",
        type=float,
        default=0.5,
        help="nominal state after each injection, for reset policies (0.5)",
    )
    p.set_defaults(inject_parser=p)


def cmd_inject(args: argparse.Namespace) -> int:
    """REQ or --all (not both: a usage error), then the run; its failures are one line."""
    parser = getattr(args, "inject_parser", None)
    if args.all == bool(args.requirement):
        msg = "give either REQ or --all" if not args.all else "give REQ or --all, not both"
        if parser is not None:
            parser.error(msg)  # exits 2 (usage)
        raise UserError(msg)
    # z3, the config pipeline and ROS load only when inject runs: the CLI imports
    # this module for its parser at every start, and must stay quick
    from supervisor.tools.inject.session import run_inject

    try:
        return run_inject(args)
    except InjectError as e:
        print(f"safety-supervisor inject: {e}", file=sys.stderr, flush=True)
        return EXIT_FAIL
