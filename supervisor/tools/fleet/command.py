"""``safety-supervisor fleet replay``: its arguments, and running it: the archive
listed, the finished bags left out, the rest run by an engine, each result written as
it comes, a progress line on a terminal and one summary line
(docs/reference/commands.md, "fleet replay")."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from monitors.errors import UserError
from supervisor.progress import Line
from supervisor.tools.fleet.report import add_parser as add_report_parser

if TYPE_CHECKING:  # the engines import pyarrow: only once a command needs them
    from supervisor.tools.fleet.engine import Engine

EXIT_OK, EXIT_FAIL, EXIT_INTERRUPTED = 0, 1, 130
MAX_JOBS = 512


def add_parser(sub: Any) -> None:
    """Add ``fleet`` and its ``replay`` to the CLI's subparsers."""
    p = sub.add_parser(
        "fleet",
        help="replay a config over a fleet's archive of bags into a Parquet dataset, "
        "and report on it",
        description="Requirements regression over recorded fleet data.",
    )
    fsub = p.add_subparsers(dest="fleet_command", required=True, metavar="COMMAND")
    r = fsub.add_parser(
        "replay",
        help="replay every bag of an archive, one task per bag, into a Parquet dataset",
        description="Replay every bag under ARCHIVE (directories or globs of rosbag2 "
        "bags, MCAP or sqlite3, and run --record recordings) with CONFIG, as replay does, "
        "in a pool of worker processes, and write each violation as a row of a Parquet "
        "dataset partitioned by robot and date, with a table of the bags read, skipped, "
        "damaged or failed. A bag already finished with the same config is not read "
        "again. Exit status 1 when any bag failed or was damaged.",
    )
    r.add_argument("config", help="the config")
    r.add_argument("archives", nargs="+", metavar="ARCHIVE", help="directories, bags or globs")
    r.add_argument("-o", "--output", required=True, metavar="DATASET", help="the dataset directory")
    r.add_argument(
        "--jobs", type=_jobs, default=None, metavar="N", help="worker processes (default: CPUs)"
    )
    r.add_argument(
        "--robot-from",
        default=None,
        metavar="RULE",
        help="the robot's name from the bag's path: a pattern with {robot}, * and ** "
        "(default: the directory under the archive root)",
    )
    r.add_argument(
        "--compare",
        default=None,
        metavar="OTHER_CONFIG",
        help="also replay OTHER_CONFIG and print, per requirement and robot, the violations "
        "only one of them reports",
    )
    r.add_argument(
        "--namespace",
        default=None,
        metavar="NS",
        help="the robots' namespace in the bags (default: the config's ros.namespace)",
    )
    r.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="what runs the tasks: a process pool on this machine (local, the default) or "
        "a Ray cluster (ray: the fleet extra; a local cluster of --jobs CPUs without --address)",
    )
    r.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="with --engine ray: a running cluster's address (HOST:PORT, as ray start prints it); "
        "its workers read the bags and the config at the paths given here",
    )
    r.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    add_report_parser(fsub)


