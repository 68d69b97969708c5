"""The sqlite3 reader in bulk (supervisor/tools/replay/sqlite.py): rows are read as
columns, with no Python code run per row, and give exactly what a row-by-row reader
(the stdlib sqlite3 module) gives, across fetches and chunks, up to a bad row."""

from __future__ import annotations

import gc
import os
import sqlite3
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from supervisor.tools.replay.sqlite import Sqlite
from supervisor.tools.replay.storage import CHUNK, Damage, Raw

TS = get_typestore(Stores.ROS2_JAZZY)
INT64 = "std_msgs/msg/Int64"


def bag(tmp_path: Path, n: int, name: str = "b") -> Path:
    """A sqlite3 bag of ``n`` Int64 messages on /a and /b, alternating, 1 µs apart."""
    with Writer(tmp_path / name, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = [w.add_connection(t, INT64, typestore=TS) for t in ("/a", "/b")]
        for i in range(n):
            msg = TS.types[INT64](data=i)
            w.write(conns[i % 2], 1_000_000 + 1000 * i, bytes(TS.serialize_cdr(msg, INT64)))
    return next((tmp_path / name).glob("*.db3"))


def read(db: Path, chunk: int = CHUNK) -> tuple[list[Raw], Damage | None]:
    got: list[Raw] = []
    try:
        for raw in Sqlite(db).chunks({"/a": 0, "/b": 1}, chunk):
            got.append(raw)
    except Damage as e:
        return got, e
    return got, None


def rows_of(raws: list[Raw]) -> list[tuple[int, int, bytes]]:
    return [(int(r.t_ns[i]), int(r.topic[i]), r.payload(i)) for r in raws for i in range(len(r))]


def python_calls(db: Path) -> int:
    """Python-level function calls (not C ones) made while reading the whole bag."""
    calls = 0

    def count(frame: FrameType, event: str, arg: Any) -> None:
        nonlocal calls
        calls += event == "call"

    sys.setprofile(count)
    try:
        raws, damage = read(db)
    finally:
        sys.setprofile(None)
    assert damage is None and sum(map(len, raws)) > 0
    return calls


def test_reading_runs_no_python_code_per_row(tmp_path: Path) -> None:
    # Both bags are one chunk; three times the rows must not mean more Python calls
    # than a few per 4096-row fetch (docs/BENCHMARKS.md, "Replay throughput").
    small = python_calls(bag(tmp_path, 20_000, "small"))
    large = python_calls(bag(tmp_path, 60_000, "large"))
    assert large - small < 1000, (small, large)


def test_reading_starts_no_garbage_collection_per_rows(tmp_path: Path) -> None:
    # A tuple per row fetched, none in a cycle: collections they would start walk the
    # whole heap, again and again (docs/BENCHMARKS.md, "Replay throughput").
    db = bag(tmp_path, 60_000)
    started: list[int] = []

    def note(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            started.append(info["generation"])

    gc.collect()
    gc.callbacks.append(note)
    try:
        raws, damage = read(db)
    finally:
        gc.callbacks.remove(note)
    assert damage is None and sum(map(len, raws)) == 60_000
    assert gc.isenabled()
    assert len(started) < 10, started


def expected(db: Path) -> list[tuple[object, ...]]:
    """Every row in replay order, read row by row by another sqlite3 binding."""
    con = sqlite3.connect(db)
    try:
        return con.execute(
            "SELECT timestamp, topic_id, data, typeof(timestamp) = 'integer' "
            "AND timestamp >= 0 AND typeof(data) = 'blob' FROM messages ORDER BY timestamp, id"
        ).fetchall()
    finally:
        con.close()


@pytest.mark.parametrize("chunk", [CHUNK, 5000, 4096, 777])
def test_chunks_and_fetches_give_every_row_in_order_with_equal_times(
    tmp_path: Path, chunk: int
) -> None:
    db = bag(tmp_path, 12_000)
    con = sqlite3.connect(db)
    # equal receive times across fetch (4096) and chunk boundaries, out of insertion order
    con.execute("UPDATE messages SET timestamp = 5 WHERE id BETWEEN 4090 AND 4100")
    con.execute("UPDATE messages SET timestamp = 7 WHERE id BETWEEN 9990 AND 10010")
    con.execute("UPDATE messages SET timestamp = 6 WHERE id = 11000")
    con.commit()
    con.close()
    raws, damage = read(db, chunk)
    assert damage is None
    want = [(t, k - 1, bytes(d)) for t, k, d, _ in expected(db)]
    assert rows_of(raws) == want
    assert all(len(r) <= chunk for r in raws)


@pytest.mark.parametrize("bad_id", [1, 4096, 4097, 9000, 11_999])
def test_a_bad_row_deep_in_a_chunk_ends_the_read_right_before_it(
    tmp_path: Path, bad_id: int
) -> None:
    db = bag(tmp_path, 12_000)
    con = sqlite3.connect(db)
    con.execute("UPDATE messages SET data = 'text' WHERE id = ?", (bad_id,))
    con.commit()
    con.close()
    raws, damage = read(db, 5000)
    rows = expected(db)
    good = next(i for i, r in enumerate(rows) if not r[3])
    assert rows_of(raws) == [(t, k - 1, bytes(d)) for t, k, d, _ in rows[:good]]
    assert damage is not None
    last = f", the last at t_ns {rows[good - 1][0]}" if good else ""
    assert str(damage) == (
        f"damaged: message row {good + 1} in timestamp order: its data is str, not a blob "
        f"(t_ns {rows[good][0]}); {good} messages read{last}"
    )
    t = np.concatenate([r.t_ns for r in raws]) if raws else np.empty(0)
    assert bool((np.diff(t) >= 0).all())


def test_a_db3_swapped_for_a_fifo_after_its_topics_were_read_is_refused_not_waited_on(
    tmp_path: Path,
) -> None:
    # The archive is anybody's input: a bag's file can become a FIFO between the
    # reader's first look (its topics) and its reading of the rows.  Opening a FIFO
    # waits for a writer, for ever; the reader opens the file itself, checks it is a
    # regular file, and has sqlite open that same file.
    db = bag(tmp_path, 10)
    source = Sqlite(db)
    db.rename(db.with_suffix(".old"))
    os.mkfifo(db)
    outcome: list[object] = []

    def rows() -> None:
        try:
            outcome.append(sum(len(r) for r in source.chunks({"/a": 0, "/b": 1}, CHUNK)))
        except Damage as e:
            outcome.append(e)

    reader = threading.Thread(target=rows, daemon=True)
    reader.start()
    reader.join(10)
    if reader.is_alive():
        # let the waiting open go (a writer's open ends it), so the thread ends
        os.close(os.open(db, os.O_WRONLY | os.O_NONBLOCK))
        reader.join(10)
        pytest.fail("the reader waited on the FIFO")
    (got,) = outcome
    assert isinstance(got, Damage) and "not a regular file" in str(got), got
