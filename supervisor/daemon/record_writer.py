"""The recording's writer process: ``python -m supervisor.daemon.record_writer SETTINGS``.

The daemon's :class:`~supervisor.daemon.recorder.Recorder` starts it and sends it
batches of messages on its stdin; it encodes and writes them into rotating rosbag2
MCAP bags with rosbags' writer, so that none of that Python work runs in the daemon
(docs/reference/config.md, record). It reports on its stdout, one JSON object a line:
``{"stats": {...}}`` after every flush and at the end (with ``"closed": true``),
``{"warning": TEXT}``, and ``{"stopped": REASON, "lost": N}`` when a write fails.

EOF on stdin is the end: when the daemon closes the recording, and also when the
daemon dies (even by SIGKILL: the kernel closes its end of the pipe). Either way the
writer writes what it received, closes the bag (MCAP index, metadata.yaml) and exits.
SIGTERM means the same; SIGINT is ignored (the daemon stops it in order).

A batch on stdin is :func:`supervisor.daemon.recorder.frame`'s.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import select
import shutil
import signal
import sys
import time
from array import array
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_typestore

from supervisor.daemon.recorder import (
    HEAD,
    MESSAGE_OVERHEAD,
    PER_MESSAGE,
    QOS_INDEX,
    RECORDS_TOPIC,
    RECORDS_TYPE,
    bag_dirs,
)
from supervisor.inputs.rostypes import load_msg_types

if TYPE_CHECKING:
    from rosbags.interfaces import Connection, Qos

READ_SIZE = 1 << 20
POLL_S = 0.05
# rosbags writes its own name as the bag's ros_distro (metadata.yaml and the MCAP
# "rosbag2" metadata record); the daemon runs on Jazzy, whose message types it records.
ROS_DISTRO = "jazzy"
_ROSBAGS_DISTRO = re.compile(r"^(\s*)ros_distro: rosbags$", re.MULTILINE)


def jazzy(metadata: str) -> str:
    """rosbag2 metadata YAML with ``ros_distro: jazzy`` in place of rosbags' name."""
    return _ROSBAGS_DISTRO.sub(rf"\1ros_distro: {ROS_DISTRO}", metadata)


def unframe(buf: bytearray) -> tuple[list[tuple[list[tuple[int, int, bytes]], int]], int]:
    """The complete batches at the start of ``buf`` as (messages, dropped), and how
    many bytes they took."""
    out = []
    pos = 0
    with memoryview(buf) as mv:
        while len(buf) - pos >= HEAD.size:
            n, size, dropped = HEAD.unpack_from(buf, pos)
            end = pos + HEAD.size + PER_MESSAGE * n + size
            if len(buf) < end:
                break
            at = pos + HEAD.size
            times, indices, lengths = array("q"), array("i"), array("I")
            times.frombytes(mv[at : at + 8 * n])
            indices.frombytes(mv[at + 8 * n : at + 12 * n])
            lengths.frombytes(mv[at + 12 * n : at + 16 * n])
            off = at + 16 * n
            batch = []
            for index, t, length in zip(indices, times, lengths, strict=True):
                batch.append((index, t, bytes(mv[off : off + length])))
                off += length
            out.append((batch, dropped))
            pos = end
    return out, pos


_reporting = [True]


def report(obj: dict[str, Any]) -> None:
    """One line to the daemon; nothing once it is gone (the bag is closed anyway)."""
    if not _reporting[0]:
        return
    try:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()
    except (OSError, ValueError):
        _reporting[0] = False


