"""``safety-supervisor report``: its arguments, and writing the page."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import printable

EXIT_OK, EXIT_FAIL = 0, 1


def add_parser(sub: Any) -> None:
    """Add the ``report`` subcommand to the CLI's subparsers."""
    p = sub.add_parser(
        "report",
        help="one self-contained HTML page about violation logs, for an incident ticket",
        description="Write one HTML file that opens without a network: whether the logs' "
        "hash chain verifies, a zoomable timeline of the inputs with every violation, "
        "mitigation, reset and supervisor event on it, per requirement counts, mitigation "
        "outcomes and latencies, and for each violation why it fired.",
    )
    p.add_argument(
        "logs",
        nargs="+",
        metavar="LOG",
        help="violation logs (.gz too), any order; a recording directory (demo --record "
        "DIR) for its log, and its bags and config unless --bag and --config say otherwise",
    )
    p.add_argument(
        "--bag",
        action="append",
        default=[],
        metavar="BAG",
        help="the run's recording (run --record directory, bag, .mcap, .jsonl): inputs and "
        "why-tree windows from it; repeatable; needs the config",
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="CONFIG",
        help="the config the log was written with (default: a *.yaml beside the log or in "
        "the recording with the log's config_sha256; the path the log names is never opened)",
    )
    p.add_argument(
        "--namespace",
        default=None,
        metavar="NS",
        help="the robot's namespace in the --bag recordings, as replay's --namespace "
        "(default: the config's ros.namespace)",
    )
    p.add_argument("-o", "--output", required=True, metavar="REPORT.html")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def cmd_report(args: argparse.Namespace) -> int:
    # The pipeline and the replay load only when report runs: the CLI imports this
    # module for its parser at every start.
    from supervisor.tools.replay.command import checked_namespace
    from supervisor.tools.report.build import build
    from supervisor.tools.report.page import write

    out = Path(args.output)
    if out.is_dir():
        raise UserError("is a directory; give the HTML file to write", file=str(out))
    namespace = checked_namespace(args.namespace, "report")
    logs, bags, config = _recordings(args.logs, args.bag, args.config)
    # progress is for a person at a terminal: a pipe or the journal gets no \r lines
    quiet = args.quiet or not sys.stderr.isatty()
    rep = build(logs, bags, config, quiet=quiet, namespace=namespace)
    try:
        write(rep, out)
    except OSError as e:
        raise UserError(f"cannot write the report: {e.strerror or e}", file=str(out)) from e
    integ = rep.data.integrity
    n = sum(len(q.violations) for q in rep.requirements)
    chain = "hash chain intact" if integ.ok else f"HASH CHAIN BROKEN: {integ.first_problem}"
    print(printable(f"wrote {out}: {len(rep.data.records)} records, {n} violations; {chain}"))
    return EXIT_OK if integ.ok else EXIT_FAIL


def _recordings(
    paths: list[str], bags: list[str], config: str | None
) -> tuple[list[str], list[str], str | None]:
    """A recording directory among the LOGs (demo --record DIR) stands for its log;
    its bags and config are used unless ``--bag`` and ``--config`` are given."""
    from supervisor.tools.recording import is_recording_dir, recording_dir

    logs: list[str] = []
    found_bags: list[str] = []
    found_config: list[str] = []
    for p in paths:
        if not is_recording_dir(p):
            logs.append(p)
            continue
        rec = recording_dir(p, log=True)
        logs += [str(f) for f in rec.logs]
        found_bags += [str(rec.path)] if rec.bags else []
        found_config += [str(rec.config)] if rec.config is not None else []
    if config is None and len(found_config) == 1:
        config = found_config[0]
    return logs, bags or found_bags, config
