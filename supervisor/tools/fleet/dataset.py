"""The result dataset, one bag's files at a time, by ``Dataset.write``:

```
DATASET/violations/robot=R/date=D/K.parquet   one row per violation (task.VIOLATIONS)
DATASET/bags/K.parquet                        the bag's row (BAGS)
```

Who writes: with the local engine, the worker that replayed the bag, before it
reports the bag done (engine.py, ``LocalEngine``), so the parent only coordinates;
with Ray, the parent, as the results come back as Arrow tables (``Writers``).  The
same files in the same order either way (docs/BENCHMARKS.md, "Fleet").

``K`` is a hash of the config's SHA-256 and the bag's fingerprint (archive.py), so a
bag replayed again with the same config overwrites its own files, never adds rows.
The bag's row is written last: a bag with no row is not finished, and its violation
files, if any, are rewritten when it is done again.  Each file is written whole or
not at all (supervisor/files.py).  Hive partitioning, as DuckDB, pandas and polars
read it (``read_parquet('DATASET/violations/**/*.parquet', hive_partitioning=true)``).

Durable in groups (``Commits``): no fsync per file, one ``syncfs`` per group of bags,
between the group's violation files and their rows, so a row is renamed into place
only once its bag's violations are on disk; the rows themselves are made durable by
the next group's sync and by the run's last one (``Dataset.sync``), before its
summary.  A process killed at any point leaves what it renamed readable (the page
cache outlives it): the parent reads a dead worker's rows back (engine.py).  Only a
power loss before a sync can leave a row file empty or cut short: its bag is then
not finished, and the next run says so in one line and replays it (``done``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import stat
import time
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import unquote

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from monitors.errors import UserError
from monitors.untrusted import printable, shown
from supervisor.files import NotRegularFile, open_regular, sync_filesystem, write_whole
from supervisor.tools.fleet import footer
from supervisor.tools.fleet.task import STATUSES, VIOLATIONS, BagResult

BAGS = pa.schema(
    [
        ("bag", pa.string()),
        ("robot", pa.string()),
        ("bag_sha256", pa.string()),
        ("fingerprint", pa.string()),
        ("config_sha256", pa.string()),
        ("messages", pa.int64()),
        ("violations", pa.int64()),
        ("status", pa.string()),
        ("reason", pa.string()),
        ("seconds", pa.float64()),
        ("finished_ts", pa.timestamp("ns", tz="UTC")),
    ]
)


@dataclass(frozen=True)
class Done:
    """What the dataset has finished, per config: bag fingerprints (known without
    reading a bag) and content hashes (a bag's identity)."""

    fingerprints: frozenset[tuple[str, str]]  # (config_sha256, fingerprint)
    contents: frozenset[tuple[str, str]]  # (config_sha256, bag_sha256)
    damaged: tuple[Path, ...] = ()  # row files a power loss left unreadable: not finished

    def damage(self) -> str | None:
        """The one line that says which bags' rows were damaged, or None."""
        if not self.damaged:
            return None
        more = f" (and {len(self.damaged) - 1} more)" if len(self.damaged) > 1 else ""
        return str(
            UserError(
                f"a bag's row is empty or cut short{more}, as a power loss before the "
                "dataset's sync leaves it: removed with its violation files, that bag is "
                "not finished and is replayed",
                file=str(self.damaged[0]),
            )
        )


MAX_ERROR = 300  # characters of a reader's error in a line about a dataset's file
# What one reading of a dataset (fleet report, with its baseline; fleet replay's
# resume) decodes at most: its columns in memory, about 18 million violations.  A
# file of a few KB can hold gigabytes of repeated text (dictionary-encoded), so this
# is checked before each file is decoded (``Budget``, docs/reference/fleet.md).
# A violation decoded takes about 230 bytes with a bag path of 70 characters.
MAX_DECODED_BYTES = 4 * 2**30
BATCH_ROWS = 65_536  # rows of a file decoded at a time, each batch within the budget
# The Parquet encodings fleet replay's files use (pyarrow's defaults): any other, a
# prefix-encoded text that decodes to far more than it stores, is not its file.  The
# footer's list is the file's word (pyarrow decodes each page by its own header); what
# holds against a page that is prefix-encoded all the same is that text is read as
# dictionary codes, which pyarrow does not build from such a page (read_file).
ENCODINGS = frozenset({"PLAIN", "RLE", "RLE_DICTIONARY", "PLAIN_DICTIONARY", "BIT_PACKED"})
# Its codecs (pyarrow's default, snappy, and none).  A page is decompressed whole
# before any of its rows is decoded and counted, and zstd or gzip expand a few KB
# to gigabytes; snappy at most about 21 times (a 3-byte copy of 64 bytes,
# https://github.com/google/snappy/blob/main/format_description.txt), so a file is
# read only if the budget has room for ``EXPANDS`` times the columns it reads of a
# row group, as stored.
CODECS = frozenset({"SNAPPY", "UNCOMPRESSED"})
EXPANDS = 22
# The violations' columns read back (``Dataset.violations``): ``inputs`` stays on disk.
COLUMNS = ["bag", "bag_sha256", "requirement", "tick", "recorded_ts", "config_sha256"]
_READ = pa.schema([VIOLATIONS.field(c) for c in COLUMNS])
KEY = re.compile(r"[0-9a-f]{32}\.parquet")  # the name of a file this dataset writes
# A file write_whole had not renamed yet (supervisor/files.py): ``.K.parquet.XXXX.tmp``.
TEMPORARY = re.compile(r"\.[0-9a-f]{32}\.parquet\.[a-z0-9_]+\.tmp")
# The run's lock on its dataset: hidden, so no reader lists it (``dataset_files``).
LOCK = ".fleet-replay.lock"


class Dataset:
    def __init__(self, root: Path, *, make: bool = True) -> None:
        """``make``: the directory made now (else only read: ``done`` before a run)."""
        try:  # made before any bag is read: a dataset that cannot be written is said first
            if make:
                root.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"cannot make the dataset: {e.strerror or e}", file=str(root)) from None
        self.root = root
        self.bags_dir = root / "bags"
        self.violations_dir = root / "violations"

    def done(self) -> Done:
        """Every bag finished (any status but failed) in an earlier run; and the
        contents replayed: only a row that holds its content's results (``read``,
        ``damaged``) stands for its content.  A copy's ``skipped`` row is written
        before or without its first's (a run stopped between them), so it vouched
        for a content no row held, and the first was skipped for good."""
        fps: set[tuple[str, str]] = set()
        contents: set[tuple[str, str]] = set()
        damaged: list[Path] = []
        table = self.bags(damaged)
        finished = table.filter(pc.not_equal(table["status"], "failed"))
        columns = ["config_sha256", "fingerprint", "bag_sha256", "status"]
        for row in finished.select(columns).to_pylist():
            fps.add((row["config_sha256"], row["fingerprint"]))
            if row["bag_sha256"] and row["status"] in ("read", "damaged"):
                contents.add((row["config_sha256"], row["bag_sha256"]))
        return Done(frozenset(fps), frozenset(contents), tuple(damaged))

    def bags(self, damaged: list[Path] | None = None, budget: Budget | None = None) -> pa.Table:
        """The bags table: one row per bag and config, from the files of
        ``dataset_files`` (anything else in ``bags/`` is one error).  A row file of
        this dataset's naming that a power loss left empty or cut short is added to
        ``damaged`` and left out (its bag is not finished); without ``damaged``
        (``fleet report``) it is one error naming it.  Any other unreadable file is
        an error: not this dataset's.  ``budget``: what the reading may still decode
        (a new ``Budget`` without it)."""
        budget = budget if budget is not None else Budget()
        if not _table_dir(self.bags_dir):
            return BAGS.empty_table()  # nothing finished yet
        tables = []
        for name in dataset_files(self.bags_dir, ()):
            f = Path(name)
            try:
                table = _row_file(f, budget)
            except FileNotFoundError as e:  # taken away while it was listed
                raise UserError(
                    f"not a fleet dataset's bags table ({e.strerror or e})", file=_shown(f)
                ) from None
            if table is not None:
                tables.append(table)
            elif damaged is not None:
                damaged.append(f)
            else:
                raise UserError(
                    "a bag's row is empty or cut short, as a power loss before the dataset's "
                    "sync leaves it",
                    file=_shown(f),
                    hint="run the same fleet replay again: it removes that row and replays its bag",
                )
        return pa.concat_tables(tables) if tables else BAGS.empty_table()

    def still_damaged(self, done: Done) -> Done:
        """``done`` with only the damaged rows that are damaged still: read again by
        the dataset's writer (``only_writer``), since another run may have replayed
        and rewritten a row between ``done`` and the lock (a row's name is its key)."""
        still = []
        for row in done.damaged:
            with contextlib.suppress(FileNotFoundError):  # removed by that other run
                if _row_file(row, Budget()) is None:
                    still.append(row)
        return replace(done, damaged=tuple(still))

    def drop(self, damaged: tuple[Path, ...]) -> None:
        """Each damaged row (``Done.damaged``) taken away with its violation files,
        those first: its bag's key may have changed since (its files touched or
        copied), and the next rows are written under the new key, so what was left
        stayed beside them, each violation two rows, and the damaged row for good."""
        # listed as every reading lists them: a link in them is an error, never
        # followed to remove another directory's files
        names = {row.name for row in damaged}
        listed = (
            dataset_files(self.violations_dir, ("robot", "date"))
            if _table_dir(self.violations_dir)
            else []
        )
        try:
            for f in listed:
                if Path(f).name in names:
                    Path(f).unlink(missing_ok=True)
            for row in damaged:
                row.unlink(missing_ok=True)
        except OSError as e:
            raise UserError(
                f"cannot write the dataset: {e.strerror or e}", file=str(self.root)
            ) from None

    def write(self, result: BagResult, robot: str, fingerprint: str) -> None:
        """One bag's files, durable: a group of one (``Commits``)."""
        commits = Commits(self)
        commits.add(result, robot, fingerprint)
        commits.commit()

    def sync(self) -> None:
        """Every file written to the dataset so far durable, by any process (a dead
        worker's too): the run's last sync, before its summary."""
        try:
            sync_filesystem(self.root)
        except OSError as e:
            raise UserError(
                f"cannot write the dataset: {e.strerror or e}", file=str(self.root)
            ) from None

    def row(self, config_sha256: str, fingerprint: str) -> dict[str, Any] | None:
        """This bag's row under this config (``BAGS``' columns, ``finished_ts`` in ns
        since the epoch), or None: the bag is not finished (no row, or one a power
        loss damaged, ``bags``)."""
        path = self._row_path(config_sha256, fingerprint)
        try:
            table = _row_file(path, Budget())
        except FileNotFoundError:
            return None
        if table is None:
            return None
        at = table.schema.get_field_index("finished_ts")
        rows = table.set_column(at, "finished_ts", table["finished_ts"].cast(pa.int64()))
        return rows.to_pylist()[0] if rows.num_rows == 1 else None

    def row_id(self, config_sha256: str, fingerprint: str) -> tuple[int, int] | None:
        """Which file this bag's row is now (device, inode), or None: none.  A row is
        written whole to a new file renamed over the old (``_write``), so another id
        is another write, whatever the clock said when it was made."""
        path = self._row_path(config_sha256, fingerprint)
        try:
            st = path.lstat()
        except FileNotFoundError:
            return None
        except OSError as e:
            raise UserError(
                f"cannot read the dataset: {e.strerror or e}", file=_shown(path)
            ) from None
        return st.st_dev, st.st_ino

    def _row_path(self, config_sha256: str, fingerprint: str) -> Path:
        return self.bags_dir / f"{self.key(config_sha256, fingerprint)}.parquet"

    @staticmethod
    def key(config_sha256: str, fingerprint: str) -> str:
        """``K``, the name of a bag's files under one config."""
        return hashlib.sha256(f"{config_sha256}\0{fingerprint}".encode()).hexdigest()[:32]

    def violations(self, budget: Budget | None = None) -> pa.Table:
        """Every violation row with its robot and date (``COLUMNS``: ``inputs``, the
        largest, is left on disk), from the files of ``dataset_files``, each read
        against fleet replay's schema (a file of other columns or types is an error,
        never a guess) and decoded only within ``budget`` (``read_file``)."""
        budget = budget if budget is not None else Budget()
        schema = pa.schema([*_READ, ("robot", pa.string()), ("date", pa.string())])
        if not _table_dir(self.violations_dir):
            return schema.empty_table()
        tables = []
        for name in dataset_files(self.violations_dir, ("robot", "date")):
            path = Path(name)
            try:
                table = read_file(path, _READ, budget, "violations")
            except (pa.ArrowException, OSError) as e:
                raise UserError(
                    f"not a fleet dataset's violations ({one_line(e)})", file=_shown(path)
                ) from None
            robot, date = (_partition(d, path) for d in (path.parent.parent, path.parent))
            parts = [pa.repeat(pa.scalar(v, pa.string()), table.num_rows) for v in (robot, date)]
            budget.take(sum(p.nbytes for p in parts), path)
            tables.append(table.append_column("robot", parts[0]).append_column("date", parts[1]))
        return pa.concat_tables(tables) if tables else schema.empty_table()