class BagWriter:
    """The bags: rotation, keep, flushed chunks, counts (docs/reference/config.md, record)."""

    def __init__(self, settings: dict[str, Any]) -> None:
        self.directory = Path(settings["directory"])
        self.inputs = [(str(t), str(m)) for t, m in settings["inputs"]]
        self.wall_offset_ns = int(settings["wall_offset_ns"])
        self.max_bag_bytes = int(settings["max_bag_bytes"])
        self.max_bag_ns = int(settings["max_bag_ns"])
        self.keep = int(settings["keep"])
        self.flush_ns = int(settings["flush_ns"])
        self.flush_messages = int(settings["flush_messages"])
        prefixes = settings.get("msg_prefixes")
        self.msg_prefixes = None if prefixes is None else [Path(p) for p in prefixes]
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.writer: Writer | None = None
        self.conns: list[Connection | None] = []
        self.records_conn: Connection | None = None
        self.skip: set[int] = set()  # inputs whose type cannot be described
        self.bag_start_ns = 0
        self.bag_bytes = 0
        self.seq = max((n for n, _ in bag_dirs(self.directory)), default=0)
        self.unflushed = 0
        self.last_flush = time.monotonic_ns()
        self.written = 0
        self.skipped = 0
        self.bytes = 0
        self.bags = 0
        self.dropped = 0  # the daemon's count, for metadata.yaml
        self.controls = 0  # entries that were not messages (offered QoS)
        # Offered QoS by (topic, type), from the daemon's graph; a change for a topic
        # the open bag holds starts a new bag (a channel's QoS cannot change in MCAP).
        self.qos: dict[tuple[str, str], list[Qos]] = {}
        self.rotate_due = False

    def stats(self) -> dict[str, int]:
        keys = ("written", "skipped", "bytes", "bags")
        return {k: getattr(self, k) for k in keys}

    def describe_inputs(self) -> None:
        """Types rosbags' Jazzy store lacks come from the installed .msg files; an
        input whose type has none is left out (a msgdef-less connection would make
        rosbags' AnyReader refuse the whole bag)."""
        for i, (topic, msgtype) in enumerate(self.inputs):
            try:
                load_msg_types(self.typestore, msgtype, self.msg_prefixes)
                self.typestore.generate_msgdef(msgtype, ros_version=2)
            except Exception as e:  # rosbags raises several kinds here
                if (topic, msgtype) not in (self.inputs[j] for j in self.skip):
                    report(
                        {
                            "warning": f"not recording {topic}: its type {msgtype} cannot "
                            f"be described ({e})"
                        }
                    )
                self.skip.add(i)

    def write(self, batch: list[tuple[int, int, bytes]]) -> None:
        offset = self.wall_offset_ns
        string_type = self.typestore.types[RECORDS_TYPE]
        for index, t_ns, data in batch:
            wall = t_ns + offset
            if index in self.skip:
                self.skipped += 1
                continue
            if index == QOS_INDEX:
                self.set_qos(data)
                continue
            if index < 0:  # a log line: the JSON text, sent as UTF-8
                text = data.decode()
                text = text[:-1] if text.endswith("\n") else text
                data = bytes(self.typestore.serialize_cdr(string_type(data=text), RECORDS_TYPE))
            if (
                self.writer is None
                or self.rotate_due
                or self.bag_bytes >= self.max_bag_bytes
                or wall - self.bag_start_ns >= self.max_bag_ns
            ):
                self.rotate(wall)
            assert self.writer is not None
            conn = self.records_conn if index < 0 else self.conns[index] or self.connect(index)
            self.writer.write(conn, wall, data)
            self.written += 1
            self.unflushed += 1
            self.bytes += len(data)
            self.bag_bytes += len(data) + MESSAGE_OVERHEAD

    def set_qos(self, data: bytes) -> None:
        """An input's offered QoS (:meth:`Recorder.offered_qos`'s entry)."""
        self.controls += 1
        entry = json.loads(data)
        key = self.inputs[int(entry["input"])]
        profiles = parse_qos(entry["profiles"])
        if self.qos.get(key, []) == profiles:
            return
        self.qos[key] = profiles
        if self.writer is None:
            return
        held = next((c for c in self.conns if c is not None and (c.topic, c.msgtype) == key), None)
        if held is not None:
            self.rotate_due = True
        elif profiles:
            self.connect(self.inputs.index(key))

    def connect(self, index: int) -> Connection:
        """Input ``index``'s connection in the open bag, added with its topic's offered
        QoS as known now. Inputs on one topic (two fields of /odom) share it."""
        assert self.writer is not None
        key = self.inputs[index]
        conn = self.writer.add_connection(
            *key, typestore=self.typestore, offered_qos_profiles=self.qos.get(key, ())
        )
        for i, other in enumerate(self.inputs):
            if other == key:
                self.conns[i] = conn
        return conn

    def rotate(self, wall_ns: int) -> None:
        """Closes the current bag (complete: index and metadata.yaml), begins the next
        one named after ``wall_ns``, and deletes the oldest beyond ``keep``."""
        self.close_bag()
        self.seq += 1
        stamp = datetime.fromtimestamp(wall_ns // 1_000_000_000, UTC).strftime("%Y%m%dT%H%M%SZ")
        writer = Writer(
            self.directory / f"{stamp}_{self.seq:06d}",
            version=9,
            storage_plugin=StoragePlugin.MCAP,
        )
        writer.open()
        self.writer = writer
        # A topic's connection is added once its offered QoS is known (the daemon sends
        # it when it subscribes) or at its first message, whichever comes first: the
        # QoS goes into the channel record, which MCAP cannot change later. Either way
        # the channel precedes its messages in the chunk, so a reader of a bag cut
        # short (no summary) knows it; close_bag adds the topics that had neither.
        self.conns = [None] * len(self.inputs)
        self.records_conn = writer.add_connection(
            RECORDS_TOPIC, RECORDS_TYPE, typestore=self.typestore
        )
        for i, key in enumerate(self.inputs):
            if i not in self.skip and self.conns[i] is None and self.qos.get(key):
                self.connect(i)
        self.bag_start_ns = wall_ns
        self.bag_bytes = 0
        self.rotate_due = False
        self.bags += 1
        for _, old in bag_dirs(self.directory)[: -self.keep]:
            shutil.rmtree(old, ignore_errors=True)

    def flush_due(self) -> bool:
        return bool(self.unflushed) and (
            time.monotonic_ns() - self.last_flush >= self.flush_ns
            or self.unflushed >= self.flush_messages
        )

    def flush(self) -> None:
        """Ends the pending MCAP chunk and puts it on disk: a chunk is self-contained,
        so what a kill -9 (or a power cut) leaves is readable up to here."""
        writer = self.writer
        if writer is not None and writer.storage is not None:
            # rosbags' McapWriter only ends a chunk at 1 MiB or at close, and has no
            # public flush: its chunk and file are used here (pyproject pins rosbags
            # < 0.12; tests/supervisor/daemon/test_recorder.py's kill -9 test fails if they change).
            storage: Any = writer.storage
            if storage.chunk.msgs:
                storage.close_chunk()
            storage.bio.flush()
            os.fsync(storage.bio.fileno())
        self.unflushed = 0
        self.last_flush = time.monotonic_ns()

    def close_bag(self) -> None:
        if self.writer is not None:
            # Every recorded topic is listed, with 0 messages if none came (as rosbag2).
            for i in range(len(self.inputs)):
                if i not in self.skip and self.conns[i] is None:
                    self.connect(i)
        writer, self.writer = self.writer, None
        if writer is not None:
            if self.dropped:
                writer.set_custom_data("safety_supervisor.dropped_messages", str(self.dropped))
            # The metadata text goes into the MCAP file through the storage's close and
            # into metadata.yaml after it: both get rosbag2's distro name.
            storage: Any = writer.storage
            close = storage.close
            storage.close = lambda version, metadata: close(version, jazzy(metadata))
            writer.close()
            meta = writer.metapath
            tmp = meta.with_suffix(".yaml.tmp")
            tmp.write_text(jazzy(meta.read_text("utf8")), "utf8")
            tmp.replace(meta)

    def abort(self) -> None:
        writer, self.writer = self.writer, None
        if writer is not None:
            try:
                writer.abort()
            except Exception:  # already stopping for a worse error
                pass


def stop_reason(error: BaseException) -> str:
    if isinstance(error, OSError) and error.errno is not None:
        where = f" ({error.filename})" if error.filename else ""
        reason = f"{os.strerror(error.errno)}{where}"
        if error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            reason += "; the bag is readable up to its last flushed chunk"
    else:
        reason = f"{type(error).__name__}: {error}"
    return f"recording stopped: {reason}"


RECORD_NICE = 10


def run(settings: dict[str, Any], fd: int = 0) -> int:
    terminating = False

    def on_term(_signum: int, _frame: Any) -> None:
        nonlocal terminating
        terminating = True

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, on_term)
    # Recording yields to monitoring when the CPUs are busy: the daemon's loop keeps
    # its priority, and the writer catches up from its queue (or drops and counts).
    with contextlib.suppress(OSError):
        os.nice(RECORD_NICE)
    os.set_blocking(fd, False)
    buf = bytearray()
    w: BagWriter | None = None
    received = 0
    try:
        w = BagWriter(settings)
        w.describe_inputs()
        eof = False
        while not eof:
            ready, _, _ = select.select([fd], [], [], POLL_S)
            if ready or terminating:
                # Read all that is there: after SIGTERM, up to what the pipe holds.
                while True:
                    try:
                        chunk = os.read(fd, READ_SIZE)
                    except BlockingIOError:
                        eof = terminating
                        break
                    if not chunk:
                        eof = True
                        break
                    buf += chunk
            batches, used = unframe(buf)
            del buf[:used]
            for batch, dropped in batches:
                received += len(batch)
                w.dropped = dropped
                w.write(batch)
            if w.flush_due():
                w.flush()
                report({"stats": w.stats()})
        w.close_bag()  # a partial batch at the end (the daemon died mid-write) is dropped
        report({"stats": w.stats(), "closed": True})
        return 0
    except Exception as e:  # a write error ends the recording, reported once
        lost = received - (w.written + w.skipped + w.controls if w is not None else 0)
        end: dict[str, object] = {"stopped": stop_reason(e), "lost": lost}
        if w is not None:
            w.abort()
            # The counts since the last flush's report: the MCAP writer also writes a
            # full chunk on its own, so the bag may hold more than that report said.
            end["stats"] = w.stats()
        report(end)
        return 1


def main(argv: Sequence[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) != 1:
        print("usage: python -m supervisor.daemon.record_writer SETTINGS_JSON", file=sys.stderr)
        return 2
    return run(json.loads(args[0]))


if __name__ == "__main__":
    raise SystemExit(main())
