"""Recording the daemon's inputs and records into rosbag2 MCAP bags (``run --record``).

Every input message goes into the bag as it arrived (serialized CDR, its own topic
and type) with the daemon's receive time; the daemon's log lines go to
``RECORDS_TOPIC`` as ``std_msgs/msg/String``, so one bag shows inputs and violations
on one timeline (docs/reference/config.md, record; docs/reference/log.md).

The receive loop only appends to a queue (``message``, ``record``); a writer thread
encodes and writes in batches with rosbags' rosbag2 writer. Recording never stops
monitoring: a full queue drops and counts, a write error stops the recording and is
reported once through ``on_stopped``. No rclpy here, so it is tested without ROS.
"""

from __future__ import annotations

import collections
import errno
import os
import re
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

if TYPE_CHECKING:
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from supervisor.config.record import RecordConfig

RECORDS_TOPIC = "/safety_supervisor/records"
RECORDS_TYPE = "std_msgs/msg/String"
# A bag directory: its first message's UTC time and a sequence number that goes on
# across rotations and restarts (the next free one in the directory).
BAG_NAME = re.compile(r"^(\d{8}T\d{6}Z)_(\d{6,})$")
# MCAP's per-message overhead in the file (record header, index entry), for the size
# rotation; the exact size is only known once the chunk is written.
MESSAGE_OVERHEAD = 47
# Records are few and are the evidence: they may exceed the message bound by this many
# so that a flood of inputs cannot push a violation out of the recording.
RECORD_RESERVE = 1000
MB = 1 << 20


@dataclass(frozen=True)
class RecorderStats:
    written: int  # messages and records in the bags
    dropped: int  # not queued: the writer was behind by queue_messages / queue_bytes
    skipped: int  # messages of topics whose type could not be described (never recorded)
    lost: int  # queued or offered after the recording stopped
    bytes: int  # payload bytes written
    bags: int  # bags begun by this recorder
    stopped: str | None  # why the recording stopped, None while it runs or after close()


def _names(node: Any) -> Iterable[str]:
    """The message types a rosbags field type refers to (nested in arrays too)."""
    kind, payload = node
    if kind == Nodetype.NAME:
        yield payload
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _names(payload[0])


def msg_search_prefixes() -> list[Path]:
    """Where installed ROS packages keep ``share/<pkg>/msg/*.msg``: the ament
    prefixes, and this Python's prefix (the ros-jazzy-* wheels install there)."""
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(":") if p]
    return [*prefixes, Path(sys.prefix)]


def load_msg_types(
    typestore: Typestore, msgtype: str, prefixes: Sequence[Path] | None = None
) -> None:
    """Registers ``msgtype`` and every type it uses from the installed .msg files.

    Raises LookupError naming the first type without a .msg file."""
    prefixes = msg_search_prefixes() if prefixes is None else prefixes
    found: dict[str, Any] = {}
    pending = [msgtype]
    while pending:
        name = pending.pop()
        if name in typestore.types or name in found:
            continue
        pkg, _, short = name.rpartition("/msg/")
        files = [p / "share" / pkg / "msg" / f"{short}.msg" for p in prefixes]
        path = next((f for f in files if pkg and f.is_file()), None)
        if path is None:
            raise LookupError(f"no .msg file for {name} (searched {', '.join(map(str, files))})")
        types = get_types_from_msg(path.read_text(encoding="utf-8"), name)
        found.update(types)
        for _consts, fields in types.values():
            pending.extend(n for _field, ftype in fields for n in _names(ftype))
    typestore.register(found)


def bag_dirs(directory: Path) -> list[tuple[int, Path]]:
    """The bag directories a recorder made in ``directory``, oldest first."""
    out = []
    for p in directory.iterdir() if directory.is_dir() else ():
        m = BAG_NAME.match(p.name)
        if m and p.is_dir():
            out.append((int(m.group(2)), p))
    return sorted(out)


