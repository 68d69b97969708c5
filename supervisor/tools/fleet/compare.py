"""Two configs' violations in one dataset, compared: per requirement and robot, the
violations only A reports, only B reports and both (matched by bag content, requirement
and recorded time, as ``replay --compare`` matches them by time), and in how many
bags each config detects first."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc

from monitors.untrusted import shown

MAX_CELL = 128  # characters of a table cell: a requirement id's most (config schema)


@dataclass
class Row:
    requirement: str
    robot: str
    a: int = 0
    b: int = 0
    only_a: int = 0
    only_b: int = 0
    both: int = 0
    a_first: int = 0  # bags where A's first violation comes before B's (or B has none)
    b_first: int = 0


def compare(violations: pa.Table, sha_a: str, sha_b: str, bags: set[str]) -> list[Row]:
    """Rows sorted by requirement and robot, over the bags (content hashes) ``bags``.
    Columnar (Arrow group-bys and joins): a row-by-row pass held a Python object per
    violation, gigabytes for a baseline of a million rows (docs/BENCHMARKS.md, "Fleet")."""
    keep = pc.and_(
        pc.is_in(violations["bag_sha256"], pa.array(sorted(bags), pa.string())),
        pc.is_in(violations["config_sha256"], pa.array([sha_a, sha_b], pa.string())),
    )
    cols = ["config_sha256", "requirement", "robot", "bag_sha256", "recorded_ts"]
    table = violations.filter(keep).select(cols)
    # the text columns as small integers (their dictionaries kept for the rows' names):
    # hashes of 64 characters grouped and joined as text cost most of the memory
    names: dict[str, pa.Array] = {}
    for i, name in enumerate(cols[:4]):
        encoded = pc.dictionary_encode(table[name].combine_chunks())
        names[name] = encoded.dictionary
        table = table.set_column(i, name, encoded.indices)
    # compared as integers: a timestamp's Python value may drop its nanoseconds
    table = table.set_column(4, "recorded_ts", pc.cast(table["recorded_ts"], pa.int64()))
    table = table.group_by(cols).aggregate([])  # each violation once, as a set holds it
    key, bag = ["requirement", "robot"], ["requirement", "robot", "bag_sha256"]
    config = names["config_sha256"].to_pylist()

    def of(sha: str) -> pa.Table:
        if sha not in config:
            return table.slice(0, 0).drop_columns(["config_sha256"])
        code = pa.scalar(config.index(sha), table["config_sha256"].type)
        return table.filter(pc.equal(table["config_sha256"], code)).drop_columns(["config_sha256"])

    a, b = of(sha_a), of(sha_b)
    both = a.join(b, [*bag, "recorded_ts"], join_type="inner")
    counts: dict[tuple[str, str], Row] = {}

    requirements, robots = names["requirement"].to_pylist(), names["robot"].to_pylist()

    def row(r: dict[str, Any]) -> Row:
        k = (requirements[r["requirement"]], robots[r["robot"]])
        return counts.setdefault(k, Row(*k))

    for name, t in (("a", a), ("b", b), ("both", both)):
        for r in t.group_by(key).aggregate([([], "count_all")]).to_pylist():
            setattr(row(r), name, r["count_all"])
    # each bag's first violation per config: which config detects first
    firsts = (
        a.group_by(bag)
        .aggregate([("recorded_ts", "min")])
        .join(
            b.group_by(bag).aggregate([("recorded_ts", "min")]),
            bag,
            join_type="full outer",
            left_suffix="_a",
            right_suffix="_b",
        )
    )
    fa, fb = firsts["recorded_ts_min_a"], firsts["recorded_ts_min_b"]
    a_first = pc.or_kleene(pc.and_kleene(pc.is_valid(fa), pc.is_null(fb)), pc.less(fa, fb))
    b_first = pc.or_kleene(pc.and_kleene(pc.is_valid(fb), pc.is_null(fa)), pc.less(fb, fa))
    firsts = firsts.select(key).append_column("a_first", pc.fill_null(a_first, False))
    firsts = firsts.append_column("b_first", pc.fill_null(b_first, False))
    for r in firsts.group_by(key).aggregate([("a_first", "sum"), ("b_first", "sum")]).to_pylist():
        x = row(r)
        x.a_first, x.b_first = int(r["a_first_sum"] or 0), int(r["b_first_sum"] or 0)
    for x in counts.values():
        x.only_a, x.only_b = x.a - x.both, x.b - x.both
    return [counts[k] for k in sorted(counts)]


def lines(rows: list[Row]) -> list[str]:
    """The table for a terminal: the dataset's text escaped (a file anyone can hand
    over: docs/reference/faults.md, "Trust") and cut to a requirement id's length."""
    rows = [
        replace(r, requirement=shown(r.requirement, MAX_CELL), robot=shown(r.robot, MAX_CELL))
        for r in rows
    ]
    width = max([len(r.requirement) for r in rows] + [11])
    rw = max([len(r.robot) for r in rows] + [5])
    out = [
        f"{'requirement':<{width}}  {'robot':<{rw}}  {'A':>7}  {'B':>7}  {'only A':>7}  "
        f"{'only B':>7}  {'both':>7}  first in bags (A/B)"
    ]
    for r in rows:
        out.append(
            f"{r.requirement:<{width}}  {r.robot:<{rw}}  {r.a:>7}  {r.b:>7}  {r.only_a:>7}  "
            f"{r.only_b:>7}  {r.both:>7}  {r.a_first}/{r.b_first}"
        )
    return out
