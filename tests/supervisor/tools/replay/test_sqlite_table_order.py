"""The sqlite reader's fallback after a failed indexed read: the table read in its
own order gives exactly the rows the indexed read had not given yet, including
rows that share the last given time (rosbag2 records several messages per
nanosecond on a fast bus)."""

from __future__ import annotations

from collections import Counter

import apsw
from hypothesis import given, settings
from hypothesis import strategies as st

from supervisor.tools.replay.sqlite import _in_table_order

WANTED = {7: 0, 9: 1}  # the file's topic ids -> the replay's topic index


def _table(rows: list[tuple[int, int, bytes]]) -> apsw.Connection:
    con = apsw.Connection(":memory:")
    con.execute(
        "CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER, "
        "timestamp INTEGER, data BLOB)"
    )
    con.execute("CREATE INDEX timestamp_idx ON messages (timestamp ASC)")
    for t, tid, data in rows:
        con.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)", (tid, t, data)
        )
    return con


def _messages(raws: list) -> list[tuple[int, int, bytes]]:
    out = []
    for raw in raws:
        for i in range(len(raw)):
            data = raw.buf[int(raw.start[i]) : int(raw.end[i])]
            out.append((int(raw.t_ns[i]), int(raw.topic[i]), data))
    return out


@settings(max_examples=200, deadline=None)
@given(
    times=st.lists(st.integers(0, 6), min_size=1, max_size=30),
    topics=st.lists(st.sampled_from([7, 9, 11]), min_size=30, max_size=30),
    cut=st.integers(0, 30),
)
def test_the_table_read_gives_exactly_the_rows_not_given_yet(times, topics, cut):
    # payloads unique per row, so a row given twice or never is seen
    rows = [(t, tid, b"%d" % k) for k, (t, tid) in enumerate(zip(times, topics, strict=False))]
    con = _table(rows)
    # what the indexed read gave before it failed: the first ``cut`` wanted rows by
    # time, ties in table order (the index's order: by key, then rowid)
    wanted_rows = [(t, WANTED[tid], d) for t, tid, d in rows if tid in WANTED]
    by_time = sorted(wanted_rows, key=lambda r: r[0])  # stable: ties keep rowid order
    cut = min(cut, len(by_time))
    given_rows = by_time[:cut]
    last = given_rows[-1][0] if given_rows else None
    at_last = sum(1 for r in given_rows if r[0] == last)
    marks = ",".join("?" * len(WANTED))

    gen = _in_table_order(con, marks, WANTED, cut, last, at_last)
    raws = []
    try:
        while True:
            raws.append(next(gen))
    except StopIteration as stop:
        n, new_last, failed = stop.value
    rest = _messages(raws)

    assert failed is None
    assert Counter(given_rows + rest) == Counter(wanted_rows)  # each row once
    assert [r[0] for r in rest] == sorted(r[0] for r in rest)  # in time order
    assert all(last is None or r[0] >= last for r in rest)
    assert n == len(wanted_rows)
    assert new_last == (max(r[0] for r in rest) if rest else last)
