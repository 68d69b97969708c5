"""rosbag2's sqlite3 storage (``.db3``), read in receive order, a cut-short file up
to its damage (supervisor/tools/replay/sources.py)."""

from __future__ import annotations

import os
import struct
import tempfile
from collections.abc import Iterator
from itertools import islice
from pathlib import Path

import apsw
import numpy as np

from monitors.errors import UserError
from supervisor.tools.replay.storage import (
    Damage,
    Raw,
    Source,
    normalise_type,
    raw_chunk,
    typestore_of,
)

# --- sqlite3 storage ------------------------------------------------------------------


class Sqlite(Source):
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
        self.store = typestore_of(defs)

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

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
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
                    raw = raw_chunk(list(ts), [], list(data))
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
                    yield raw_chunk(ts_, tops, data_)
                n += len(ts_)
                where = f"{n} messages read" + (
                    f", the last at t_ns {last}" if last is not None else ""
                )
                raise Damage(f"damaged database ({e}); {where}") from None
            if ts_:
                yield raw_chunk(ts_, tops, data_)
        finally:
            con.close()
            self._drop()
