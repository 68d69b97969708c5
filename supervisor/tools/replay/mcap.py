"""MCAP storage, read by the specification with struct and numpy (supervisor/tools/replay/sources.py
says why): a file with or without its summary, chunks compressed or not, up to its damage."""

from __future__ import annotations

import mmap
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from monitors.errors import UserError
from monitors.untrusted import Untrusted, inflate
from supervisor.inputs.rostypes import typestore_of
from supervisor.tools.replay.storage import (
    DEFAULT_BOUNDS,
    NS_MAX,
    Bounds,
    Damage,
    Raw,
    Source,
    inflate_payloads,
    normalise_type,
    open_regular,
    raw_chunk,
    refuse_serialization,
)

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


def _decompress(compression: str, data: bytes, size: int, at: int, bounds: Bounds) -> bytes:
    """A chunk's records, never more than the bounds: its declared size is checked
    before anything is inflated, and the inflating stops at the cap."""
    cap = bounds.chunk_bytes
    if size > cap or (not compression and len(data) > cap):
        raise Damage(
            f"the chunk at byte {at} holds {max(size, len(data) if not compression else 0)} "
            f"bytes, more than {cap} ({bounds.says()})"
        )
    if not compression:
        return data
    if compression not in ("zstd", "lz4"):
        raise Damage(
            f"the chunk at byte {at} is compressed with '{compression[:40]}', which is not supported"
        )
    try:
        out = inflate(compression, data, max_size=cap, max_ratio=int(bounds.ratio))
    except Untrusted as e:
        raise Damage(f"the {compression} chunk at byte {at}: {e} ({bounds.says()})") from None
    if len(out) != size:
        raise Damage(
            f"the chunk at byte {at} inflates to {len(out)} bytes, not the {size} it declares"
        )
    return out


