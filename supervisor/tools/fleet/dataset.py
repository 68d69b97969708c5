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
"""

from __future__ import annotations

import hashlib
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.files import write_atomic
from supervisor.tools.fleet.task import BagResult

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
        """Every bag finished (any status but failed) in an earlier run."""
        fps: set[tuple[str, str]] = set()
        contents: set[tuple[str, str]] = set()
        table = self.bags()
        finished = table.filter(pc.not_equal(table["status"], "failed"))
        for row in finished.select(["config_sha256", "fingerprint", "bag_sha256"]).to_pylist():
            fps.add((row["config_sha256"], row["fingerprint"]))
            if row["bag_sha256"]:
                contents.add((row["config_sha256"], row["bag_sha256"]))
        return Done(frozenset(fps), frozenset(contents))

    def bags(self) -> pa.Table:
        """The bags table: one row per bag and config."""
        files = sorted(self.bags_dir.glob("*.parquet")) if self.bags_dir.is_dir() else []
        if not files:
            return BAGS.empty_table()
        try:
            return pa.concat_tables([pq.read_table(f, schema=BAGS) for f in files])
        except (pa.ArrowException, OSError) as e:
            raise UserError(
                f"not a fleet dataset's bags table ({e})", file=str(self.bags_dir)
            ) from None

    def write(self, result: BagResult, robot: str, fingerprint: str) -> None:
        """One bag's violations, then its row."""
        task = result.task
        key = self.key(task.config_sha256, fingerprint)
        v = result.violations
        for date in sorted(set(v.column("date").to_pylist())):
            part = v.filter(pc.equal(v["date"], date)).drop_columns(["date"])
            _write(self.violations_dir / f"robot={robot}" / f"date={date}" / f"{key}.parquet", part)
        row = {
            "bag": task.bag,
            "robot": robot,
            "bag_sha256": result.bag_sha256,
            "fingerprint": fingerprint,
            "config_sha256": task.config_sha256,
            "messages": result.messages,
            "violations": v.num_rows,
            "status": result.status,
            "reason": result.reason,
            "seconds": result.seconds,
            "finished_ts": time.time_ns(),
        }
        _write(self.bags_dir / f"{key}.parquet", pa.Table.from_pylist([row], schema=BAGS))

    def row(self, config_sha256: str, fingerprint: str) -> dict[str, Any] | None:
        """This bag's row under this config (``BAGS``' columns, ``finished_ts`` in ns
        since the epoch), or None: the bag is not finished.  A row is written whole or
        not at all (``_write``)."""
        path = self.bags_dir / f"{self.key(config_sha256, fingerprint)}.parquet"
        try:
            table = pq.read_table(path, schema=BAGS)
            at = table.schema.get_field_index("finished_ts")
            rows = table.set_column(at, "finished_ts", table["finished_ts"].cast(pa.int64()))
        except FileNotFoundError:
            return None
        except (pa.ArrowException, OSError) as e:
            raise UserError(
                f"not a fleet dataset's bag row ({printable(str(e))})", file=str(path)
            ) from None
        return rows.to_pylist()[0] if rows.num_rows == 1 else None

    @staticmethod
    def key(config_sha256: str, fingerprint: str) -> str:
        """``K``, the name of a bag's files under one config."""
        return hashlib.sha256(f"{config_sha256}\0{fingerprint}".encode()).hexdigest()[:32]

    def violations(self) -> pa.Table:
        """The whole violations dataset, its partitions as columns."""
        if not self.violations_dir.is_dir():
            return pa.table({})
        import pyarrow.dataset as ds

        try:
            found = ds.dataset(self.violations_dir, format="parquet", partitioning=partitions())
            return found.to_table()
        except (pa.ArrowException, OSError) as e:
            raise UserError(
                f"not a fleet dataset's violations ({printable(str(e))})",
                file=str(self.violations_dir),
            ) from None


def partitions() -> Any:
    """The violations' hive partitions, as text: a robot named 007 stays "007"
    (pyarrow infers a number otherwise)."""
    import pyarrow.dataset as ds

    return ds.partitioning(
        pa.schema([("robot", pa.string()), ("date", pa.string())]), flavor="hive"
    )


class Writers:
    """``Dataset.write`` on a few threads, so that the parent keeps taking results while
    files are synced: each file is fsynced with its directory (supervisor/files.py),
    milliseconds on a busy disk, as long as a small bag's whole task
    (docs/BENCHMARKS.md, "Fleet").  A bag's own files stay in order (its violations,
    then its row); ``put`` and ``drain`` give back the results whose files are
    written, in the order they were put, and raise a write's error."""

    THREADS = 4
    BACKLOG = 64  # results waiting for their files at most: then put waits

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset
        self.pool = ThreadPoolExecutor(self.THREADS, thread_name_prefix="fleet-write")
        self.pending: deque[tuple[Future[None], BagResult]] = deque()

    def put(self, result: BagResult, robot: str, fingerprint: str) -> list[BagResult]:
        future = self.pool.submit(self.dataset.write, result, robot, fingerprint)
        self.pending.append((future, result))
        out = []
        while self.pending and (self.pending[0][0].done() or len(self.pending) > self.BACKLOG):
            out.append(self._next())
        return out

    def drain(self) -> list[BagResult]:
        return [self._next() for _ in range(len(self.pending))]

    def _next(self) -> BagResult:
        future, result = self.pending.popleft()
        future.result()  # its error (a full disk) stops the run, as a write here would
        return result

    def __enter__(self) -> Writers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        # stopped early: the writes not started are dropped; a started one ends whole
        self.pool.shutdown(wait=True, cancel_futures=True)


def _write(path: Path, table: pa.Table) -> None:
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, sink.getvalue().to_pybytes(), mode=0o644)
    except OSError as e:  # a full disk or a directory taken away during the run
        raise UserError(f"cannot write the dataset: {e.strerror or e}", file=str(path)) from None
