"""One bag, one task: the bag replayed by ``replay``'s own core and readers
(supervisor/tools/replay/session.py, ``run_one``), its violations returned as an Arrow
table, which the local engine's worker writes itself and Ray's parent writes
(dataset.py, engine.py).

``run_task`` is the whole interface an engine needs: a picklable ``BagTask`` in, a
picklable ``BagResult`` out, no shared state, no file written.  It never raises for
anything a bag or the config holds: that is the result's status and reason.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pyarrow as pa

from mitigations.violationlog.discard import DiscardingLog
from monitors.errors import UserError
from monitors.untrusted import shown
from supervisor.tools.fleet.archive import content_hash, fingerprint

# One row per violation; robot and date are the dataset's partitions (dataset.py).
VIOLATIONS = pa.schema(
    [
        ("bag", pa.string()),
        ("bag_sha256", pa.string()),
        ("requirement", pa.string()),
        ("tick", pa.int64()),
        ("recorded_ts", pa.timestamp("ns", tz="UTC")),
        ("config_sha256", pa.string()),
        ("inputs", pa.string()),  # JSON text: the inputs that decided the verdict
        ("date", pa.string()),  # the partition, dropped from the written files
    ]
)
STATUSES = ("read", "skipped", "damaged", "failed")
MAX_REASON = 2000  # a reason is one line of an error; a bag's text stays bounded


@dataclass(frozen=True)
class BagTask:
    """What a worker needs for one bag: no open file, no compiled monitor (a worker
    builds or finds it in the start-up cache from the config's path)."""

    bag: str
    robot: str
    config: str
    config_sha256: str
    namespace: str | None = None
    fingerprint: str = ""  # the bag's (archive.py): its files' key when a worker writes them


@dataclass
class BagResult:
    """A task's outcome. ``status``: read (whole), skipped (nothing the config reads,
    or content already replayed with this config), damaged (read up to the damage:
    its violations before it are kept), failed (not replayed: ``reason``)."""

    task: BagTask
    status: str
    reason: str = ""
    bag_sha256: str = ""
    messages: int = 0
    seconds: float = 0.0
    violations: pa.Table = field(default_factory=VIOLATIONS.empty_table)
    # set once a worker has written the bag's files itself (engine.py, LocalEngine):
    # ``violations`` is then left out of the result, and this is how many rows it had
    written: int | None = None

    def without_table(self) -> BagResult:
        """This result, once its files are durable, as the parent needs it: its
        violations counted, not sent back (docs/BENCHMARKS.md, "Fleet")."""
        return BagResult(
            self.task,
            self.status,
            self.reason,
            self.bag_sha256,
            self.messages,
            self.seconds,
            written=self.violations.num_rows,
        )


class _Records(DiscardingLog):
    """The ``sink`` of run_one: keeps the violation records, drops the others (the
    dry-run mitigations, resets and notes are replay's, not the dataset's)."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, int, int, str]] = []

    def violation(self, requirement: str, *, recorded_ts: str, **fields: Any) -> bool:
        self.rows.append(
            (requirement, int(fields["tick"]), _ns(recorded_ts), _json(fields.get("inputs", {})))
        )
        return True


CHANGED = (
    "the config or a file it imports changed during the run: this bag was not replayed "
    "with the config the run began with (run fleet replay again)"
)
# This worker's configs compiled (config path -> its bytes' SHA-256 and the compiled
# config): a worker replays many bags with one or two configs, and compiling took
# most of a small bag's task (docs/BENCHMARKS.md, "Fleet").  Keyed by the bytes read
# once for each task and compiled from those same bytes, so a config edited during
# the run is compiled again, never kept under another version's key.
_prepared: dict[str, tuple[str, Any]] = {}


def _compiled(config: str) -> Any:
    """The config compiled, from this worker's cache when its bytes are unchanged; a
    ``UserError`` for a config that cannot be read (bounded: a FIFO or /dev/zero is
    one line, not a hang) or compiled."""
    from supervisor.config import read_config
    from supervisor.tools.replay.session import prepare

    source = read_config(config)
    kept = _prepared.get(config)
    if kept is None or kept[0] != source.sha256:
        kept = _prepared[config] = (source.sha256, prepare(source))
    return kept[1]


def compile_config(config: str) -> str | tuple[str, str, int | None, int | None, str | None]:
    """The config compiled and its monitor loaded, both kept for this worker's tasks,
    as a worker starts (engine.py, ``LocalEngine.start``): the parent then compiles
    nothing (docs/BENCHMARKS.md, "Fleet").  The config's identity (``Config.identity``,
    what the dataset is keyed by); a bad config: its error's parts, as a
    ``UserError`` does not cross processes whole (its fields are keyword-only)."""
    from supervisor.tools.replay.session import loaded

    try:
        prepared = _compiled(config)
        with loaded(Path(config), prepared):
            pass  # the monitor built or found in the cache, then kept for the tasks
    except UserError as e:
        return (e.message, e.file, e.line, e.col, e.hint)
    return str(prepared.project.config.identity)


def config_error(parts: tuple[str, str, int | None, int | None, str | None]) -> UserError:
    """``compile_config``'s error again as the ``UserError`` it was."""
    message, file, line, col, hint = parts
    return UserError(message, file=file, line=line, col=col, hint=hint)


