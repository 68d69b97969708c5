"""rosbag2's sqlite3 storage (``.db3``), read in receive order, a cut-short file up
to its damage (supervisor/tools/replay/sources.py)."""

from __future__ import annotations

import gc
import os
import struct
import tempfile
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from itertools import chain, islice
from pathlib import Path
from typing import Any
from urllib.parse import quote

import apsw
import numpy as np

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.inputs.rostypes import typestore_of
from supervisor.tools.replay.storage import (
    CHUNK_BYTES,
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
    temp_room,
)

# --- sqlite3 storage ------------------------------------------------------------------


# One row as the database holds it, checked where it is read: a receive time in
# int64 nanoseconds, a blob (sqlite3 lets any column hold any type, and a bag is
# input anybody could have written; docs/reference/faults.md, "Trust").
_ROW_OK = "typeof(timestamp) = 'integer' AND timestamp >= 0 AND typeof(data) = 'blob'"
_FETCH = 4096  # rows per fetch, so that a chunk stops at CHUNK_BYTES of payloads
# Rows per chunk at most: the bulk stepper re-scans the rest of a chunk after each
# violation, so chunks about as long as an MCAP chunk's keep violating bags fast
# (docs/BENCHMARKS.md, "Replay throughput").
_ROWS = 8192


def _check_topics(con: apsw.Connection, rows: list[Any], label: str) -> None:
    """Raises UserError for a topics row that is not (whole number, name, type), or
    a topic in a serialization replay cannot read."""
    for k, row in enumerate(rows, 1):
        if not (isinstance(row[0], int) and isinstance(row[1], str) and isinstance(row[2], str)):
            shown = printable(repr(tuple(row))[:120])
            raise UserError(
                f"row {k} of table topics is {shown}: not (whole number, name, type)", file=label
            )
    try:
        for name, fmt in con.execute("SELECT name, serialization_format FROM topics"):
            if isinstance(name, str) and isinstance(fmt, str):
                refuse_serialization(name, fmt, label)
    except apsw.Error:
        pass  # no such column: CDR, the only serialization of that bag's rosbag2


def _definitions(con: apsw.Connection) -> list[tuple[str, str, str]]:
    """The bag's message definitions (type, encoding, text); none before version 8."""
    try:
        return [
            d
            for d in con.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            )
            if all(isinstance(x, str) for x in d)
        ]
    except apsw.Error:
        return []  # bags before version 8 have no definitions


def _rows_of_no_topic(con: apsw.Connection) -> int:
    """Message rows of no topic (NULL or unknown id): never replayed, counted."""
    try:
        (lost,) = con.execute(
            "SELECT count(*) FROM messages "
            "WHERE topic_id IS NULL OR topic_id NOT IN (SELECT id FROM topics)"
        ).fetchone()
    except apsw.Error:
        return 0  # no readable messages table: reading it says where
    return lost


