"""``safety-supervisor fleet report``: its arguments, the page written, and with
``--bags DIR`` each listed bag's incident page made by ``report``'s own machinery
(docs/reference/fleet.md, "fleet report").

A bag's page is named from a hash of its content and config hashes, never from its
path, and is made only when the bag on disk still has the content hash the dataset
recorded: the dataset names the bag, but does not choose what is read or written.
"""

from __future__ import annotations

import argparse
import hashlib
import os
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.progress import Line

EXIT_OK = 0


def add_parser(fsub: Any) -> None:
    """Add ``report`` to ``fleet``'s subparsers."""
    r = fsub.add_parser(
        "report",
        help="one self-contained HTML page about a fleet dataset",
        description="Write one HTML file that opens without a network, about a dataset "
        "fleet replay wrote: per requirement, its violations per robot and day as a heat "
        "map; the bags read, skipped, damaged or failed with their reasons; against a "
        "baseline, the violations new and lost per requirement and robot. Lists are "
        "capped, and what is left out is counted.",
    )
    r.add_argument("dataset", metavar="DATASET", help="the directory fleet replay -o wrote")
    r.add_argument("-o", "--output", required=True, metavar="FLEET.html", help="the page to write")
    r.add_argument(
        "--baseline",
        default=None,
        metavar="OTHER",
        help="compare with another dataset (one config each), or, for a dataset of "
        "fleet replay --compare, the hash (8+ hex digits) of its baseline config",
    )
    r.add_argument(
        "--bags",
        default=None,
        metavar="DIR",
        help="also write into DIR the incident page (report) of each listed bag, "
        "linked from the fleet page; needs the configs (--config)",
    )
    r.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="CONFIG",
        help="a config the dataset was replayed with (matched by its hash), for --bags; repeatable",
    )
    r.add_argument(
        "--namespace",
        default=None,
        metavar="NS",
        help="the robots' namespace in the bags, as fleet replay's (default: the config's)",
    )
    r.add_argument("--quiet", action="store_true", help="no progress on stderr")


def cmd_report(args: argparse.Namespace) -> int:
    from supervisor.tools.fleet.page import render
    from supervisor.tools.fleet.summary import summarize
    from supervisor.tools.replay.command import checked_namespace

    out = Path(args.output)
    if out.is_dir():
        raise UserError("is a directory; give the HTML file to write", file=str(out))
    if args.config and args.bags is None:
        raise UserError("--config is for --bags: give the directory of the bags' pages")
    namespace = checked_namespace(args.namespace, "fleet report")
    configs = _configs(args.config)
    show = Line("fleet report", on=False if args.quiet else None)
    summary = summarize(Path(args.dataset), args.baseline)
    notes: list[str] = []
    pages: dict[tuple[str, str], str] = {}
    if args.bags is not None:
        pages, notes = _bag_pages(summary, Path(args.bags), configs, namespace, out, show)

    def link(v: Any) -> str | None:
        return pages.get((v.config_sha256, v.bag_sha256))

    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(render(summary, link, notes), encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot write the page: {e.strerror or e}", file=str(out)) from None
    print(
        printable(
            f"wrote {out}: {summary.violations:,} violations, {len(summary.maps)} heat map(s), "
            f"{sum(summary.statuses.values()):,} bags, {len(set(pages.values()))} bag page(s)"
        ),
        flush=True,
    )
    return EXIT_OK


def _configs(paths: list[str]) -> dict[str, Path]:
    """config_sha256 -> the config file, for the bags' pages."""
    from supervisor.config import load_config

    out = {}
    for p in paths:
        path = Path(p).absolute()
        out[load_config(path).identity] = path  # as fleet replay keyed its rows
    return out


def page_name(config_sha256: str, bag_sha256: str) -> str:
    """A bag's page: from hashes only, so no dataset text reaches a path."""
    return hashlib.sha256(f"{config_sha256}:{bag_sha256}".encode()).hexdigest()[:32] + ".html"


def _bag_pages(
    summary: Any,
    where: Path,
    configs: dict[str, Path],
    namespace: str | None,
    out: Path,
    show: Line,
) -> tuple[dict[tuple[str, str], str], list[str]]:
    """The incident page of every bag the fleet page lists: (config, bag hash) ->
    its URL relative to the fleet page; and a note for each bag without one."""
    from urllib.request import pathname2url

    import pyarrow as pa
    import pyarrow.compute as pc

    from supervisor.tools.fleet.archive import content_hash, fingerprint

    wanted: dict[tuple[str, str], str] = {}
    listed = [v for m in summary.maps for v in m.listed]
    if summary.changes is not None:
        for _, vs in (*summary.changes.new.values(), *summary.changes.lost.values()):
            listed += vs
    for v in listed:
        wanted.setdefault((v.config_sha256, v.bag_sha256), v.bag)
    # each listed bag's fingerprint as its row recorded it (its path, its files' names,
    # sizes and times): a path whose files are not those is never read, so a dataset
    # naming some other path (a disk's worth of bytes, a directory) chooses no reading
    ids = summary.identities
    rows = ids.filter(pc.is_in(ids["bag_sha256"], pa.array(sorted({d for _, d in wanted}))))
    recorded = {(r["config_sha256"], r["bag_sha256"], r["bag"]): r["fingerprint"]
                for r in rows.to_pylist()}  # fmt: skip
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(
            f"cannot make the pages' directory: {e.strerror or e}", file=str(where)
        ) from None
    base = os.path.relpath(where.absolute(), out.absolute().parent)
    pages: dict[tuple[str, str], str] = {}
    notes: list[str] = []
    no_config: set[str] = set()
    for n, ((sha, digest), bag) in enumerate(sorted(wanted.items()), 1):
        show.show(f"bag page {n}/{len(wanted)}")
        if sha not in configs:
            no_config.add(sha)
            continue
        try:
            known = fingerprint(Path(bag))[1] == recorded.get((sha, digest, bag))
            same = known and content_hash(Path(bag)) == digest
        except OSError as e:
            notes.append(f"no page for {bag}: {e.strerror or e}")
            continue
        if not known:
            notes.append(
                f"no page for {bag}: its files are not the ones replayed "
                "(their names, sizes or times changed, or the dataset has no row for it)"
            )
            continue
        if not same:
            notes.append(f"no page for {bag}: its content is not the one replayed")
            continue
        name = page_name(sha, digest)
        problem = _one_page(configs[sha], Path(bag), where / name, namespace)
        if problem is not None:
            notes.append(f"no page for {bag}: {problem}")
            continue
        pages[(sha, digest)] = pathname2url(os.path.join(base, name))
    show.end()
    notes += [
        f"no bag pages for config {sha[:12]}: give it with --config" for sha in sorted(no_config)
    ]
    return pages, [printable(n) for n in notes]


def _one_page(config: Path, bag: Path, page: Path, namespace: str | None) -> str | None:
    """Replay the bag into a log beside its page, then ``report`` it; the reason when
    it cannot be made."""
    from supervisor.tools.replay.session import run_one
    from supervisor.tools.report.build import build
    from supervisor.tools.report.page import write

    log = page.with_suffix(".jsonl")
    try:
        log.unlink(missing_ok=True)  # a page made again: its log anew, not appended to
        run_one(config, [bag], log, None, namespace=namespace)
        write(build([str(log)], [str(bag)], str(config), quiet=True, namespace=namespace), page)
    except UserError as e:
        return str(e).splitlines()[0] if str(e) else type(e).__name__
    except OSError as e:
        return str(e.strerror or e)
    return None