class Recorder:
    """Records input messages and log records into rotating rosbag2 MCAP bags.

    ``message`` and ``record`` may be called from any thread; they append to a queue
    under one short lock and never block on I/O or raise. ``inputs[i]`` is the
    (topic, ROS type) of input ``i``; ``message(i, ...)`` records on it.

    Times: callers pass ``time.monotonic_ns()``; the bag holds wall-clock time
    ``t_ns + wall_offset_ns`` with one offset fixed here, so differences between bag
    timestamps are exactly the differences of the receive times.

    Construction creates the directory (OSError if it cannot); every later error
    stops the recording and is reported once through ``on_stopped(reason)``.
    ``on_warning(text)`` says what the recording leaves out (a topic whose type
    cannot be described, messages dropped while the writer was behind).
    """

    def __init__(
        self,
        directory: str | Path,
        inputs: Sequence[tuple[str, str]],
        *,
        max_bag_bytes: int = 100 * MB,
        max_bag_s: float = 300.0,
        keep: int = 20,
        queue_messages: int = 100_000,
        queue_bytes: int = 64 * MB,
        on_stopped: Callable[[str], None] | None = None,
        on_warning: Callable[[str], None] | None = None,
        flush_s: float = 0.5,
        flush_messages: int = 10_000,
        poll_s: float = 0.01,
        msg_prefixes: Sequence[Path] | None = None,
    ) -> None:
        if keep < 1 or max_bag_bytes < 1 or max_bag_s <= 0 or queue_messages < 1:
            raise ValueError("keep, max_bag_bytes, max_bag_s and queue_messages must be positive")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.inputs = [(str(topic), str(msgtype)) for topic, msgtype in inputs]
        self.wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self._max_bag_bytes = max_bag_bytes
        self._max_bag_ns = int(max_bag_s * 1e9)
        self._keep = keep
        self._max_queue = queue_messages
        self._max_queue_bytes = queue_bytes
        self._on_stopped = on_stopped
        self._on_warning = on_warning
        self._flush_ns = int(flush_s * 1e9)
        self._flush_messages = flush_messages
        self._poll_s = poll_s
        self._msg_prefixes = msg_prefixes

        # Shared with the callers, under _lock: the queue and what it holds.
        self._lock = threading.Lock()
        self._queue: collections.deque[tuple[int, int, bytes | str]] = collections.deque()
        self._queued = 0
        self._queued_bytes = 0
        self._dropped = 0
        self._lost = 0
        self._stopped = False

        # The writer thread's own.
        self._writer: Writer | None = None
        self._conns: list[Connection | None] = []
        self._records_conn: Connection | None = None
        self._typestore: Typestore | None = None
        self._skip: set[int] = set()  # inputs whose type cannot be described
        self._bag_start_ns = 0
        self._bag_bytes = 0
        self._seq = max((n for n, _ in bag_dirs(self.directory)), default=0)
        self._unflushed = 0
        self._last_flush = time.monotonic_ns()
        self._written = 0
        self._skipped = 0
        self._bytes = 0
        self._bags = 0
        self._reported_drops = 0
        self._reason: str | None = None

        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    @classmethod
    def from_config(
        cls,
        config: RecordConfig,
        inputs: Sequence[tuple[str, str]],
        *,
        path: str | Path | None = None,
        on_stopped: Callable[[str], None] | None = None,
        on_warning: Callable[[str], None] | None = None,
    ) -> Recorder:
        """A recorder with the ``record:`` section's settings; ``path`` (``run
        --record``) overrides ``record.path``."""
        directory = path if path is not None else config.path
        if directory is None:
            raise ValueError("no directory to record into (record.path or run --record)")
        return cls(
            directory,
            inputs,
            max_bag_bytes=config.max_bag_bytes,
            max_bag_s=config.max_bag_s,
            keep=config.keep,
            queue_messages=config.queue_messages,
            on_stopped=on_stopped,
            on_warning=on_warning,
        )

    # -- the callers' side: cheap, never blocks on I/O, never raises ---------------

    def message(self, index: int, t_ns: int, data: bytes) -> None:
        """Input ``index``'s serialized message, received at monotonic ``t_ns``."""
        n = len(data)
        with self._lock:
            if self._stopped:
                self._lost += 1
            elif self._queued >= self._max_queue or self._queued_bytes + n > self._max_queue_bytes:
                self._dropped += 1
            else:
                self._queued += 1
                self._queued_bytes += n
                self._queue.append((index, t_ns, data))

    def record(self, t_ns: int, json_text: str) -> None:
        """One log line (a JSON record) made at monotonic ``t_ns``, for RECORDS_TOPIC."""
        n = len(json_text)
        with self._lock:
            if self._stopped:
                self._lost += 1
            elif self._queued >= self._max_queue + RECORD_RESERVE:
                self._dropped += 1
            else:
                self._queued += 1
                self._queued_bytes += n
                self._queue.append((-1, t_ns, json_text))

    def stats(self) -> RecorderStats:
        with self._lock:
            dropped, lost = self._dropped, self._lost
        return RecorderStats(
            written=self._written,
            dropped=dropped,
            skipped=self._skipped,
            lost=lost,
            bytes=self._bytes,
            bags=self._bags,
            stopped=self._reason,
        )

    def close(self, timeout_s: float = 30.0) -> RecorderStats:
        """Writes what is queued, closes the bag (index and metadata.yaml) and ends
        the writer thread; waits at most ``timeout_s``."""
        self._closing.set()
        self._thread.join(timeout_s)
        with self._lock:  # from now on message() and record() only count
            self._stopped = True
        return self.stats()

    # -- the writer thread ------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._typestore = get_typestore(Stores.ROS2_JAZZY)
            self._describe_inputs()
            while True:
                closing = self._closing.wait(self._poll_s)
                batch = self._take()
                if batch:
                    self._write(batch)
                self._report_drops()
                now = time.monotonic_ns()
                if self._unflushed and (
                    now - self._last_flush >= self._flush_ns
                    or self._unflushed >= self._flush_messages
                ):
                    self._flush()
                if closing and not self._queue:
                    break
            self._close_bag()
        except Exception as e:  # whatever fails ends the recording, never the daemon
            self._stop(e)

    def _describe_inputs(self) -> None:
        """Types rosbags' Jazzy store lacks come from the installed .msg files; an
        input whose type has none is left out (a msgdef-less connection would make
        rosbags' AnyReader refuse the whole bag)."""
        assert self._typestore is not None
        for i, (topic, msgtype) in enumerate(self.inputs):
            try:
                load_msg_types(self._typestore, msgtype, self._msg_prefixes)
                self._typestore.generate_msgdef(msgtype, ros_version=2)
            except Exception as e:  # rosbags raises several kinds here
                if (topic, msgtype) not in (self.inputs[j] for j in self._skip):
                    self._warn(
                        f"not recording {topic}: its type {msgtype} cannot be described ({e})"
                    )
                self._skip.add(i)

    def _take(self) -> collections.deque[tuple[int, int, bytes | str]]:
        with self._lock:  # a swap, so the callers never wait for a copy
            batch, self._queue = self._queue, collections.deque()
            self._queued = 0
            self._queued_bytes = 0
        return batch

    def _write(self, batch: collections.deque[tuple[int, int, bytes | str]]) -> None:
        assert self._typestore is not None
        offset = self.wall_offset_ns
        string_type = self._typestore.types[RECORDS_TYPE]
        for index, t_ns, data in batch:
            wall = t_ns + offset
            if index in self._skip:
                self._skipped += 1
                continue
            if isinstance(data, str):
                text = data[:-1] if data.endswith("\n") else data
                data = bytes(self._typestore.serialize_cdr(string_type(data=text), RECORDS_TYPE))
            if self._writer is None or (
                self._bag_bytes >= self._max_bag_bytes
                or wall - self._bag_start_ns >= self._max_bag_ns
            ):
                self._rotate(wall)
            assert self._writer is not None
            conn = self._records_conn if index < 0 else self._conns[index]
            assert conn is not None
            self._writer.write(conn, wall, data)
            self._written += 1
            self._unflushed += 1
            self._bytes += len(data)
            self._bag_bytes += len(data) + MESSAGE_OVERHEAD

    def _rotate(self, wall_ns: int) -> None:
        """Closes the current bag (complete: index and metadata.yaml), begins the next
        one named after ``wall_ns``, and deletes the oldest beyond ``keep``."""
        assert self._typestore is not None
        self._close_bag()
        self._seq += 1
        stamp = datetime.fromtimestamp(wall_ns // 1_000_000_000, UTC).strftime("%Y%m%dT%H%M%SZ")
        writer = Writer(
            self.directory / f"{stamp}_{self._seq:06d}",
            version=9,
            storage_plugin=StoragePlugin.MCAP,
        )
        writer.open()
        self._writer = writer
        # Every connection goes into the first chunk, so a reader of a bag cut short
        # (no summary) knows every channel before its first message. Inputs on one
        # topic (two fields of /odom) share its connection.
        by_topic: dict[tuple[str, str], Connection] = {}
        self._conns = []
        for i, key in enumerate(self.inputs):
            if i not in self._skip and key not in by_topic:
                by_topic[key] = writer.add_connection(*key, typestore=self._typestore)
            self._conns.append(by_topic.get(key))
        self._records_conn = writer.add_connection(
            RECORDS_TOPIC, RECORDS_TYPE, typestore=self._typestore
        )
        self._bag_start_ns = wall_ns
        self._bag_bytes = 0
        self._bags += 1
        for _, old in bag_dirs(self.directory)[: -self._keep]:
            shutil.rmtree(old, ignore_errors=True)

    def _flush(self) -> None:
        """Ends the pending MCAP chunk and puts it on disk: a chunk is self-contained,
        so what a kill -9 (or a power cut) leaves is readable up to here."""
        writer = self._writer
        if writer is not None and writer.storage is not None:
            # rosbags' McapWriter only ends a chunk at 1 MiB or at close, and has no
            # public flush: its chunk and file are used here (pyproject pins rosbags
            # < 0.12; tests/test_recorder.py's kill -9 test fails if they change).
            storage: Any = writer.storage
            if storage.chunk.msgs:
                storage.close_chunk()
            storage.bio.flush()
            os.fsync(storage.bio.fileno())
        self._unflushed = 0
        self._last_flush = time.monotonic_ns()

    def _close_bag(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            dropped = self._dropped
            if dropped:
                writer.set_custom_data("safety_supervisor.dropped_messages", str(dropped))
            writer.close()

    def _report_drops(self) -> None:
        dropped = self._dropped
        if dropped > self._reported_drops:
            self._warn(
                f"recording fell behind: {dropped - self._reported_drops} messages dropped "
                f"({dropped} in all; record.queue_messages is {self._max_queue})"
            )
            self._reported_drops = dropped

    def _warn(self, text: str) -> None:
        if self._on_warning is not None:
            try:
                self._on_warning(text)
            except Exception:  # the daemon's callback must not end the writer
                pass

    def _stop(self, error: BaseException) -> None:
        if isinstance(error, OSError) and error.errno is not None:
            where = f" ({error.filename})" if error.filename else ""
            reason = f"{os.strerror(error.errno)}{where}"
            if error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                reason += "; the bag is readable up to its last flushed chunk"
        else:
            reason = f"{type(error).__name__}: {error}"
        with self._lock:
            self._stopped = True
            self._lost += self._queued
            self._queue.clear()
            self._queued = 0
            self._queued_bytes = 0
        self._reason = f"recording stopped: {reason}"
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()
            except Exception:  # already stopping for a worse error
                pass
        if self._on_stopped is not None:
            try:
                self._on_stopped(self._reason)
            except Exception:  # the daemon's callback must not end the writer
                pass


def benchmark(rate_hz: float = 20_000.0, seconds: float = 2.0, size: int = 16) -> dict[str, float]:
    """Cost of ``message()`` on the caller's thread at ``rate_hz`` messages of ``size``
    bytes (paced, with the writer thread running), and the writer thread's
    throughput (a backlog of messages written as fast as it can)."""
    import tempfile

    data = bytes(size)
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder(Path(tmp) / "paced", [("/x", "std_msgs/msg/Int64")], max_bag_s=1e6)
        n = int(rate_hz * seconds)
        period = 1e9 / rate_hz
        costs = []
        start = time.perf_counter_ns()
        for i in range(n):
            due = start + i * period
            while time.perf_counter_ns() < due:
                pass
            t0 = time.perf_counter_ns()
            rec.message(0, t0, data)
            costs.append(time.perf_counter_ns() - t0)
        stats = rec.close()
        costs.sort()
        out["call_ns_median"] = costs[len(costs) // 2]
        out["call_ns_p99"] = costs[int(len(costs) * 0.99)]
        out["call_ns_p999"] = costs[int(len(costs) * 0.999)]
        out["call_ns_max"] = costs[-1]
        out["paced_written"] = stats.written
        out["paced_dropped"] = stats.dropped

        # Throughput: fill the queue first, then time how long the writer takes.
        n = 200_000
        rec = Recorder(
            Path(tmp) / "backlog",
            [("/x", "std_msgs/msg/Int64")],
            max_bag_s=1e6,
            queue_messages=n + 1,
            queue_bytes=n * size + 1,
            poll_s=3600,
        )
        t0 = time.perf_counter_ns()
        for i in range(n):
            rec.message(0, i, data)
        out["unpaced_call_ns_mean"] = (time.perf_counter_ns() - t0) / n
        t0 = time.perf_counter_ns()
        stats = rec.close()
        out["writer_msgs_per_s"] = stats.written / ((time.perf_counter_ns() - t0) / 1e9)
    return out


if __name__ == "__main__":
    for key, value in benchmark().items():
        print(f"{key:24} {value:,.0f}")