class Sqlite(Source):
    def __init__(
        self,
        path: Path,
        counts: dict[str, int] | None = None,
        bounds: Bounds = DEFAULT_BOUNDS,
        label: str | None = None,
        topics: dict[str, str] | None = None,
    ) -> None:
        self.path = path
        self.bounds = bounds
        self.label = label or str(path)
        self.counts = counts
        self.warnings: list[str] = []
        self._tmp: Path | None = None
        self._cut = False  # truncated: read a copy whose header counts the pages present
        self._cut_at: int | None = _cut_short(path)  # the file's size, if shorter than it says
        con, rows = self._read_topics(topics)
        if not rows and topics and self._cut_at is not None:
            self._ids: dict[int, str] = {}
            self.topics = dict(topics)
            self.store = typestore_of([])
            return
        try:
            _check_topics(con, rows, self.label)
        except UserError:
            con.close()
            self._drop()
            raise
        self._ids = {tid: name for tid, name, _ in rows}
        self.topics = {name: normalise_type(typ) for _, name, typ in rows}
        defs = _definitions(con)
        lost = _rows_of_no_topic(con)
        if lost:
            self.warnings.append(
                f"warning: {self.label}: {lost} message rows name no topic of the bag: not replayed"
            )
        con.close()
        self._drop()
        self.store = typestore_of(defs, self.topics.values(), self.warnings, self.label)

    def _read_topics(self, topics: dict[str, str] | None) -> tuple[apsw.Connection, list[Any]]:
        """The open database and its topics table's rows (none when the table is past
        the damage of a truncated file and the bag's metadata names the topics)."""
        try:
            con = self._connect()
            rows = con.execute("SELECT id, name, type FROM topics").fetchall()
        except Damage as e:
            raise UserError(str(e), file=self.label) from None
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
                if self._cut_at is None or topics is None:
                    raise UserError(
                        f"not a readable rosbag2 sqlite3 file ({e})", file=self.label
                    ) from None
                # the topics table is past the damage: the bag's metadata names them,
                # and reading says where the damage is
                rows = []
        return con, rows

    def _connect(self) -> apsw.Connection:
        """The database, read-only; ``Damage`` if the bag's file is not a regular file
        now (an archive's file can change between two looks at it)."""
        if self._cut:
            return _open_db(self._patched(), wal=False)  # a copy made whole
        # sqlite opens the very file opened and checked here (/proc/self/fd/N, which it
        # resolves to that file's current name), not whatever has its name by then:
        # opening a FIFO would wait for a writer for ever.
        with open_regular(self.path) as f:
            return _open_db(Path(f"/proc/self/fd/{f.fileno()}"), _wal_of(self.path))

    def _drop(self) -> None:
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None

    def _patched(self) -> Path:
        """A copy of the whole pages present, its header counting them, copied in
        blocks (a bag can be larger than memory)."""
        try:
            f = open_regular(self.path)
        except Damage as e:
            raise UserError(str(e), file=self.label) from None
        with f:
            head = f.read(100)
            if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
                raise UserError("not an sqlite3 file", file=self.label)
            size = struct.unpack_from(">H", head, 16)[0]
            page = 65536 if size == 1 else size
            if page < 512 or page & (page - 1):
                raise UserError(f"not an sqlite3 file (page size {size})", file=self.label)
            pages = os.fstat(f.fileno()).st_size // page
            with temp_room(f"copy the damaged {self.path.name}", pages * page):
                fd, name = tempfile.mkstemp(suffix=".db3")
                self._tmp = Path(name)  # removed by _drop, whole or not
                with os.fdopen(fd, "wb") as out:
                    out.write(head[:28] + struct.pack(">I", pages) + head[32:])
                    left = pages * page - 100
                    while left > 0:
                        block = f.read(min(left, 1 << 20))
                        if not block:
                            break
                        out.write(block)
                        left -= len(block)
        try:
            # Tables and indexes whose first page is lost make sqlite refuse the whole
            # schema: the copy forgets them, so that what is present reads.
            con = apsw.Connection(str(self._tmp))
            con.execute("PRAGMA writable_schema=ON")
            con.execute("DELETE FROM sqlite_master WHERE rootpage > ?", (pages,))
            con.close()
        except apsw.Error:
            pass  # a schema damaged otherwise: reading it says so
        return self._tmp

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        # rosbag2's per-message compression, whatever the metadata says
        return (inflate_payloads(raw, self.bounds) for raw in self._rows(ids, chunk))

    def _rows(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        wanted = {tid: ids[name] for tid, name in self._ids.items() if name in ids}
        # Only the wanted topics' rows: the extra topics' payloads are never fetched.
        marks = ",".join("?" * len(wanted))
        query = (
            f"SELECT timestamp, topic_id, data, {_ROW_OK} FROM messages "
            f"WHERE topic_id IN ({marks}) ORDER BY timestamp"
        )
        n, last = 0, None
        self._given = np.empty(0, np.int64)  # the last chunk's times, to count those at last
        try:
            con = self._connect()
        except Damage:
            self._drop()
            raise
        except (apsw.Error, UserError) as e:
            self._drop()
            raise Damage(f"damaged database ({e})") from None
        # topic id -> index by search: the ids are the file's, any int64 (no table)
        keys = np.array(sorted(wanted), dtype=np.int64)
        index = np.array([wanted[k] for k in sorted(wanted)], dtype=np.int32)
        try:
            try:
                cur = con.execute(query, list(wanted))
                while True:
                    # Columns per fetch, joined once per chunk: no Python code per row
                    # (docs/BENCHMARKS.md, "Replay throughput").
                    tparts, kparts, dparts, count, bad = _fetch(cur, min(chunk, _ROWS))
                    if count:
                        raw = _columns(tparts, dparts, count)
                        # the query matched these ids: numbers equal to a wanted one
                        tid = np.fromiter(chain.from_iterable(kparts), np.int64, count)
                        raw.topic = index[np.searchsorted(keys, tid)]
                        yield raw
                        n += count
                        last = int(raw.t_ns[-1])
                        self._given = raw.t_ns
                    if bad is not None:
                        raise Damage(_bad_row(n, bad, last))
                    if not count:
                        break
            except apsw.Error as e:
                failed: apsw.Error | None = e
            else:
                failed = None
            if failed is not None:
                # A failed read loses its chunk's rows, and the timestamp index may be
                # what is lost: read the table itself row by row, in its own order, up
                # to the damage, leaving out the rows given already (all before
                # ``last``, and ``at_last`` of those at it), so that every readable
                # message is replayed (docs/reference/commands.md, "Damaged input").
                at_last = 0 if last is None else _count_at(self._given.tolist(), last)
                n, last, failed = yield from _in_table_order(con, marks, wanted, n, last, at_last)
            if failed is not None or self._cut_at is not None:
                raise Damage(_damage(n, last, failed, self._cut_at))
        finally:
            con.close()
            self._drop()


_Parts = list[tuple[object, ...]]


def _fetch(
    cur: apsw.Cursor, most: int
) -> tuple[_Parts, _Parts, _Parts, int, tuple[object, ...] | None]:
    """Up to ``most`` rows (and CHUNK_BYTES of payloads) as columns per fetch: times,
    topic ids, payloads, how many, and the first row that is not as it should be."""
    tparts: _Parts = []
    kparts: _Parts = []
    dparts: _Parts = []
    count = size = 0
    bad: tuple[object, ...] | None = None
    with _gc_paused():
        while count < most and size < CHUNK_BYTES and bad is None:
            got = list(islice(cur, min(_FETCH, most - count)))
            if not got:
                break
            ts, tids, data, ok = zip(*got, strict=True)
            if not all(ok):
                good = ok.index(0)
                bad = got[good]
                ts, tids, data = ts[:good], tids[:good], data[:good]
            tparts.append(ts)
            kparts.append(tids)
            dparts.append(data)
            count += len(ts)
            size += sum(map(len, data))  # type: ignore[arg-type]
    return tparts, kparts, dparts, count, bad


def _in_table_order(
    con: apsw.Connection,
    marks: str,
    wanted: dict[int, int],
    n: int,
    last: int | None,
    at_last: int,
) -> Generator[Raw, None, tuple[int, int | None, apsw.Error | None]]:
    """The wanted rows in the table's own order (no index) up to the damage, leaving
    out those given already (all before ``last``, and ``at_last`` of those at it);
    returns the messages read, the last time, and the read's failure if any."""
    ts_: list[int] = []
    tops: list[int] = []
    data_: list[bytes] = []
    failed: apsw.Error | None
    try:
        cur = con.execute(
            f"SELECT timestamp, topic_id, data, {_ROW_OK} FROM messages NOT INDEXED "
            f"WHERE topic_id IN ({marks}) ORDER BY rowid",
            list(wanted),
        )
        while row := cur.fetchone():
            if not row[3]:
                if ts_:
                    yield raw_chunk(ts_, tops, data_).in_order()
                raise Damage(_bad_row(n + len(ts_), row, last))
            if last is not None and row[0] <= last:
                if row[0] < last or at_last > 0:
                    at_last -= row[0] == last
                    continue
            ts_.append(row[0])
            tops.append(wanted[row[1]])
            data_.append(row[2])
    except apsw.Error as e:
        failed = e
    else:
        failed = None
    if ts_:
        yield raw_chunk(ts_, tops, data_).in_order()
        n += len(ts_)
        last = max(ts_)
    return n, last, failed


def _damage(n: int, last: int | None, failed: apsw.Error | None, cut_at: int | None) -> str:
    """The damage line: where reading stopped, and why."""
    where = f"{n} messages read" + (f", the last at t_ns {last}" if last is not None else "")
    said = f" ({failed})" if failed is not None else ""
    if cut_at is not None:
        return f"damaged: the file is cut short at byte {cut_at}{said}; {where}"
    return f"damaged database{said}; {where}"


@contextmanager
def _gc_paused() -> Iterator[None]:
    """The cyclic garbage collector paused while rows are fetched: a tuple per row, none
    in a cycle, whose allocation would start collections of the whole heap again and
    again, a third of a replay's time (docs/BENCHMARKS.md, "Replay throughput")."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _columns(tparts: list[tuple[object, ...]], dparts: list[tuple[object, ...]], count: int) -> Raw:
    """A chunk of ``count`` rows from the fetches' timestamp and blob columns (checked
    by ``_ROW_OK``: whole numbers and blobs), its topics left to the caller."""
    datas: list[bytes] = list(chain.from_iterable(dparts))  # type: ignore[arg-type]
    lengths = np.fromiter(map(len, datas), np.int64, count)
    end = np.cumsum(lengths)
    return Raw(
        np.fromiter(chain.from_iterable(tparts), np.int64, count),  # type: ignore[arg-type]
        np.empty(count, np.int32),
        b"".join(datas),
        end - lengths,
        end,
    )


def _wal_of(path: Path) -> bool:
    """Whether a killed recorder's write-ahead log beside ``path`` holds pages."""
    wal = Path(f"{path}-wal")
    return wal.exists() and wal.stat().st_size > 0