class Mcap(Source):
    """An MCAP file read from the start, record by record, so that a file without its
    summary (a recorder killed) reads up to where it ends."""

    def __init__(
        self,
        path: Path,
        counts: dict[str, int] | None = None,
        topics: dict[str, str] | None = None,
        bounds: Bounds = DEFAULT_BOUNDS,
        label: str | None = None,
    ) -> None:
        self.path = path
        self.bounds = bounds
        self.warnings: list[str] = []
        self.label = label or str(path)
        self._encodings: dict[str, str] = {}
        self.counts = counts
        self._schemas: dict[int, tuple[str, str, str]] = {}
        self._channels: dict[int, tuple[str, int]] = {}
        self.topics = dict(topics or {})
        damage: Damage | None = None  # where a file without its summary ends early
        if not self._summary():
            # No summary (a recorder killed): a pass over the file finds the channels,
            # skipping chunks whose indexes name known channels only.
            try:
                for _ in self._records({}, head=True):
                    pass
            except Damage as e:
                if not self.topics:
                    raise UserError(f"not a readable MCAP file: {e}", file=self.label) from None
                damage = e
        for topic, enc in self._encodings.items():
            refuse_serialization(topic, enc, self.label)
        self.store = typestore_of(
            list(self._schemas.values()), self.topics.values(), self.warnings, self.label
        )
        lost = sorted({t for t in self.topics.values() if t not in self.store.fielddefs})
        if damage is not None and lost:
            # the metadata names the topics, but their definitions were in the part
            # lost (rosbag2 writes them into the first chunk): damage, not a type fault
            raise UserError(
                f"{damage}; the definition of {lost[0]} was in the part lost", file=self.label
            )

    def _summary(self) -> bool:
        """Every schema and channel (and the message counts) from the summary at the
        end of the file, if it has an intact one."""
        try:
            with (
                open_regular(self.path) as f,
                mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm,
            ):
                return self._summary_of(mm, len(mm))
        except (OSError, ValueError, Damage):
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
        topic, at = _string(buf, pos + 4)
        self._encodings[topic], _ = _string(buf, at)
        self._channels[cid] = (topic, sid)
        if sid in self._schemas:
            self.topics.setdefault(topic, normalise_type(self._schemas[sid][0]))

    def _records(self, ids: dict[str, int], head: bool = False) -> Iterator[Raw]:
        """The wanted messages, chunk by chunk; with head, only the types up to the
        first message."""
        with open_regular(self.path) as f:
            size = os.fstat(f.fileno()).st_size
            if size < len(MAGIC):
                raise Damage("the file is empty" if not size else "the file ends early (at byte 0)")
            mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            try:
                if mm[: len(MAGIC)] != MAGIC:
                    raise Damage("not an MCAP file (no MCAP magic at its start)")
                yield from self._data_section(mm, size, ids, head)
            finally:
                mm.close()

    def _data_section(
        self, mm: mmap.mmap, size: int, ids: dict[str, int], head: bool
    ) -> Iterator[Raw]:
        self._count = 0
        self._last_t: int | None = None
        pos = len(MAGIC)
        pending: tuple[int, int] | None = None  # the last chunk, until its indexes are read
        indexes: dict[int, np.ndarray] = {}
        loose: tuple[list[int], list[int], list[bytes]] = ([], [], [])
        try:
            while True:
                op, length = _record_at(mm, pos, size)
                body = pos + 9
                if op == MESSAGE_INDEX and pending is not None:
                    cid, index = _message_index(mm, pos, length)
                    indexes[cid] = index
                else:
                    if pending is not None:
                        # taken before it is read: a chunk that is damage is not read again
                        at, pending = pending, None
                        if head:
                            self._head_chunk(mm, at, indexes)
                        else:
                            yield from self._chunk(mm, at, indexes, ids)
                        indexes = {}
                    if op == SCHEMA:
                        self._schema(mm, body)
                    elif op == CHANNEL:
                        self._channel(mm, body)
                    elif op == MESSAGE:
                        self._loose_message(mm, pos, length, ids, loose)
                    elif op == CHUNK_OP:
                        if loose[0]:
                            yield raw_chunk(*loose).in_order()
                            loose = ([], [], [])
                        pending = (pos, body)
                    elif op in (DATA_END, FOOTER):
                        break
                pos = body + length
        except (Damage, struct.error, ValueError, UnicodeDecodeError) as e:
            if not isinstance(e, Damage):
                e = Damage(f"a malformed record at byte {pos} ({e})")
            if loose[0]:
                yield raw_chunk(*loose).in_order()
            # the last whole chunk is readable even without its indexes
            if pending is not None and not head:
                try:
                    yield from self._chunk(mm, pending, {}, ids)
                except (Damage, struct.error, ValueError, UnicodeDecodeError):
                    pass  # damaged too: the damage found first is the one said
            raise Damage(f"damaged: {e} (after byte {pos}, {self._read_so_far()})") from None
        if pending is not None:
            yield from self._chunk(mm, pending, indexes, ids)
        if loose[0]:
            yield raw_chunk(*loose).in_order()
        if not head and mm[size - len(MAGIC) :] != MAGIC:
            # every message is read, but the summary after them is cut: damage all
            # the same (truncation anywhere is, docs/reference/commands.md)
            raise Damage(
                f"damaged: the file is cut short at byte {size}, after its data "
                f"({self._read_so_far()})"
            )

    def _loose_message(
        self,
        mm: mmap.mmap,
        pos: int,
        length: int,
        ids: dict[str, int],
        loose: tuple[list[int], list[int], list[bytes]],
    ) -> None:
        """A message record outside any chunk: counted, and kept in ``loose`` when its
        channel's topic is wanted."""
        body = pos + 9
        cid, _, t, _ = _MSG.unpack_from(mm, body)
        if t > NS_MAX or length < _MSG.size:
            raise Damage(_bad_message(pos, t))
        self._count += 1
        self._last_t = t
        k = ids.get(self._channels.get(cid, ("", 0))[0], -1)
        if k >= 0:
            loose[0].append(t)
            loose[1].append(k)
            loose[2].append(mm[body + _MSG.size : body + length])

    def _read_so_far(self) -> str:
        """Where reading got to, for a damage line."""
        where = f"{self._count} messages read"
        if self._last_t is not None:
            where += f", the last at t_ns {self._last_t}"
        return where

    def _chunk(
        self,
        mm: mmap.mmap,
        at: tuple[int, int],
        indexes: dict[int, np.ndarray],
        ids: dict[str, int],
    ) -> Iterator[Raw]:
        pos, body = at
        _, length = _REC.unpack_from(mm, pos)
        _, _, usize, _ = struct.unpack_from("<QQQI", mm, body)
        compression, p = _string(mm, body + 28)
        (n,) = struct.unpack_from("<Q", mm, p)
        if p + 8 + n > body + length:
            raise Damage(f"the chunk at byte {pos} holds more bytes than its record")
        buf = _decompress(compression, mm[p + 8 : p + 8 + n], usize, pos, self.bounds)
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

    def _indexed(self, buf: bytes, indexes: dict[int, np.ndarray], ids: dict[str, int]) -> Raw:
        """Every message's time and place from the chunk's indexes, with numpy."""
        if any(len(ix) and int(ix["t"].max()) > NS_MAX for ix in indexes.values()):
            raise Damage("a message index gives a log time past 2^63-1 ns")
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
            return Raw(np.empty(0, np.int64), np.empty(0, np.int32))
        t = np.concatenate([ix["t"] for ix, _ in want]).astype(np.int64)
        o = np.concatenate([ix["o"] for ix, _ in want]).astype(np.int64)
        top = np.concatenate([np.full(len(ix), k, np.int32) for ix, k in want])
        order = np.lexsort((o, t))  # by time, then as written
        t, o, top = t[order], o[order], top[order]
        arr = np.frombuffer(buf, np.uint8)
        if len(o) and (o.min() < 0 or o.max() + _MSG_HEAD > len(arr) or (arr[o] != MESSAGE).any()):
            raise Damage("a message index points outside its chunk's messages")
        lengths = arr[(o + 1)[:, None] + np.arange(8)].copy().view("<u8").reshape(len(o))
        if len(lengths) and (lengths.max() > len(arr) or lengths.min() < _MSG.size):
            raise Damage("a message in a chunk has an impossible length")
        end = o + 9 + lengths.astype(np.int64)
        if len(end) and end.max() > len(arr):
            raise Damage("a message in a chunk is cut short")
        return Raw(t, top, buf, o + _MSG_HEAD, end)

    def _scan(self, buf: bytes, ids: dict[str, int], at: int) -> Raw:
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
                raise Damage(f"a record in the chunk at byte {at} is cut short")
            if op == MESSAGE:
                cid, _, t, _ = _MSG.unpack_from(buf, body)
                if t > NS_MAX or length < _MSG.size:
                    raise Damage(f"in the chunk at byte {at}: {_bad_message(pos, t)}")
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
        return Raw(
            np.asarray(ts, np.int64),
            np.asarray(tops, np.int32),
            buf,
            np.asarray(starts, np.int64),
            np.asarray(ends, np.int64),
        )

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        # rosbag2's per-message compression, whatever the metadata says
        return (inflate_payloads(raw, self.bounds) for raw in self._records(ids))


def _bad_message(pos: int, t: int) -> str:
    if t > NS_MAX:
        return f"the message at byte {pos} has a log time past 2^63-1 ns ({t})"
    return f"the message record at byte {pos} is shorter than a message header"


def _record_at(mm: mmap.mmap, pos: int, size: int) -> tuple[int, int]:
    """The opcode and body length of the record at ``pos``, whole within the file."""
    if pos + 9 > size:
        raise Damage("the file ends early")
    op, length = _REC.unpack_from(mm, pos)
    if pos + 9 + length > size:
        raise Damage(f"the record at byte {pos} is cut short: the file ends early")
    if op == 0:
        raise Damage(f"the record at byte {pos} has opcode 0, which MCAP never uses")
    return op, length


def _message_index(mm: mmap.mmap, pos: int, length: int) -> tuple[int, np.ndarray]:
    """A chunk's message index record at ``pos``: its channel and (time, offset) rows."""
    body = pos + 9
    (cid,) = struct.unpack_from("<H", mm, body)
    (n,) = struct.unpack_from("<I", mm, body + 2)
    if 6 + n > length:
        raise Damage(f"the message index at byte {pos} is longer than its record")
    return cid, np.frombuffer(mm, _INDEX, n // 16, body + 6).copy()