@contextlib.contextmanager
def only_writer(root: Path) -> Iterator[int]:
    """This run the dataset's only writer while the block runs: an exclusive lock
    on its lock file (made if need be, never through a link).  Two runs writing one
    dataset would replay every bag twice, and a run would take the other's
    unfinished files for an interrupted run's.  Then those are removed: the hidden
    temporary files of writes a killed run had not renamed (``TEMPORARY``), which
    nothing else would ever remove.  Yields how many were removed."""
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot make the dataset: {e.strerror or e}", file=str(root)) from None
    try:
        fd = os.open(root / LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    except OSError as e:
        raise UserError(f"cannot lock the dataset: {e.strerror or e}", file=str(root)) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(
                "the dataset is being written by another fleet replay",
                file=str(root),
                hint="wait for it to end, or give this one another -o",
            ) from None
        except OSError as e:
            raise UserError(f"cannot lock the dataset: {e.strerror or e}", file=str(root)) from None
        yield _remove_temporaries(root)
    finally:
        os.close(fd)  # releases the lock


def _remove_temporaries(root: Path) -> int:
    """The ``TEMPORARY`` files in the dataset's directories, removed; links and
    anything else left to the readers (``dataset_files`` names them)."""
    removed = 0
    todo = [d for d in (root / "bags", root / "violations") if _table_dir(d)]
    while todo:
        d = todo.pop()
        try:
            with os.scandir(d) as it:
                entries = list(it)
        except (FileNotFoundError, NotADirectoryError):
            continue
        except OSError as e:
            raise UserError(f"cannot list: {e.strerror or e}", file=_shown(d)) from None
        for entry in entries:
            if entry.is_dir(follow_symlinks=False) and "=" in entry.name:
                todo.append(Path(entry.path))
            elif TEMPORARY.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
                try:
                    os.unlink(entry.path)
                except FileNotFoundError:
                    continue
                except OSError as e:
                    raise UserError(
                        f"cannot write the dataset: {e.strerror or e}",
                        file=_shown(Path(entry.path)),
                    ) from None
                removed += 1
    return removed


def _table_dir(path: Path) -> bool:
    """Whether the table's directory (``bags/``, ``violations/``) is there; a link
    there (another dataset's rows, counted as this one's) is an error."""
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return False
    except OSError as e:
        raise UserError(f"cannot read: {e.strerror or e}", file=_shown(path)) from None
    if stat.S_ISLNK(mode):
        raise UserError("a link, not a directory fleet replay writes", file=_shown(path))
    return True


def _partition(directory: Path, path: Path) -> str:
    """A partition's value (``robot=R``), URI-decoded as Hive partitioning reads it;
    one of no value (Hive's default partition) is not fleet replay's."""
    value = unquote(directory.name.partition("=")[2])
    if value in ("", "__HIVE_DEFAULT_PARTITION__"):
        raise UserError(
            "not a fleet dataset's violations (a partition of no value, outside robot=R/date=D)",
            file=_shown(path),
        )
    return value


class Commits:
    """One writer's bags made durable in groups (module docstring): each bag's
    violation files written whole at once, its row once they are synced.  A bag
    without violation files has nothing to wait for: its row is written at once.  A
    group is synced once its bags took ``GROUP_S`` seconds of replay, so a worker
    killed loses at most that much finished work (a long bag is a group of its own),
    or when the caller ends it (``commit``: a pool's call, a few of Ray's results)."""

    GROUP_S = 0.5

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset
        self.rows: list[tuple[BagResult, str, str]] = []  # waiting for the next sync
        self.seconds = 0.0  # the replay time of the bags waiting

    def add(self, result: BagResult, robot: str, fingerprint: str) -> None:
        ds = self.dataset
        key = ds.key(result.task.config_sha256, fingerprint)
        v = result.violations
        dates = sorted(set(v.column("date").to_pylist()))
        for date in dates:
            part = v.filter(pc.equal(v["date"], date)).drop_columns(["date"])
            where = ds.violations_dir / f"robot={robot}" / f"date={date}"
            _write(where / f"{key}.parquet", part, ds.root)
        if not dates:
            self._row(result, robot, fingerprint)
            return
        self.rows.append((result, robot, fingerprint))
        self.seconds += result.seconds
        if self.seconds >= self.GROUP_S:
            self.commit()

    def commit(self) -> None:
        """The waiting bags' violations synced, then their rows written."""
        if not self.rows:
            return
        self.dataset.sync()
        for result, robot, fingerprint in self.rows:
            self._row(result, robot, fingerprint)
        self.rows, self.seconds = [], 0.0

    def _row(self, result: BagResult, robot: str, fingerprint: str) -> None:
        task = result.task
        row = {
            "bag": task.bag,
            "robot": robot,
            "bag_sha256": result.bag_sha256,
            "fingerprint": fingerprint,
            "config_sha256": task.config_sha256,
            "messages": result.messages,
            "violations": result.violations.num_rows,
            "status": result.status,
            "reason": result.reason,
            "seconds": result.seconds,
            "finished_ts": time.time_ns(),
        }
        key = self.dataset.key(task.config_sha256, fingerprint)
        row_table = pa.Table.from_pylist([row], schema=BAGS)
        _write(self.dataset.bags_dir / f"{key}.parquet", row_table, self.dataset.root)


def dataset_files(where: Path, levels: tuple[str, ...]) -> list[str]:
    """The Parquet files under ``where`` as fleet replay lays them out: a directory
    per level (``robot=``, ``date=``), then ``*.parquet`` files.  Anything else is an
    error naming it: a link (pyarrow's discovery followed a loop without end, or
    counted another dataset's rows), a FIFO or device, a directory or file where
    the layout has none (its rows were added, or left out, without a word).  Hidden
    and ``_`` names are skipped, as pyarrow does (an interrupted write's temporary)."""
    out: list[str] = []
    todo = [(where, 0)]
    while todo:
        d, depth = todo.pop()
        try:
            with os.scandir(d) as it:
                entries = sorted(it, key=lambda e: e.name)
        except OSError as e:
            raise UserError(f"cannot list: {e.strerror or e}", file=str(d)) from None
        for entry in entries:
            if entry.name.startswith((".", "_")):
                continue
            path = Path(entry.path)
            try:
                mode = entry.stat(follow_symlinks=False).st_mode
            except OSError as e:
                raise UserError(f"cannot read: {e.strerror or e}", file=_shown(path)) from None
            what = _kind(mode)
            if what is not None:
                raise UserError(f"{what}, not a file fleet replay writes", file=_shown(path))
            if depth < len(levels):
                if not (stat.S_ISDIR(mode) and entry.name.startswith(f"{levels[depth]}=")):
                    raise UserError(
                        f"not {levels[depth]}={levels[depth][0].upper()}: not fleet replay's "
                        "layout",
                        file=_shown(path),
                    )
                todo.append((path, depth + 1))
            elif stat.S_ISREG(mode) and entry.name.endswith(".parquet"):
                out.append(entry.path)
            else:
                raise UserError(
                    "not a .parquet file here: not fleet replay's layout", file=_shown(path)
                )
    return sorted(out)


def _kind(mode: int) -> str | None:
    """What an entry is, when no dataset of fleet replay holds one."""
    if stat.S_ISLNK(mode):
        return "a link"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    return "a device or socket"


def _shown(path: Path) -> str:
    return printable(str(path))


class Writers:
    """Ray's results written by the parent, in groups of up to ``GROUP`` bags
    (``Commits``: one sync per group) on a few threads, so that the parent keeps
    taking results while a group is synced (docs/BENCHMARKS.md, "Fleet").  A bag's
    own files stay in order (its violations, then its row); ``put`` and ``drain``
    give back the results whose files are written, in the order they were put, and
    raise a write's error."""

    THREADS = 4
    GROUP = 16  # bags a sync at most: a Ray task's results (engine.py, RAY_BATCH)
    BACKLOG = 64  # results waiting for their files at most: then put waits

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset
        self.pool = ThreadPoolExecutor(self.THREADS, thread_name_prefix="fleet-write")
        self.group: list[tuple[BagResult, str, str]] = []  # not yet handed to a thread
        self.pending: deque[tuple[Future[None], list[BagResult]]] = deque()
        self.waiting = 0  # results in ``pending``

    def put(self, result: BagResult, robot: str, fingerprint: str) -> list[BagResult]:
        self.group.append((result, robot, fingerprint))
        if len(self.group) >= self.GROUP:
            self._send()
        out: list[BagResult] = []
        while self.pending and (self.pending[0][0].done() or self.waiting > self.BACKLOG):
            out += self._next()
        return out

    def _send(self) -> None:
        group, self.group = self.group, []
        self.pending.append(
            (self.pool.submit(_write_group, self.dataset, group), [r for r, _, _ in group])
        )
        self.waiting += len(group)

    def drain(self) -> list[BagResult]:
        if self.group:
            self._send()
        return [r for _ in range(len(self.pending)) for r in self._next()]

    def _next(self) -> list[BagResult]:
        future, results = self.pending.popleft()
        future.result()  # its error (a full disk) stops the run, as a write here would
        self.waiting -= len(results)
        return results

    def __enter__(self) -> Writers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        # stopped early: the writes not started are dropped; a started one ends whole
        self.pool.shutdown(wait=True, cancel_futures=True)


def _write_group(dataset: Dataset, group: list[tuple[BagResult, str, str]]) -> None:
    commits = Commits(dataset)
    for result, robot, fingerprint in group:
        commits.add(result, robot, fingerprint)
    commits.commit()


def _write(path: Path, table: pa.Table, root: Path) -> None:
    """Whole, not yet durable (``Commits`` syncs), in the dataset ``root``."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    try:
        _directories(root, path.parent)
        write_whole(path, sink.getvalue().to_pybytes(), mode=0o644)
    except OSError as e:  # a full disk or a directory taken away during the run
        raise UserError(f"cannot write the dataset: {e.strerror or e}", file=str(path)) from None


def _directories(root: Path, where: Path) -> None:
    """``where`` made below ``root`` one directory at a time, none of them a link: a
    dataset handed over with ``robot=R`` linked elsewhere had a resumed run write its
    files there (mkdir and the write follow links)."""
    path = root
    for part in where.relative_to(root).parts:
        path = path / part
        with contextlib.suppress(FileExistsError):
            os.mkdir(path)
        mode = path.lstat().st_mode
        what = _kind(mode)
        if what is not None:
            raise UserError(f"{what}, not a directory fleet replay writes", file=_shown(path))
        if not stat.S_ISDIR(mode):
            raise UserError("cannot write the dataset: not a directory", file=_shown(path))


class Budget:
    """What one reading of a dataset may still decode (``MAX_DECODED_BYTES``),
    shared by the files it reads."""

    def __init__(self, limit: int = MAX_DECODED_BYTES) -> None:
        self.limit = limit
        self.left = limit

    def check(self, n: int, path: Path) -> None:
        if n > self.left:
            raise UserError(
                f"with this file the dataset decodes to more than {self.limit / 2**30:g} GiB, "
                "the most it is read to: not read",
                file=_shown(path),
                hint="a dataset this large is for DuckDB (docs/reference/fleet.md)",
            )

    def take(self, n: int, path: Path) -> None:
        self.check(n, path)
        self.left -= n


def read_file(path: Path, schema: pa.Schema, budget: Budget, what: str) -> pa.Table:
    """One of the dataset's Parquet files, ``schema``'s columns of ``schema``'s types,
    each batch of rows decoded only once ``budget`` has room for it.  Its text columns
    are read as dictionary codes first (each distinct value once), so that a batch's
    decoded size is known exactly before it is decoded.  The footer's sizes and row
    counts are never the bound: they are the file's word, and pyarrow decodes what
    the pages hold whatever the footer says.  Its pages' decompression is bounded by
    what the columns read store (``CODECS``).  A file of other columns, types,
    encodings or codecs: not this dataset's."""

    with _opened(path) as source:
        return _read(source, path, schema, budget, what)


@contextlib.contextmanager
def _opened(path: Path) -> Iterator[pa.NativeFile]:
    """``path`` opened once, a regular file or an error: listed as one, a file can be
    swapped for a FIFO (opening it waited for a writer for ever) or a link before it
    is opened (``dataset_files`` looked at it by name)."""
    try:
        f = open_regular(path, follow=False)
    except NotRegularFile as e:
        what = _kind(e.mode) or "a directory"
        raise UserError(f"{what}, not a file fleet replay writes", file=_shown(path)) from None
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise UserError("a link, not a file fleet replay writes", file=_shown(path)) from None
        raise
    # the file this descriptor holds, whatever the name holds now
    with f, pa.OSFile(f"/proc/self/fd/{f.fileno()}") as source:
        yield source


def _read(
    source: pa.NativeFile, path: Path, schema: pa.Schema, budget: Budget, what: str
) -> pa.Table:
    try:
        return _read_checked(source, path, schema, budget, what)
    except UnicodeDecodeError:  # pyarrow decodes the footer's names as it gives them
        raise _wrong(path, what, "its footer has a name that is not UTF-8") from None


def _wrong(path: Path, what: str, why: str) -> UserError:
    return UserError(f"not a fleet dataset's {what} ({why})", file=_shown(path))


def _read_checked(
    source: pa.NativeFile, path: Path, schema: pa.Schema, budget: Budget, what: str
) -> pa.Table:
    def wrong(why: str) -> UserError:
        return _wrong(path, what, why)

    if (bad := _bad_footer(source)) is not None:
        raise wrong(bad)
    parquet = pq.ParquetFile(source)
    found = parquet.schema_arrow
    for f in schema:
        i = found.get_field_index(f.name)
        if i < 0:
            raise wrong(f"no column {f.name}")
        if found.field(i).type != f.type:
            raise wrong(f"column {f.name} is {found.field(i).type}, not {f.type}")
    meta = parquet.metadata
    names = set(schema.names)
    stored = 0  # the most a row group's columns read hold, compressed
    for g in range(meta.num_row_groups):
        group = meta.row_group(g)
        read = [group.column(c) for c in range(group.num_columns)]
        read = [k for k in read if k.path_in_schema in names]
        stored = max(stored, sum(k.total_compressed_size for k in read))
        for column in read:
            if not set(column.encodings) <= ENCODINGS:
                odd = ", ".join(sorted(set(column.encodings) - ENCODINGS))
                raise wrong(f"column {column.path_in_schema} encoded as {odd}")
            if column.compression not in CODECS:
                raise wrong(f"column {column.path_in_schema} compressed as {column.compression}")
    # A page is read from its column chunk's bytes, which pyarrow keeps within the
    # file: so the chunks' sizes (the footer's word) are bounded by the file's.
    budget.check(EXPANDS * min(stored, source.size()), path)
    text = [f.name for f in schema if pa.types.is_string(f.type)]
    coded = pq.ParquetFile(source, read_dictionary=text, metadata=meta)
    tables = []
    for batch in coded.iter_batches(BATCH_ROWS, columns=schema.names, use_threads=False):
        table = pa.Table.from_batches([batch]).select(schema.names)
        budget.take(_decoded(table), path)
        for name in schema.names:
            why = _bad_values(table[name])
            if why is not None:
                raise wrong(f"column {name} {why}")
        tables.append(table.cast(schema))
    return pa.concat_tables(tables) if tables else schema.empty_table()


def _bad_footer(source: pa.NativeFile) -> str | None:
    """Why the file's footer is none pyarrow may be given (footer.py), or None."""
    size = source.size()
    if size < 12:
        return None
    try:
        source.seek(size - 8)
        n = footer.footer_length(size, source.read(8))
        if n is None:
            return None
        source.seek(size - 8 - n)
        footer.check(source.read(n))
    except footer.BadFooter as e:
        return str(e)
    finally:
        source.seek(0)
    return None


def _bad_values(column: pa.ChunkedArray) -> str | None:
    """What no file fleet replay writes holds: a null (its texts are "" when empty) or
    text that is not UTF-8 (pyarrow reads a string column's bytes unchecked)."""
    for chunk in column.chunks:
        values = chunk.dictionary if pa.types.is_dictionary(chunk.type) else chunk
        if chunk.null_count or values.null_count:
            return "has null values"
        if pa.types.is_string(values.type):
            try:
                values.validate(full=True)
            except pa.ArrowInvalid:
                return "has text that is not UTF-8"
    return None


def _decoded(table: pa.Table) -> int:
    """The bytes ``table`` takes once its dictionary columns are decoded."""
    n = 0
    for column in table.columns:
        if not pa.types.is_dictionary(column.type):
            n += column.nbytes
            continue
        for chunk in column.chunks:
            lengths = pc.binary_length(chunk.dictionary)
            n += (pc.sum(pc.take(lengths, chunk.indices)).as_py() or 0) + 4 * (len(chunk) + 1)
    return n


def _row_file(path: Path, budget: Budget) -> pa.Table | None:
    """A row file read against ``BAGS``; None for one of this dataset's names that a
    power loss left empty or cut short (module docstring).  Any other file that is
    not a row is one error: not this dataset's."""
    ours = KEY.fullmatch(path.name) is not None
    try:
        with _opened(path) as source:
            try:
                table = _read(source, path, BAGS, budget, "bags table")
            except (pa.ArrowException, OSError) as e:
                if ours and _cut(source):
                    return None
                raise UserError(
                    f"not a fleet dataset's bags table ({one_line(e)})", file=_shown(path)
                ) from None
    except FileNotFoundError:
        raise
    except PermissionError as e:  # another user's: no sign of a power loss, never removed
        raise UserError(
            f"cannot read it: {e.strerror or 'Permission denied'}", file=_shown(path)
        ) from None
    why = _not_a_row(table) if table.num_rows else None
    if why is not None:
        raise UserError(f"not a fleet dataset's bags table ({why})", file=_shown(path))
    return table


def _not_a_row(table: pa.Table) -> str | None:
    """What makes a file no row fleet replay writes: more than one row (a bag's row is
    a file of its own), or values it never writes (a status of its own, a count below
    zero, seconds not a finite count)."""
    if table.num_rows != 1:
        return f"{table.num_rows:,} rows in one bag's row file"
    row = table.select(["status", "messages", "violations", "seconds"]).to_pylist()[0]
    if row["status"] not in STATUSES:
        return f"status {shown(str(row['status']), 40)!r} is none of {', '.join(STATUSES)}"
    for name in ("messages", "violations"):
        if row[name] < 0:
            return f"{name} is below zero"
    if not 0 <= row["seconds"] < float("inf"):
        return "seconds is not a finite count"
    return None


def one_line(e: BaseException) -> str:
    """An error's text as one printable line of a bounded length."""
    return printable(" ".join(str(e).split()))[:MAX_ERROR]


def _cut(source: pa.NativeFile) -> bool:
    """Whether a file that is no row has the signs of a write a power loss cut short:
    empty, or not Parquet to its end (no footer), or a footer whose columns are the
    row's (its data pages lost).  ``source``: the file as opened for the read."""
    try:
        if source.size() == 0:
            return True
        if _bad_footer(source) is not None:
            return False  # a footer there, damaged: not a write cut short
        schema = pq.read_schema(source)
    except UnicodeDecodeError:
        return False  # a footer there, damaged: not a write cut short
    except (pa.ArrowException, OSError):
        return True
    return schema.names == BAGS.names