def run_task(task: BagTask, done: Collection[str] = ()) -> BagResult:
    """Replay one bag. ``done``: ``CONFIG_SHA256:BAG_SHA256`` of the bags already
    replayed (the same bag under another path is then skipped after hashing, not
    replayed again)."""
    # replay's modules load here, in the worker: the parent only lists and writes
    from supervisor.tools.replay.session import run_one
    from supervisor.tools.replay.sources import NothingToJudge

    t0 = time.perf_counter()
    try:
        before = fingerprint(Path(task.bag))[1]  # what _changed compares with
        digest = content_hash(Path(task.bag))
    except OSError as e:
        return BagResult(task, "failed", _reason(f"{task.bag}: {e.strerror or e}"))
    if f"{task.config_sha256}:{digest}" in done:
        return BagResult(task, "skipped", "already replayed with this config", digest)
    records = _Records()
    try:
        prepared = _compiled(task.config)
        if str(prepared.project.config.identity) != task.config_sha256:
            # the config or an import edited since the run began: its rows would name
            # the identity the run began with and hold what another version judged
            return BagResult(task, "failed", CHANGED, digest, seconds=time.perf_counter() - t0)
        run = run_one(
            Path(task.config),
            [Path(task.bag)],
            None,
            None,
            namespace=task.namespace,
            sink=records,
            prepared=prepared,
        )
    except NothingToJudge as e:
        return BagResult(task, "skipped", _reason(str(e)), digest, seconds=time.perf_counter() - t0)
    except UserError as e:
        return BagResult(task, "failed", _reason(str(e)), digest, seconds=time.perf_counter() - t0)
    if (changed := _changed(task, before)) is not None:
        return BagResult(task, "failed", _reason(changed), digest, seconds=time.perf_counter() - t0)
    outcome = run.outcome
    status, reason = "read", ""
    if isinstance(outcome.error, NothingToJudge):
        status, reason = "skipped", str(outcome.error)
    elif outcome.error is not None:
        status, reason = "damaged", str(outcome.error)
    return BagResult(
        task,
        status,
        _reason(reason),
        digest,
        outcome.messages,
        time.perf_counter() - t0,
        _table(task, digest, records.rows),
    )


def _changed(task: BagTask, before: str) -> str | None:
    """Why the bag's files are no longer those hashed (their names, sizes and times:
    ``fingerprint``, taken ``before`` the hash), or None.  Changed between the hash and
    the replay's reading, the row paired one content's hash with another's results: a
    damaged verdict on an intact bag's hash, which a later run skipped as replayed."""
    try:
        now = fingerprint(Path(task.bag))[1]
    except OSError as e:
        return f"{task.bag}: {e.strerror or e}"
    if now != before:
        return f"{task.bag}: its files changed while it was replayed: run again"
    return None


def copy_of(task: BagTask, first: str, digest: str) -> BagResult:
    """The result of a bag whose content is that of ``first``, another bag of the
    run (archive.py, ``copies``): skipped, not replayed twice."""
    return BagResult(
        task, "skipped", _reason(f"the same content as {first}, replayed with this config"), digest
    )


def vouched(copy: BagResult, first: BagResult) -> BagResult:
    """A copy's result (``copy_of``) once its first's is in: skipped only if the first
    was replayed (or skipped) with the content the copy was found to share.  A first
    rewritten between the hash that found the copy and its task, or failed, holds the
    copy's content in no row: the copy is failed, and the next run replays it."""
    if first.status != "failed" and first.bag_sha256 == copy.bag_sha256:
        return copy
    what = "failed" if first.status == "failed" else "changed during the run"
    why = f"the same content as {first.task.bag}, which {what}: not replayed"
    return BagResult(copy.task, "failed", _reason(why), copy.bag_sha256)


def _table(task: BagTask, digest: str, rows: list[tuple[str, int, int, str]]) -> pa.Table:
    n = len(rows)
    return pa.table(
        {
            "bag": [task.bag] * n,
            "bag_sha256": [digest] * n,
            "requirement": [r[0] for r in rows],
            "tick": [r[1] for r in rows],
            "recorded_ts": [r[2] for r in rows],
            "config_sha256": [task.config_sha256] * n,
            "inputs": [r[3] for r in rows],
            "date": [_date(r[2]) for r in rows],
        },
        schema=VIOLATIONS,
    )


def _ns(stamp: str) -> int:
    """``recorded_ts`` as replay writes it (``...T12:00:00.123456789Z``) in ns."""
    whole, _, frac = stamp.rstrip("Z").partition(".")
    # fromisoformat: several times faster than strptime, and a dense bag has a
    # violation every few messages
    seconds = datetime.fromisoformat(whole).replace(tzinfo=UTC).timestamp()
    return int(seconds) * 1_000_000_000 + int((frac or "0").ljust(9, "0")[:9])


def _date(ns: int) -> str:
    return datetime.fromtimestamp(ns // 1_000_000_000, tz=UTC).strftime("%Y-%m-%d")


def _json(inputs: Any) -> str:
    """JSON text any reader parses: a NaN or infinity (an input can be one) as its
    name in a string, as JSON has no such number."""

    def fix(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return str(v)
        if isinstance(v, dict):
            return {str(k): fix(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [fix(x) for x in v]
        return v

    return json.dumps(fix(inputs), sort_keys=True, allow_nan=False, default=str)


def _reason(text: str) -> str:
    return shown(" ".join(text.split()), MAX_REASON)
