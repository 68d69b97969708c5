"""Recordings read back as a time-ordered stream of the config's input values.

Inputs (any mix, merged by receive time):

- a rosbag2 bag directory (``metadata.yaml`` and ``.db3`` or ``.mcap`` files,
  metadata version 8 or 9), or one of its storage files given directly, also an MCAP
  file whose recorder was killed before writing ``metadata.yaml`` or its summary;
- a JSON-lines trace (``.jsonl``/``.json``), one object per line::

      {"t_ns": 1500000000, "name": "speed", "value": 0.25}
      {"t_ns": 1600000000, "record": {"event": "marker", "what": "start"}}

  ``t_ns`` is a whole number of nanoseconds, not decreasing from line to line;
  ``name`` is a topic variable of the config and ``value`` a JSON value of its type
  (``true``/``false``, an integer, a number); ``record`` passes a log record through.
  Any other shape is an error naming the line.

Two ways to read (the replay engine picks): ``Recording.events()`` yields one event
per message, ``Recording.batches()`` the same data as columns of up to ``chunk``
messages. Events are ``(t_ns, topic, [(variable, value), ...])`` with every config
variable read from that topic, and ``(t_ns, "record", dict)`` for the daemon's own
JSON records recorded on ``RECORD_TOPICS`` (markers, resets, violations). Times are
the bag's receive (log) time in nanoseconds.

Damage (a truncated or corrupt file, a message that does not decode) ends the stream:
everything readable before it is yielded first, then a ``UserError`` names the file and
the position (message number, byte offset or line, last timestamp).

Speed: the bag readers here read the storage directly: sqlite3 in timestamp order
through apsw (rosbags' own SQLite binding, a fifth faster than the sqlite3 module at
fetching rows), the MCAP records with struct and numpy, since rosbags' MCAP reader
reaches about 0.5 M messages/s and refuses a file without its summary. rosbags
supplies the types: the bag's own message definitions, its CDR deserialiser for
variable-size messages, and its ROS 2 Jazzy types for bags without definitions. A primitive field (``cdr.py``: at a fixed CDR offset, or after strings and
primitive sequences whose lengths each message gives) is decoded for a whole batch with
numpy; any other field is deserialised message by message.
"""

from __future__ import annotations

import json
import mmap
import os
import struct
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any, Literal

import apsw
import numpy as np
import yaml
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from mitigations.rosmsg import COMPATIBLE
from monitors.errors import UserError
from supervisor.config.model import Config, Variable
from supervisor.daemon.cdr import PRIMITIVES, FieldPlan, field_plan
from supervisor.names import VIOLATIONS_TOPIC

# The daemon's JSON records on ROS: the full record stream (with markers) and the
# violations topic (docs/reference/ros-interfaces.md); both std_msgs/msg/String.
RECORDS_TOPIC = "/safety_supervisor/records"
RECORD_TOPICS = (RECORDS_TOPIC, VIOLATIONS_TOPIC)
STRING = "std_msgs/msg/String"
CHUNK = 100_000

ValueEvent = tuple[int, str, list[tuple[str, Any]]]
RecordEvent = tuple[int, Literal["record"], dict[str, Any]]
Event = ValueEvent | RecordEvent
Progress = Callable[[int, int | None], None]  # (messages read, total if known)
_DTYPES: dict[str, Any] = {"bool": np.bool_, "int64": np.int64, "double": np.float64}


def _field(msg: Any, path: str) -> Any:
    """A dotted field of a deserialised message (as mitigations/rosmsg.py's get_field)."""
    for part in path.split("."):
        msg = getattr(msg, part)
    return msg


def normalise_type(name: str) -> str:
    """'std_msgs/Int64', 'std_msgs::msg::Int64' -> 'std_msgs/msg/Int64'."""
    parts = [p for p in name.replace("::", "/").split("/") if p]
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    return "/".join(parts)


@dataclass
class Batch:
    """Up to ``chunk`` messages in receive order, as columns.

    Row i is a message on ``topics[topic[i]]`` received at ``t_ns[i]``. ``values[v]``
    holds variable v's value on the rows of v's topic (other rows are 0); ``records``
    are the rows of ``RECORD_TOPICS`` with their parsed record; ``given`` (JSON-lines
    traces only) marks the rows of v's topic that set v."""

    t_ns: np.ndarray  # int64
    topic: np.ndarray  # int32, index into topics
    topics: list[str]
    values: dict[str, np.ndarray]
    records: dict[int, dict[str, Any]] = field(default_factory=dict)
    # A JSON-lines line sets one variable of its topic: given[v] marks the rows that
    # set v. A variable not in given has a value on every row of its topic.
    given: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_ns)

    def rows(self, topic: str) -> np.ndarray:
        """The row mask of one topic."""
        return self.topic == self.topics.index(topic)


@dataclass
class _Raw:
    """Messages of one source as read: receive times, topic ids and the payloads,
    message i's being ``buf[start[i]:end[i]]`` (one buffer, so that a fixed field
    is gathered for all messages at once); a JSON-lines trace has ``items``."""

    t_ns: np.ndarray  # int64
    topic: np.ndarray  # int32, index into Recording.topics
    buf: bytes = b""
    start: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    end: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    items: list[Any] | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    def payload(self, i: int) -> bytes:
        return self.buf[self.start[i] : self.end[i]]

    def part(self, i: int, j: int) -> _Raw:
        items = self.items[i:j] if self.items is not None else None
        return _Raw(
            self.t_ns[i:j], self.topic[i:j], self.buf, self.start[i:j], self.end[i:j], items
        )

    def in_order(self) -> _Raw:
        """Sorted by receive time (stable: equal times keep the file's order)."""
        if len(self.t_ns) < 2 or bool((np.diff(self.t_ns) >= 0).all()):
            return self
        o = np.argsort(self.t_ns, kind="stable")
        items = [self.items[i] for i in o] if self.items is not None else None
        return _Raw(self.t_ns[o], self.topic[o], self.buf, self.start[o], self.end[o], items)