def _jobs(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= MAX_JOBS:
        raise argparse.ArgumentTypeError(
            f"not a number of processes from 1 to {MAX_JOBS}: {text!r}"
        )
    return n


def cmd_fleet(args: argparse.Namespace) -> int:
    if args.fleet_command != "replay":
        return _fleet(args)
    from supervisor.tools.stopping import sigterm_as_interrupt

    # what an interrupted run did, said once its processes are all stopped (a second
    # signal during the stop is raised again after it, ``uninterrupted``)
    said: list[str] = []
    with sigterm_as_interrupt():
        try:
            rc = _fleet_replay(args, said)
        except KeyboardInterrupt:
            rc = EXIT_INTERRUPTED
    if rc == EXIT_INTERRUPTED:
        line = said[0] if said else "fleet replay: interrupted before any bag was replayed"
        print(line, file=sys.stderr, flush=True)
    return rc


def _fleet_replay(args: argparse.Namespace, said: list[str]) -> int:
    if args.engine != "local":
        return _fleet(args, said)
    from supervisor.tools.fleet import server
    from supervisor.tools.stopping import uninterrupted

    server.serve()  # first: its imports beside this process's (server.py)
    try:
        return _fleet(args, said)
    finally:
        with uninterrupted():
            server.stop()  # whatever stopped the run: nothing outlives it


def _fleet(args: argparse.Namespace, said: list[str] | None = None) -> int:
    try:
        import pyarrow  # noqa: F401 - only to say what is missing, once
    except ImportError:
        raise UserError(
            "fleet needs pyarrow, which the base install leaves out",
            file="fleet",
            hint="pip install 'safety-supervisor[fleet]'",
        ) from None
    if args.fleet_command == "report":
        from supervisor.tools.fleet.report import cmd_report

        return cmd_report(args)
    from supervisor.cache import Cache
    from supervisor.tools.fleet.dataset import Dataset
    from supervisor.tools.fleet.engine import LocalEngine, RayEngine, import_ray
    from supervisor.tools.replay.command import checked_namespace

    # the run's summary goes here: while on a Ray cluster, sys.stdout is Ray's notes'
    # (engine.py, ``RayNotes``)
    out = sys.stdout
    if args.address is not None and args.engine != "ray":
        raise UserError("--address is the Ray cluster's: give --engine ray", file="fleet replay")
    if args.engine == "ray":
        import_ray()  # missing: one line with the fix, before any config is compiled
    # made first: an unreachable cluster is said before anything is compiled or read
    engine = (
        RayEngine(args.jobs, args.address)
        if args.engine == "ray"
        # the pool's workers write their bags' files: the parent only coordinates
        else LocalEngine(args.jobs, Path(args.output))
    )
    namespace = checked_namespace(args.namespace, "fleet replay")
    # the start-up cache the local workers share, its warnings said here once: they keep
    # quiet (warm.py)
    if (cache := Cache.open_user()) is not None:
        cache.close()
    # what an earlier run finished, read (nothing made yet) before the workers start:
    # they take it at their start, while this process compiles the config
    # (a power loss's damaged rows are left out of it: those bags run again)
    done = Dataset(Path(args.output), make=False).done()
    # by content hash too: the same bag under another path is hashed, not replayed
    # (a task's key is its config's hash and its content: other configs' never match)
    done_contents = {f"{s}:{h}" for s, h in done.contents}
    try:
        return _replay(args, engine, namespace, done, done_contents, out, said)
    finally:
        engine.close()  # started, and not taken by a run stopped by an error


def _replay(
    args: argparse.Namespace,
    engine: Engine,
    namespace: str | None,
    done: Any,
    done_contents: set[str],
    out: TextIO,
    said: list[str] | None = None,
) -> int:
    from supervisor.tools.fleet.archive import copies, list_archive
    from supervisor.tools.fleet.dataset import Dataset, Writers, only_writer
    from supervisor.tools.fleet.task import BagResult, BagTask, copy_of, vouched
    from supervisor.tools.stopping import uninterrupted

    configs = [Path(args.config).absolute()]
    if args.compare:
        configs.append(Path(args.compare).absolute())
    bags = list_archive(args.archives, args.robot_from)
    # no more workers than the tasks can be (a few bags, --jobs 16: not 16 spawned);
    # each compiles the configs as it starts (either engine)
    engine.start(done_contents, len(bags) * len(configs), tuple(map(str, configs)))
    shas = _config_shas(configs, engine)
    output = Path(args.output)
    dataset = Dataset(output)  # made once the configs compiled, not for a bad one
    held = contextlib.ExitStack()  # let go once the pool has stopped, in the finally
    if removed := held.enter_context(only_writer(output)):
        print(
            f"fleet replay: {output}: removed {removed} unfinished "
            f"file{'s' if removed != 1 else ''} of an interrupted run",
            file=sys.stderr,
            flush=True,
        )
    # removed by the writer only (only_writer), as they are now: read before the lock
    damaged = dataset.still_damaged(done)
    if (damage := damaged.damage()) is not None:
        dataset.drop(damaged.damaged)  # its error said alone
        print(damage, file=sys.stderr, flush=True)
    tasks: list[BagTask] = []
    where: dict[str, tuple[str, str, int]] = {}  # bag -> robot, fingerprint, size
    # results known before any task: a bag without its robot, a copy of another bag
    settled: list[BagResult] = []
    # among the bags to replay: a copy of a bag done before is the worker's to skip
    # (``done_contents``), once it has hashed it
    copied = copies(
        [b for b in bags if any((s, b.fingerprint) not in done.fingerprints for s in shas)]
    )
    copied_results: list[BagResult] = []
    already = 0
    for bag in bags:
        for c, sha in zip(configs, shas, strict=True):
            if (sha, bag.fingerprint) in done.fingerprints:
                already += 1
                continue
            task = BagTask(bag.path, bag.robot or "", str(c), sha, namespace, bag.fingerprint)
            if bag.robot is None:
                settled.append(BagResult(task, "failed", bag.robot_error or ""))
            elif bag.path in copied:
                copied_results.append(copy_of(task, *copied[bag.path]))
            else:
                tasks.append(task)
        where[bag.path] = (bag.robot or "", bag.fingerprint, bag.size)
    # a copy whose first is replayed in this run waits for the first's result (its
    # content may have changed since it was hashed: ``vouched``)
    tasked = {(t.bag, t.config_sha256) for t in tasks}
    waiting: dict[tuple[str, str], list[BagResult]] = {}
    for r in copied_results:
        first = (copied[r.task.bag][0], r.task.config_sha256)
        if first in tasked:
            waiting.setdefault(first, []).append(r)
        else:
            settled.append(r)
    line = Line("fleet", on=False if args.quiet else None)
    total = len(settled) + sum(map(len, waiting.values())) + len(tasks)
    progress = Progress(total, sum(where[t.bag][2] for t in tasks), line)
    counts = {"read": 0, "skipped": 0, "damaged": 0, "failed": 0}
    results = engine.results(tasks, done_contents)
    interrupted = False
    try:
        with Writers(dataset) as writers:

            def count(written: list[BagResult]) -> None:  # once its files are written
                for w in written:
                    counts[w.status] += 1
                    progress.add(w, where[w.task.bag][2])
                    progress.draw()

            def take(result: BagResult) -> None:
                if result.written is not None:  # its worker wrote its files (LocalEngine)
                    count([result])
                    return
                robot, fp, _size = where[result.task.bag]
                count(writers.put(result, robot, fp))

            for result in _chain(settled, results):
                take(result)
                for copy in waiting.pop((result.task.bag, result.task.config_sha256), []):
                    take(vouched(copy, result))
            count(writers.drain())
        # every bag's files durable, the pool's (a dead worker's too) and the writers':
        # the groups' syncs leave the last rows to this one (dataset.py)
        dataset.sync()
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (cmd_fleet): the pool is stopped below
        interrupted = True
    finally:
        # A second signal during the stop and the count waits for the line (it cut
        # them short, and the command said no bag was done with rows in the dataset).
        with uninterrupted():
            results.close()  # an error stops the pool too (engine.py)
            progress.end()
            held.close()
            if interrupted and said is not None:
                said.append(_interrupted_line(dataset, where, shas, done, total, already))
    if interrupted:
        return EXIT_INTERRUPTED
    print(progress.summary(counts, already, Path(args.output)), file=out, flush=True)
    if args.compare:
        _compare(dataset, shas, {fp for _, fp, _ in where.values()}, out)
    # a damaged bag was judged only up to its damage: as replay, that is not a success
    return EXIT_FAIL if counts["failed"] or counts["damaged"] else EXIT_OK


def _interrupted_line(
    dataset: Any,
    where: dict[str, tuple[str, str, int]],
    shas: list[str],
    done: Any,
    total: int,
    already: int,
) -> str:
    """What an interrupted run leaves.  The rows written stay, and the next run takes
    them as done.  They are counted in the dataset: a pool's worker writes each bag's
    row as it ends, and its results reach this process only once its call's bags are
    all done."""
    written = sum(
        dataset.row_id(sha, fp) is not None
        for _robot, fp, _size in where.values()
        for sha in shas
        if (sha, fp) not in done.fingerprints
    )
    return (
        f"fleet replay: interrupted: {written:,} of {total:,} bags done, {already:,} done "
        f"before; their rows in {dataset.root}: the same command replays the rest"
    )


def _config_shas(configs: list[Path], engine: Engine) -> list[str]:
    """Each config's identity (``ConfigSource.identity``: its bytes' SHA-256, with the
    files it imports), once it is known to compile: a bad config is one error before
    any bag.  The pool's first worker compiles them for its tasks anyway and answers
    with them, so this process does not (0.5 s of its CPU per run, docs/BENCHMARKS.md,
    "Fleet"); so does Ray's first worker.  Without one (no bags, or its worker died)
    they are compiled here.  ``--compare`` of a config with itself (the same bytes and
    imports) is refused: every row is keyed by this hash, so each bag would be replayed
    twice into the same files and compared with itself."""
    shas = engine.checked()
    if shas is None:
        from supervisor.tools.replay.session import loaded

        shas = []
        for c in configs:
            with loaded(c) as session:  # its error, if any, is said here
                shas.append(session.config.identity)
    if len(shas) == 2 and shas[0] == shas[1]:
        raise UserError(
            f"--compare: the same bytes as {configs[0]}, importing the same files: "
            "nothing to compare",
            file=str(configs[1]),
            hint="give the changed config",
        )
    return shas


def _chain(first: list[Any], rest: Any) -> Any:
    yield from first
    yield from rest


def _compare(dataset: Any, shas: list[str], fingerprints: set[str], out: TextIO) -> None:
    import pyarrow.compute as pc

    from supervisor.tools.fleet.compare import compare, lines

    bags = dataset.bags()
    mine = bags.filter(pc.is_in(bags["fingerprint"], _strings(fingerprints)))
    contents = {h for h in mine.column("bag_sha256").to_pylist() if h}
    print(f"A = config {shas[0][:12]}, B = config {shas[1][:12]}", file=out)
    for line in lines(compare(dataset.violations(), shas[0], shas[1], contents)):
        print(line, file=out)
    out.flush()


def _strings(values: set[str]) -> Any:
    import pyarrow as pa

    return pa.array(sorted(values), pa.string())


class Progress:
    """Bags done and failed, messages per second and the time left (from the bytes
    of the bags still to read), as one ``\\r`` line on stderr."""

    def __init__(self, bags: int, size: int, line: Line) -> None:
        self.bags, self.size, self.line = bags, size, line
        self.done = self.failed = self.messages = self.read_bytes = 0
        self.t0 = time.monotonic()

    def add(self, result: Any, size: int) -> None:
        self.done += 1
        self.failed += result.status == "failed"
        self.messages += result.messages
        self.read_bytes += size

    def rate(self) -> float:
        elapsed = time.monotonic() - self.t0
        return self.messages / elapsed if elapsed > 0 else 0.0

    def draw(self) -> None:
        elapsed = time.monotonic() - self.t0
        left = "-"
        if self.read_bytes and self.size > self.read_bytes:
            s = int(elapsed * (self.size - self.read_bytes) / self.read_bytes)
            left = f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"
        elif self.done == self.bags:
            left = "0:00:00"
        self.line.show(
            f"{self.done:,}/{self.bags:,} bags, {self.failed:,} failed, "
            f"{self.rate():,.0f} messages/s, ETA {left}"
        )

    def end(self) -> None:
        self.line.end()

    def summary(self, counts: dict[str, int], already: int, output: Path) -> str:
        elapsed = time.monotonic() - self.t0
        parts = ", ".join(f"{n:,} {status}" for status, n in counts.items())
        return (
            f"fleet replay: {self.done:,} bags ({parts}), {already:,} done before; "
            f"{self.messages:,} messages in {elapsed:.1f} s ({self.rate():,.0f} messages/s); "
            f"dataset {output}"
        )