def _open_db(path: Path, wal: bool) -> apsw.Connection:
    # rosbag2 writes WAL mode, where even a read-only open creates -shm and -wal files
    # beside the bag (and fails in a read-only directory): immutable reads the file
    # alone, unless a -wal of a recorder killed holds messages.
    if wal:
        return apsw.Connection(str(path), flags=apsw.SQLITE_OPEN_READONLY)
    uri = f"file:{quote(str(path))}?immutable=1"
    return apsw.Connection(uri, flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI)


def _cut_short(path: Path) -> int | None:
    """The file's size if it ends before the pages its header counts, or inside a page
    (sqlite's file format, "The database header"); None if whole or not known."""
    if _wal_of(path):
        return None  # the pages may be in the write-ahead log
    try:
        with open_regular(path) as f:
            head = f.read(100)
            size = os.fstat(f.fileno()).st_size
    except Damage:
        return None  # opening says why
    if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
        return None
    (psize,) = struct.unpack_from(">H", head, 16)
    page = 65536 if psize == 1 else psize
    (changes, declared, valid_for) = (
        struct.unpack_from(">I", head, 24)[0],
        struct.unpack_from(">I", head, 28)[0],
        struct.unpack_from(">I", head, 92)[0],
    )
    if page < 512 or page & (page - 1):
        return None
    if size % page or (changes == valid_for and declared * page > size):
        return size
    return None


def _count_at(given: list[int], last: object) -> int:
    """How many of the times given (in order, ``last`` the final one) equal ``last``."""
    k = 0
    for t in reversed(given):
        if t != last:
            break
        k += 1
    return k


def _bad_row(n: int, row: tuple[object, ...], last: object) -> str:
    """Why row ``n + 1`` (in timestamp order) is damage."""
    t, _, data = row[:3]
    if not isinstance(t, int) or isinstance(t, bool):
        why = f"its timestamp is {printable(repr(t)[:60])}, not a whole number of nanoseconds"
    elif not 0 <= t <= NS_MAX:
        why = f"its timestamp {t} is negative"
    else:
        what = "NULL" if data is None else type(data).__name__
        why = f"its data is {what}, not a blob (t_ns {t})"
    where = f"{n} messages read" + (f", the last at t_ns {last}" if last is not None else "")
    return f"damaged: message row {n + 1} in timestamp order: {why}; {where}"