def _raw(ts: list[int], topics: list[int], payloads: list[bytes]) -> _Raw:
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
    end = np.cumsum(lengths)
    return _Raw(
        np.asarray(ts, dtype=np.int64),
        np.asarray(topics, dtype=np.int32),
        b"".join(payloads),
        end - lengths,
        end,
    )


class _Damage(Exception):
    """A source ends here; its message locates the damage (the source adds the file)."""


@dataclass
class _TopicReader:
    """How one topic's payloads become values."""

    topic: str
    msgtype: str
    variables: list[Variable]
    plans: list[FieldPlan | None]  # None: deserialise each message
    record: bool = False
    # Per variable, the column's numpy dtype: the field's own type, so that a value
    # the variable's type cannot hold (a uint64 above 2^63-1) reaches the runtime as
    # it is and is rejected there, as the daemon rejects it.
    dtypes: list[Any] = field(default_factory=list)


class _Source:
    """One file or bag directory: its topics and a stream of raw chunks."""

    label: str
    topics: dict[str, str]  # topic -> recorded type
    counts: dict[str, int] | None  # messages per topic, when the bag's metadata says
    store: Typestore

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[_Raw]:
        raise NotImplementedError


def _typestore(defs: list[tuple[str, str, str]]) -> Typestore:
    """Types from the recording's own definitions (name, encoding, text); rosbags'
    Jazzy types fill in what a recording does not define."""
    types: dict[str, Any] = {}
    for name, encoding, text in defs:
        if not text:
            continue
        try:
            if encoding in ("ros2idl", "idl"):
                sep = "=" * 80 + "\n"
                parts = text.split(sep)[1:] if text.startswith(f"{sep}IDL: ") else [text]
                for part in parts:
                    types.update(
                        get_types_from_idl(
                            part.split("\n", 1)[1] if part.startswith("IDL: ") else part
                        )
                    )
            else:
                types.update(get_types_from_msg(text, normalise_type(name)))
        except Exception:  # noqa: BLE001 - a definition rosbags cannot parse: use Jazzy's
            continue
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    store.register({k: v for k, v in jazzy.fielddefs.items() if k not in store.fielddefs})
    return store


# --- sqlite3 storage ------------------------------------------------------------------


class _Sqlite(_Source):
    def __init__(self, path: Path, counts: dict[str, int] | None = None) -> None:
        self.path = path
        self.label = str(path)
        self.counts = counts
        self._tmp: Path | None = None
        self._cut = False  # truncated: read a copy whose header counts the pages present
        try:
            con = self._connect()
            rows = con.execute("SELECT id, name, type FROM topics").fetchall()
        except apsw.Error:
            # A truncated file: its header still counts the lost pages, which makes
            # sqlite refuse it whole. A copy that counts only the pages present reads
            # up to the damage.
            self._cut = True
            con = self._connect()
            try:
                rows = con.execute("SELECT id, name, type FROM topics").fetchall()
            except apsw.Error as e:
                con.close()
                self._drop()
                raise UserError(
                    f"not a readable rosbag2 sqlite3 file ({e})", file=self.label
                ) from None
        self._ids = {tid: name for tid, name, _ in rows}
        self.topics = {name: normalise_type(typ) for _, name, typ in rows}
        defs: list[tuple[str, str, str]] = []
        try:
            defs = con.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ).fetchall()
        except apsw.Error:
            pass  # bags before version 8 have no definitions
        con.close()
        self._drop()
        self.store = _typestore(defs)

    def _connect(self) -> apsw.Connection:
        path = self._patched() if self._cut else self.path
        return apsw.Connection(str(path), flags=apsw.SQLITE_OPEN_READONLY)

    def _drop(self) -> None:
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None

    def _patched(self) -> Path:
        data = bytearray(self.path.read_bytes())
        if len(data) < 100 or not data.startswith(b"SQLite format 3\x00"):
            raise UserError("not an sqlite3 file", file=self.label)
        size = struct.unpack_from(">H", data, 16)[0]
        page = 65536 if size == 1 else size
        pages = len(data) // page
        del data[pages * page :]
        struct.pack_into(">I", data, 28, pages)
        fd, name = tempfile.mkstemp(suffix=".db3")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        self._tmp = Path(name)
        return self._tmp

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[_Raw]:
        wanted = {tid: ids[name] for tid, name in self._ids.items() if name in ids}
        # Only the wanted topics' rows: the extra topics' payloads are never fetched.
        marks = ",".join("?" * len(wanted))
        query = (
            f"SELECT timestamp, topic_id, data FROM messages WHERE topic_id IN ({marks}) "
            "ORDER BY timestamp"
        )
        n, last = 0, None
        con = self._connect()
        try:
            lut = np.full(max(wanted, default=0) + 1, -1, dtype=np.int32)
            for tid, k in wanted.items():
                lut[tid] = k
            try:
                cur = con.execute(query, list(wanted))
                while rows := list(islice(cur, chunk)):
                    ts, tids, data = zip(*rows, strict=True)
                    n += len(rows)
                    last = ts[-1]
                    raw = _raw(list(ts), [], list(data))
                    raw.topic = lut[np.asarray(tids, dtype=np.int64)]
                    yield raw
                return
            except apsw.Error:
                pass
            # A failed read loses its chunk's rows: read them again one by one up to the
            # damage, so that every readable message is replayed.
            ts_: list[int] = []
            tops: list[int] = []
            data_: list[bytes] = []
            try:
                cur = con.execute(f"{query} LIMIT -1 OFFSET ?", [*wanted, n])
                while row := cur.fetchone():
                    ts_.append(row[0])
                    tops.append(wanted[row[1]])
                    data_.append(row[2])
                    last = row[0]
            except apsw.Error as e:
                if ts_:
                    yield _raw(ts_, tops, data_)
                n += len(ts_)
                where = f"{n} messages read" + (
                    f", the last at t_ns {last}" if last is not None else ""
                )
                raise _Damage(f"damaged database ({e}); {where}") from None
            if ts_:
                yield _raw(ts_, tops, data_)
        finally:
            con.close()
            self._drop()


