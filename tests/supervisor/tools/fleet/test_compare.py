"""Two configs' violations compared (supervisor/tools/fleet/compare.py), on a table
whose answer is counted by hand: a violation both report, one each alone, the same
violation written twice, nanoseconds apart, a bag outside the compared set, a third
config, and which config comes first per bag."""

from __future__ import annotations

from dataclasses import asdict

import pytest

pa = pytest.importorskip("pyarrow")

from supervisor.tools.fleet.compare import compare  # noqa: E402

S = 1_000_000_000


def _table(rows: list[tuple[str, str, str, str, int]]) -> pa.Table:
    cols = ["config_sha256", "requirement", "robot", "bag_sha256", "recorded_ts"]
    data = {c: [r[i] for r in rows] for i, c in enumerate(cols)}
    schema = pa.schema(
        [*((c, pa.string()) for c in cols[:4]), ("recorded_ts", pa.timestamp("ns", tz="UTC"))]
    )
    return pa.table(data, schema=schema)


def test_counts_and_first_detection_per_requirement_and_robot():
    table = _table(
        [
            ("A", "limit", "r1", "b1", 10 * S),  # both
            ("B", "limit", "r1", "b1", 10 * S),
            ("A", "limit", "r1", "b1", 10 * S),  # the same violation again: once
            ("A", "limit", "r1", "b1", 20 * S),  # A alone
            ("B", "limit", "r1", "b1", 20 * S + 1),  # B alone: a nanosecond later
            ("B", "limit", "r1", "b2", 5 * S),  # B alone, in a bag A has none in
            ("A", "limit", "r1", "b9", 1 * S),  # a bag outside the compared set
            ("C", "limit", "r1", "b1", 1 * S),  # a third config
            ("A", "turn", "007", "b1", 3 * S),  # A first in b1
            ("B", "turn", "007", "b1", 4 * S),
            ("B", "turn", "007", "b2", 4 * S),  # B alone in b2: B first there
        ]
    )
    rows = [asdict(r) for r in compare(table, "A", "B", {"b1", "b2"})]
    assert rows == [
        dict(requirement="limit", robot="r1", a=2, b=3, only_a=1, only_b=2, both=1,
             a_first=0, b_first=1),
        dict(requirement="turn", robot="007", a=1, b=2, only_a=1, only_b=2, both=0,
             a_first=1, b_first=1),
    ]  # fmt: skip
    # a config with no violations at all: everything is the other's alone
    (alone,) = [asdict(r) for r in compare(table, "A", "D", {"b1"}) if r.requirement == "turn"]
    assert alone == dict(
        requirement="turn", robot="007", a=1, b=0, only_a=1, only_b=0, both=0, a_first=1, b_first=0
    )
    assert compare(table.slice(0, 0), "A", "B", {"b1"}) == []