# --- MCAP storage ---------------------------------------------------------------------
# The records are read here with struct and numpy (format: https://mcap.dev/spec): the
# `mcap` package's reader decodes every message record in Python (about 0.3 M/s), and
# the chunk's message index gives every message's time and place at once.

MAGIC = b"\x89MCAP0\r\n"
_REC = struct.Struct("<BQ")  # opcode, length
_MSG = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_MSG_HEAD = 9 + _MSG.size  # record header + message header: the payload's offset
SCHEMA, CHANNEL, MESSAGE, CHUNK_OP, MESSAGE_INDEX, FOOTER, DATA_END = 3, 4, 5, 6, 7, 2, 15
STATISTICS = 11
_INDEX = np.dtype([("t", "<u8"), ("o", "<u8")])


def _string(buf: Any, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    return bytes(buf[pos + 4 : pos + 4 + n]).decode(), pos + 4 + n


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    try:
        if compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        if compression == "lz4":
            import lz4.frame

            return lz4.frame.decompress(data)
    except Exception as e:  # noqa: BLE001 - any failure here is a damaged chunk
        raise _Damage(f"a {compression} chunk does not decompress ({e})") from None
    if compression:
        raise _Damage(f"a chunk is compressed with '{compression}', which is not supported")
    return data


class _Mcap(_Source):
    """An MCAP file read from the start, record by record, so that a file without its
    summary (a recorder killed) reads up to where it ends."""

    def __init__(
        self,
        path: Path,
        counts: dict[str, int] | None = None,
        topics: dict[str, str] | None = None,
    ) -> None:
        self.path = path
        self.label = str(path)
        self.counts = counts
        self._schemas: dict[int, tuple[str, str, str]] = {}
        self._channels: dict[int, tuple[str, int]] = {}
        self.topics = dict(topics or {})
        if not self._summary():
            # No summary (a recorder killed): a pass over the file finds the channels,
            # skipping chunks whose indexes name known channels only.
            try:
                for _ in self._records({}, head=True):
                    pass
            except _Damage as e:
                if not self.topics:
                    raise UserError(f"not a readable MCAP file: {e}", file=self.label) from None
        self.store = _typestore(list(self._schemas.values()))

    def _summary(self) -> bool:
        """Every schema and channel (and the message counts) from the summary at the
        end of the file, if it has an intact one."""
        try:
            with self.path.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                return self._summary_of(mm, len(mm))
        except (OSError, ValueError):
            return False  # empty or unreadable: the pass over the file says why

    def _summary_of(self, mm: mmap.mmap, size: int) -> bool:
        foot = size - len(MAGIC) - 9 - 20
        if foot < len(MAGIC) or mm[:8] != MAGIC or mm[size - len(MAGIC) :] != MAGIC:
            return False
        op, length = _REC.unpack_from(mm, foot)
        (start,) = struct.unpack_from("<Q", mm, foot + 9)
        if op != FOOTER or length != 20 or not len(MAGIC) <= start < foot:
            return False
        counts: dict[str, int] = {}
        stats: list[tuple[int, int]] = []
        pos = start
        try:
            while pos + 9 <= foot:
                op, length = _REC.unpack_from(mm, pos)
                body = pos + 9
                if body + length > foot:
                    return False
                if op == SCHEMA:
                    self._schema(mm, body)
                elif op == CHANNEL:
                    self._channel(mm, body)
                elif op == STATISTICS:
                    (n,) = struct.unpack_from("<I", mm, body + 42)
                    stats = list(struct.iter_unpack("<HQ", mm[body + 46 : body + 46 + n]))
                pos = body + length
        except (struct.error, UnicodeDecodeError):
            return False
        for cid, n in stats:
            if cid in self._channels:
                topic = self._channels[cid][0]
                counts[topic] = counts.get(topic, 0) + n
        if self.counts is None and stats:
            self.counts = counts
        return True

    def _schema(self, buf: Any, pos: int) -> None:
        (sid,) = struct.unpack_from("<H", buf, pos)
        name, pos = _string(buf, pos + 2)
        encoding, pos = _string(buf, pos)
        (n,) = struct.unpack_from("<I", buf, pos)
        self._schemas[sid] = (
            name,
            encoding,
            bytes(buf[pos + 4 : pos + 4 + n]).decode("utf-8", "replace"),
        )

    def _channel(self, buf: Any, pos: int) -> None:
        cid, sid = struct.unpack_from("<HH", buf, pos)
        topic, _ = _string(buf, pos + 4)
        self._channels[cid] = (topic, sid)
        if sid in self._schemas:
            self.topics.setdefault(topic, normalise_type(self._schemas[sid][0]))

    def _records(self, ids: dict[str, int], head: bool = False) -> Iterator[_Raw]:
        """The wanted messages, chunk by chunk; with head, only the types up to the
        first message."""
        try:
            f = self.path.open("rb")
        except OSError as e:
            raise _Damage(e.strerror or str(e)) from None
        with f:
            size = os.fstat(f.fileno()).st_size
            if size < len(MAGIC):
                raise _Damage(
                    "the file is empty" if not size else "the file ends early (at byte 0)"
                )
            mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            try:
                if mm[: len(MAGIC)] != MAGIC:
                    raise _Damage("not an MCAP file (no MCAP magic at its start)")
                yield from self._data_section(mm, size, ids, head)
            finally:
                mm.close()

    def _data_section(
        self, mm: mmap.mmap, size: int, ids: dict[str, int], head: bool
    ) -> Iterator[_Raw]:
        self._count = 0
        self._last_t: int | None = None
        pos = len(MAGIC)
        pending: tuple[int, int] | None = None  # the last chunk, until its indexes are read
        indexes: dict[int, np.ndarray] = {}
        loose: tuple[list[int], list[int], list[bytes]] = ([], [], [])
        try:
            while True:
                if pos + 9 > size:
                    raise _Damage("the file ends early")
                op, length = _REC.unpack_from(mm, pos)
                body = pos + 9
                if body + length > size:
                    raise _Damage(f"the record at byte {pos} is cut short: the file ends early")
                if op == MESSAGE_INDEX and pending is not None:
                    (cid,) = struct.unpack_from("<H", mm, body)
                    (n,) = struct.unpack_from("<I", mm, body + 2)
                    indexes[cid] = np.frombuffer(mm, _INDEX, n // 16, body + 6).copy()
                else:
                    if pending is not None:
                        if head:
                            self._head_chunk(mm, pending, indexes)
                        else:
                            yield from self._chunk(mm, pending, indexes, ids)
                        pending, indexes = None, {}
                    if op == SCHEMA:
                        self._schema(mm, body)
                    elif op == CHANNEL:
                        self._channel(mm, body)
                    elif op == MESSAGE:
                        cid, _, t, _ = _MSG.unpack_from(mm, body)
                        self._count += 1
                        self._last_t = t
                        k = ids.get(self._channels.get(cid, ("", 0))[0], -1)
                        if k >= 0:
                            loose[0].append(t)
                            loose[1].append(k)
                            loose[2].append(mm[body + _MSG.size : body + length])
                    elif op == CHUNK_OP:
                        if loose[0]:
                            yield _raw(*loose).in_order()
                            loose = ([], [], [])
                        pending = (pos, body)
                    elif op in (DATA_END, FOOTER):
                        break
                pos = body + length
        except _Damage as e:
            # the last whole chunk is readable even without its indexes
            if pending is not None:
                yield from self._chunk(mm, pending, {}, ids)
            if loose[0]:
                yield _raw(*loose).in_order()
            where = f"after byte {pos}, {self._count} messages read"
            if self._last_t is not None:
                where += f", the last at t_ns {self._last_t}"
            raise _Damage(f"damaged: {e} ({where})") from None
        except (struct.error, ValueError, UnicodeDecodeError) as e:
            raise _Damage(f"damaged: a malformed record at byte {pos} ({e})") from None
        if pending is not None:
            yield from self._chunk(mm, pending, indexes, ids)
        if loose[0]:
            yield _raw(*loose).in_order()

    def _chunk(
        self,
        mm: mmap.mmap,
        at: tuple[int, int],
        indexes: dict[int, np.ndarray],
        ids: dict[str, int],
    ) -> Iterator[_Raw]:
        pos, body = at
        _, _, usize, _ = struct.unpack_from("<QQQI", mm, body)
        compression, p = _string(mm, body + 28)
        (n,) = struct.unpack_from("<Q", mm, p)
        buf = _decompress(compression, mm[p + 8 : p + 8 + n], usize)
        if indexes and all(c in self._channels for c in indexes):
            raw = self._indexed(buf, indexes, ids)
        else:
            raw = self._scan(buf, ids, pos)
        if len(raw):
            yield raw.in_order()

    def _head_chunk(
        self, mm: mmap.mmap, at: tuple[int, int], indexes: dict[int, np.ndarray]
    ) -> None:
        """The schemas and channels a chunk defines, if its indexes name new ones."""
        if indexes and all(c in self._channels for c in indexes):
            return
        for _ in self._chunk(mm, at, {}, {}):
            pass

    def _indexed(self, buf: bytes, indexes: dict[int, np.ndarray], ids: dict[str, int]) -> _Raw:
        """Every message's time and place from the chunk's indexes, with numpy."""
        self._count += sum(len(ix) for ix in indexes.values())
        lasts = [int(ix["t"].max()) for ix in indexes.values() if len(ix)]
        if lasts:
            self._last_t = max(lasts)
        want = [
            (ix, ids[self._channels[c][0]])
            for c, ix in indexes.items()
            if self._channels[c][0] in ids
        ]
        if not want:
            return _Raw(np.empty(0, np.int64), np.empty(0, np.int32))
        t = np.concatenate([ix["t"] for ix, _ in want]).astype(np.int64)
        o = np.concatenate([ix["o"] for ix, _ in want]).astype(np.int64)
        top = np.concatenate([np.full(len(ix), k, np.int32) for ix, k in want])
        order = np.lexsort((o, t))  # by time, then as written
        t, o, top = t[order], o[order], top[order]
        arr = np.frombuffer(buf, np.uint8)
        if len(o) and (o.max() + _MSG_HEAD > len(arr) or (arr[o] != MESSAGE).any()):
            raise _Damage("a message index points outside its chunk's messages")
        lengths = arr[(o + 1)[:, None] + np.arange(8)].copy().view("<u8").reshape(len(o))
        end = o + 9 + lengths.astype(np.int64)
        if len(end) and end.max() > len(arr):
            raise _Damage("a message in a chunk is cut short")
        return _Raw(t, top, buf, o + _MSG_HEAD, end)

    def _scan(self, buf: bytes, ids: dict[str, int], at: int) -> _Raw:
        """A chunk without indexes, record by record."""
        ts: list[int] = []
        tops: list[int] = []
        starts: list[int] = []
        ends: list[int] = []
        cmap: dict[int, int] = {}
        pos, size = 0, len(buf)
        while pos + 9 <= size:
            op, length = _REC.unpack_from(buf, pos)
            body = pos + 9
            if body + length > size:
                raise _Damage(f"a record in the chunk at byte {at} is cut short")
            if op == MESSAGE:
                cid, _, t, _ = _MSG.unpack_from(buf, body)
                self._count += 1
                self._last_t = t
                if cid not in cmap:
                    cmap[cid] = ids.get(self._channels.get(cid, ("", 0))[0], -1)
                if cmap[cid] >= 0:
                    ts.append(t)
                    tops.append(cmap[cid])
                    starts.append(body + _MSG.size)
                    ends.append(body + length)
            elif op == SCHEMA:
                self._schema(buf, body)
            elif op == CHANNEL:
                self._channel(buf, body)
                cmap.clear()
            pos = body + length
        return _Raw(
            np.asarray(ts, np.int64),
            np.asarray(tops, np.int32),
            buf,
            np.asarray(starts, np.int64),
            np.asarray(ends, np.int64),
        )

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[_Raw]:
        return self._records(ids)


# --- rosbag2 directories --------------------------------------------------------------


def _bag_dir(path: Path) -> list[_Source]:
    meta = path / "metadata.yaml"
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as e:
        raise UserError(f"not a readable rosbag2 metadata file ({e})", file=str(meta)) from None
    if info.get("compression_mode") and info.get("compression_format"):
        raise UserError(
            f"compressed bag ({info['compression_format']}, per {info['compression_mode'].lower()})",
            file=str(path),
            hint="decompress it: ros2 bag convert",
        )
    topics = {
        t["topic_metadata"]["name"]: normalise_type(t["topic_metadata"]["type"])
        for t in info.get("topics_with_message_count") or []
    }
    files = [path / p for p in info.get("relative_file_paths") or []]
    if not files:
        files = sorted([*path.glob("*.mcap"), *path.glob("*.db3")])
    counts = {
        t["topic_metadata"]["name"]: int(t.get("message_count") or 0)
        for t in info.get("topics_with_message_count") or []
    }
    sources: list[_Source] = []
    for k, f in enumerate(files):
        if not f.exists():
            raise UserError(f"the bag's file {f.name} is missing", file=str(path))
        # the bag's counts are per topic over all its files: give them to the first
        part = counts if k == 0 else {}
        sources.append(_Mcap(f, part, topics) if f.suffix == ".mcap" else _Sqlite(f, part))
    return sources


# --- JSON-lines traces ----------------------------------------------------------------


class _Trace(_Source):
    def __init__(self, path: Path, cfg: Config) -> None:
        self.path = path
        self.label = str(path)
        self.counts = None
        self.store = get_typestore(Stores.EMPTY)
        self.vars = {v.name: v for v in cfg.inputs if v.topic}
        self.topics = {v.topic: normalise_type(v.msg or "") for v in self.vars.values() if v.topic}
        self.topics[RECORDS_TOPIC] = STRING

    def _value(self, v: Variable, value: Any) -> Any:
        ok = {
            "bool": isinstance(value, bool),
            "int64": isinstance(value, int)
            and not isinstance(value, bool)
            and -(2**63) <= value < 2**63,
            "double": isinstance(value, int | float) and not isinstance(value, bool),
        }[v.type]
        if not ok:
            raise ValueError(f"'{v.name}' is {v.type}; {json.dumps(value)} is not")
        return float(value) if v.type == "double" else value

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[_Raw]:
        ts: list[int] = []
        tops: list[int] = []
        items: list[Any] = []

        def out() -> _Raw:
            return _Raw(np.asarray(ts, np.int64), np.asarray(tops, np.int32), items=items)

        last = -1
        try:
            f = self.path.open(encoding="utf-8")
        except OSError as e:
            raise UserError(f"cannot read the trace ({e.strerror})", file=self.label) from None
        with f:
            for lineno, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    t, topic, item = self._line(line)
                    if t < last:
                        raise ValueError(f"t_ns {t} is before the previous line's {last}")
                except ValueError as e:
                    if ts:
                        yield out()
                    raise _Damage(f"line {lineno}: {e}") from None
                last = t
                if topic in ids:
                    ts.append(t)
                    tops.append(ids[topic])
                    items.append(item)
                if len(ts) >= chunk:
                    yield out()
                    ts, tops, items = [], [], []
        if ts:
            yield out()

    def _line(self, line: str) -> tuple[int, str, Any]:
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as e:
            raise ValueError(f"not JSON ({e.msg}, column {e.colno})") from None
        schema = '{"t_ns": N, "name": VARIABLE, "value": V} or {"t_ns": N, "record": {...}}'
        if not isinstance(obj, dict) or set(obj) not in (
            {"t_ns", "name", "value"},
            {"t_ns", "record"},
        ):
            raise ValueError(f"expected {schema}, got {line.strip()[:80]}")
        t = obj["t_ns"]
        if not isinstance(t, int) or isinstance(t, bool) or t < 0:
            raise ValueError(
                f"t_ns must be a whole number of nanoseconds >= 0, got {json.dumps(t)}"
            )
        if "record" in obj:
            if not isinstance(obj["record"], dict):
                raise ValueError("record must be a JSON object")
            return t, RECORDS_TOPIC, obj["record"]
        name = obj["name"]
        v = self.vars.get(name) if isinstance(name, str) else None
        if v is None or v.topic is None:
            known = ", ".join(self.vars) or "none"
            raise ValueError(
                f"{json.dumps(name)} is not a topic variable of the config (known: {known})"
            )
        return t, v.topic, (name, self._value(v, obj["value"]))


# --- the recording --------------------------------------------------------------------


def _column_dtype(leaf: str, vtype: str) -> Any:
    """A column for a field of ROS type ``leaf``: its own numpy type (bool for a bool)."""
    if leaf == "bool":
        return np.bool_
    prim = PRIMITIVES.get(leaf)
    return np.dtype(prim[1].lstrip("<")) if prim is not None else _DTYPES[vtype]


def _leaf_type(store: Typestore, msgtype: str, path: str) -> str:
    """The primitive type at a dotted path of msgtype, from the recording's types."""
    typ = msgtype
    parts = path.split(".")
    for i, part in enumerate(parts):
        fields = dict(store.fielddefs[typ][1])
        if part not in fields:
            raise UserError(f"{typ} has no field '{part}' (fields: {', '.join(fields) or 'none'})")
        kind, detail = fields[part]
        last = i == len(parts) - 1
        if kind == Nodetype.BASE and last:
            return "boolean" if detail[0] == "bool" else detail[0]
        if kind == Nodetype.NAME and not last:
            typ = detail
            continue
        raise UserError(f"field '{'.'.join(parts[: i + 1])}' of {msgtype} is not a number or bool")
    raise AssertionError("unreachable")


class Recording:
    """Recordings opened for a config; see the module docstring."""

    def __init__(self, sources: list[_Source], cfg: Config) -> None:
        self.sources = sources
        self.cfg = cfg
        self.warnings: list[str] = []
        by_topic: dict[str, list[Variable]] = {}
        for v in cfg.inputs:
            if v.topic:
                by_topic.setdefault(v.topic, []).append(v)
        recorded: dict[str, str] = {}
        self.ignored: dict[str, set[str]] = {}
        for src in sources:
            for topic, typ in src.topics.items():
                if topic in by_topic:
                    want = normalise_type(by_topic[topic][0].msg or "")
                    if typ != want:
                        v = by_topic[topic][0]
                        raise UserError(
                            f"topic {topic} is recorded as {typ}, but the config reads it as {want}",
                            file=src.label,
                            hint=f"variable '{v.name}' at {cfg.path}:{v.line}",
                        )
                    recorded[topic] = typ
                elif topic == VIOLATIONS_TOPIC and RECORDS_TOPIC in src.topics:
                    # the same violations are on the records topic beside it
                    self.ignored.setdefault(src.label, set()).add(topic)
                elif topic in RECORD_TOPICS:
                    if typ != STRING:
                        raise UserError(
                            f"topic {topic} is recorded as {typ}, not {STRING}", file=src.label
                        )
                    recorded[topic] = typ
                else:
                    self.ignored.setdefault(src.label, set()).add(topic)
        missing = [t for t in by_topic if t not in recorded]
        for t in missing:
            names = [v.name for v in by_topic[t]]
            no_initial = [v.name for v in by_topic[t] if v.initial is None]
            text = f"warning: topic {t} ({', '.join(names)}) is in none of the recordings"
            if no_initial:
                text += f"; {', '.join(no_initial)} without 'initial:' never get a value, so the monitor never steps"
            self.warnings.append(text)
        self.topics = sorted(recorded)
        self.ids = {t: i for i, t in enumerate(self.topics)}
        self.by_topic = by_topic
        # the messages to read, if every source's metadata counts them
        self.total: int | None = None
        if all(s.counts is not None for s in sources):
            self.total = sum(
                n for s in sources for t, n in (s.counts or {}).items() if t in recorded
            )
        # Fields are checked against the recorded types now, before anything is read.
        self._topic_readers = [self._readers(s) for s in sources]

    def summary(self) -> str:
        """What is read and what is not, a line each."""
        lines = [f"reading {len(self.topics)} topic(s): {', '.join(self.topics) or 'none'}"]
        for label, topics in self.ignored.items():
            lines.append(f"{label}: ignored (not in the config): {', '.join(sorted(topics))}")
        return "\n".join([*lines, *self.warnings])

    def _readers(self, src: _Source) -> dict[int, _TopicReader]:
        out: dict[int, _TopicReader] = {}
        for topic, tid in self.ids.items():
            if topic not in src.topics:
                continue
            if topic in RECORD_TOPICS:
                out[tid] = _TopicReader(topic, STRING, [], [], record=True)
                continue
            variables = self.by_topic[topic]
            msgtype = src.topics[topic]
            plans: list[FieldPlan | None] = []
            dtypes: list[Any] = []
            for v in variables:
                if isinstance(src, _Trace):
                    plans.append(None)
                    dtypes.append(_DTYPES[v.type])
                    continue
                try:
                    leaf = _leaf_type(src.store, msgtype, v.field)
                except UserError as e:
                    raise UserError(f"topic {topic}: {e.message}", file=src.label) from None
                except KeyError as e:
                    raise UserError(
                        f"topic {topic}: type {e} is not defined in the recording", file=src.label
                    ) from None
                if leaf not in COMPATIBLE[v.type]:
                    raise UserError(
                        f"topic {topic}: field '{v.field}' of {msgtype} is {leaf}, which cannot feed the {v.type} variable '{v.name}'",
                        file=src.label,
                    )
                plans.append(field_plan(src.store, msgtype, v.field))
                dtypes.append(_column_dtype(leaf, v.type))
            out[tid] = _TopicReader(topic, msgtype, variables, plans, dtypes=dtypes)
        return out

    def _decode(
        self, src: _Source, readers: dict[int, _TopicReader], raw: _Raw, first: int
    ) -> tuple[Batch, str | None]:
        """Columns of one raw chunk; on a message that does not decode, the columns
        of the messages before it and the located error."""
        n = len(raw)
        top = raw.topic
        arr = np.frombuffer(raw.buf, np.uint8)
        values: dict[str, np.ndarray] = {}
        records: dict[int, dict[str, Any]] = {}
        given: dict[str, np.ndarray] = {}
        bad = n
        error: str | None = None

        def fail(i: int, topic: str, what: str) -> None:
            nonlocal bad, error
            if i < bad:
                t = int(raw.t_ns[i])
                bad, error = i, f"message {first + i + 1} read (topic {topic}, t_ns {t}) {what}"

        for tid, rd in readers.items():
            rows = np.flatnonzero(top == tid)
            if not len(rows):
                continue
            if raw.items is not None:  # a JSON-lines trace: values already checked
                for i in rows.tolist():
                    item = raw.items[i]
                    if rd.record:
                        records[i] = item
                for v in rd.variables:
                    col = np.zeros(n, dtype=_DTYPES[v.type])
                    mask = np.zeros(n, dtype=np.bool_)
                    for i in rows.tolist():
                        name, value = raw.items[i]
                        if name == v.name:
                            col[i], mask[i] = value, True
                    values[v.name], given[v.name] = col, mask
                continue
            if rd.record:
                for i in rows.tolist():
                    try:
                        records[i] = self._record(src, raw.payload(i))
                    except ValueError as e:
                        fail(i, rd.topic, str(e))
                        break
                continue
            slow: list[Variable] = []
            for j, (v, plan) in enumerate(zip(rd.variables, rd.plans, strict=True)):
                got = plan.gather(arr, raw.start[rows], raw.end[rows]) if plan else None
                if (
                    got is not None
                    and not plan.fixed
                    and not self._agrees(src, rd, v, raw, rows, got)
                ):  # type: ignore[union-attr]
                    rd.plans[j] = None  # the layout guess is wrong for this data
                    got = None
                if got is None:
                    slow.append(v)
                    continue
                col = np.zeros(n, dtype=rd.dtypes[j])
                col[rows] = got != 0 if col.dtype == np.bool_ else got
                values[v.name] = col
            if slow:
                # One deserialisation per message for all of the topic's other fields.
                dtype_of = dict(zip((v.name for v in rd.variables), rd.dtypes, strict=True))
                cols = {v.name: np.zeros(n, dtype=dtype_of[v.name]) for v in slow}
                for i in rows.tolist():
                    if i >= bad:
                        break
                    try:
                        msg = src.store.deserialize_cdr(raw.payload(i), rd.msgtype)
                        for v in slow:
                            cols[v.name][i] = _field(msg, v.field)
                    except Exception as e:  # noqa: BLE001 - any failure here is the data's
                        fail(i, rd.topic, f"does not decode as {rd.msgtype} ({e})")
                        break
                values.update(cols)
        batch = Batch(
            raw.t_ns[:bad],
            top[:bad],
            self.topics,
            {k: c[:bad] for k, c in values.items()},
            {i: r for i, r in records.items() if i < bad},
            {k: m[:bad] for k, m in given.items()},
        )
        return batch, error

    @staticmethod
    def _agrees(
        src: _Source, rd: _TopicReader, v: Variable, raw: _Raw, rows: np.ndarray, got: np.ndarray
    ) -> bool:
        """A bulk read past strings and sequences, checked against rosbags'
        deserialiser on a few messages (first, middle, last)."""
        for k in {0, len(rows) // 2, len(rows) - 1}:
            try:
                want = _field(
                    src.store.deserialize_cdr(raw.payload(int(rows[k])), rd.msgtype), v.field
                )
            except Exception:  # noqa: BLE001 - the per-message path will locate it
                return False
            if want != got[k] and not (want != want and got[k] != got[k]):  # NaN == NaN here
                return False
        return True

    @staticmethod
    def _record(src: _Source, payload: bytes) -> dict[str, Any]:
        try:
            text = src.store.deserialize_cdr(payload, STRING).data  # type: ignore[attr-defined]
        except Exception as e:  # noqa: BLE001
            raise ValueError(f"does not decode as {STRING}: {e}") from None
        try:
            rec = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"not a JSON record ({e.msg})") from None
        if not isinstance(rec, dict):
            raise ValueError("not a JSON object")
        return rec

    def _source_batches(self, src: _Source, chunk: int) -> Iterator[Batch | UserError]:
        """One source's batches; damage ends them with the located error."""
        readers = self._topic_readers[self.sources.index(src)]
        ids = {
            t: self.ids[t]
            for t in src.topics
            if t in self.ids and t not in self.ignored.get(src.label, ())
        }
        first = 0
        last = -1
        try:
            for whole in src.chunks(ids, chunk):
                for i in range(0, len(whole), chunk):
                    raw = whole.part(i, i + chunk)
                    batch, error = self._decode(src, readers, raw, first)
                    first += len(raw)
                    if len(batch):
                        if int(batch.t_ns[0]) < last:
                            self._warn_order(src, last)
                        last = int(batch.t_ns[-1])
                        yield batch
                    if error:
                        yield UserError(error, file=src.label)
                        return
        except _Damage as e:
            yield UserError(str(e), file=src.label)
        except UserError as e:
            yield e

    def _warn_order(self, src: _Source, t: int) -> None:
        text = (
            f"warning: {src.label}: messages before t_ns {t} come after it in the file; "
            "they are replayed in file order"
        )
        if text.split(" before ")[0] not in "\n".join(self.warnings):
            self.warnings.append(text)

    def batches(self, chunk: int = CHUNK, progress: Progress | None = None) -> Iterator[Batch]:
        """Columns of up to ``chunk`` messages in receive order across all sources;
        raises the located UserError after the last readable batch.

        A damaged source ends the stream at its last readable message: the other
        sources' later messages are not yielded, so what is replayed is a gapless
        prefix of the recording."""
        gens = [self._source_batches(s, chunk) for s in self.sources]
        bufs: list[Batch | None] = [None] * len(gens)
        last = [-1] * len(gens)
        live = set(range(len(gens)))
        error: UserError | None = None
        stop_at: int | None = None
        done = 0
        while True:
            for k in sorted(live):
                if bufs[k] is not None:
                    continue
                item = next(gens[k], None)
                if isinstance(item, UserError):
                    live.discard(k)
                    if stop_at is None or last[k] < stop_at:
                        stop_at, error = last[k], item
                elif item is None:
                    live.discard(k)
                else:
                    bufs[k], last[k] = item, int(item.t_ns[-1])
            have = [k for k, b in enumerate(bufs) if b is not None]
            if not have:
                break
            # Rows up to the earliest last time of the sources still reading are final:
            # none of them can deliver an earlier message any more.
            bound = min((last[k] for k in live), default=None)
            if stop_at is not None:
                bound = stop_at if bound is None else min(bound, stop_at)
            parts = []
            for k in have:
                b = bufs[k]
                assert b is not None
                cut = len(b) if bound is None else int(np.searchsorted(b.t_ns, bound, side="right"))
                parts.append(_slice(b, 0, cut))
                bufs[k] = _slice(b, cut, len(b)) if cut < len(b) else None
            out = _merge(parts)
            if out is not None:
                done += len(out)
                yield out
                if progress:
                    progress(done, self.total)
            if stop_at is not None and bound == stop_at:
                break
        if error is not None:
            raise error

    def events(self, chunk: int = CHUNK, progress: Progress | None = None) -> Iterator[Event]:
        """One event per message in receive order: ``(t_ns, topic, [(var, value)])``
        or ``(t_ns, "record", dict)``; raises the located UserError after the last
        readable event."""
        names = {
            self.ids[t]: [v.name for v in vs] for t, vs in self.by_topic.items() if t in self.ids
        }
        for batch in self.batches(chunk, progress):
            ts = batch.t_ns.tolist()
            tops = batch.topic.tolist()
            cols = {k: c.tolist() for k, c in batch.values.items()}
            given = {k: m.tolist() for k, m in batch.given.items()}
            records = batch.records
            for i, (t, tid) in enumerate(zip(ts, tops, strict=True)):
                if i in records:
                    yield (t, "record", records[i])
                elif given:
                    vals = [(n, cols[n][i]) for n in names[tid] if n in cols]
                    yield (
                        t,
                        self.topics[tid],
                        [(n, x) for n, x in vals if n not in given or given[n][i]],
                    )
                else:
                    yield (t, self.topics[tid], [(n, cols[n][i]) for n in names[tid]])


def _slice(b: Batch, i: int, j: int) -> Batch:
    return Batch(
        b.t_ns[i:j],
        b.topic[i:j],
        b.topics,
        {k: c[i:j] for k, c in b.values.items()},
        {r - i: rec for r, rec in b.records.items() if i <= r < j},
        {k: m[i:j] for k, m in b.given.items()},
    )


def _merge(parts: list[Batch]) -> Batch | None:
    """Parts into one batch in receive order (stable: a source's own order is kept)."""
    parts = [p for p in parts if len(p)]
    if len(parts) <= 1:
        return parts[0] if parts else None
    topics = parts[0].topics
    t = np.concatenate([p.t_ns for p in parts])
    top = np.concatenate([p.topic for p in parts])
    names = {k: p.values[k].dtype for p in parts for k in p.values}
    values = {
        k: np.concatenate([p.values.get(k, np.zeros(len(p), dtype=dt)) for p in parts])
        for k, dt in names.items()
    }
    given = {
        k: np.concatenate([p.given.get(k, np.ones(len(p), dtype=np.bool_)) for p in parts])
        for k in {k for p in parts for k in p.given}
    }
    records: dict[int, dict[str, Any]] = {}
    base = 0
    for p in parts:
        records.update({base + r: rec for r, rec in p.records.items()})
        base += len(p)
    order = np.argsort(t, kind="stable")
    inverse = np.empty_like(order)
    inverse[order] = np.arange(len(order))
    return Batch(
        t[order],
        top[order],
        topics,
        {k: c[order] for k, c in values.items()},
        {int(inverse[r]): rec for r, rec in records.items()},
        {k: m[order] for k, m in given.items()},
    )


def _open_one(path: Path, cfg: Config) -> list[_Source]:
    if not path.exists():
        raise UserError("no such file or directory", file=str(path))
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return _bag_dir(path)
        files = sorted([*path.glob("*.mcap"), *path.glob("*.db3")])
        if not files:
            raise UserError(
                "not a rosbag2 bag: no metadata.yaml, .mcap or .db3 file", file=str(path)
            )
        # a bag directory whose recorder died before writing metadata.yaml
        return [_Mcap(f) if f.suffix == ".mcap" else _Sqlite(f) for f in files]
    if path.suffix == ".mcap":
        return [_Mcap(path)]
    if path.suffix == ".db3":
        return [_Sqlite(path)]
    if path.suffix in (".jsonl", ".json", ".ndjson"):
        return [_Trace(path, cfg)]
    raise UserError(
        f"unknown recording format '{path.suffix}'",
        file=str(path),
        hint="give a rosbag2 bag directory, a .mcap or .db3 file, or a .jsonl trace",
    )


def open_recordings(paths: list[Path], cfg: Config) -> Recording:
    """Open bags, storage files and traces for cfg's topic variables; type mismatches
    are errors here, before anything is read (``Recording.warnings`` lists the config
    topics no recording has)."""
    sources = [s for p in paths for s in _open_one(Path(p), cfg)]
    return Recording(sources, cfg)


__all__ = [
    "RECORD_TOPICS",
    "RECORDS_TOPIC",
    "Batch",
    "Event",
    "Recording",
    "open_recordings",
]
