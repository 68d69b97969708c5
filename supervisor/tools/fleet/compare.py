"""Two configs' violations in one dataset, compared: per requirement and robot, the
violations only A reports, only B reports and both (matched by bag content, requirement
and recorded time, as ``replay --compare`` matches them by time), and in how many
bags each config detects first."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import pyarrow as pa
import pyarrow.compute as pc


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
    """Rows sorted by requirement and robot, over the bags (content hashes) ``bags``."""
    keep = pc.is_in(violations["bag_sha256"], pa.array(sorted(bags), pa.string()))
    seen: dict[str, dict[tuple[str, str], dict[str, set[int]]]] = {sha_a: {}, sha_b: {}}
    cols = ["config_sha256", "requirement", "robot", "bag_sha256", "recorded_ts"]
    table = violations.filter(keep).select(cols)
    # compared as integers: a timestamp's Python value may drop its nanoseconds
    table = table.set_column(4, "recorded_ts", pc.cast(table["recorded_ts"], pa.int64()))
    for row in table.to_pylist():
        sha = row["config_sha256"]
        if sha in seen:
            by_bag = seen[sha].setdefault((row["requirement"], row["robot"]), defaultdict(set))
            by_bag[row["bag_sha256"]].add(row["recorded_ts"])
    rows = []
    for key in sorted(set(seen[sha_a]) | set(seen[sha_b])):
        ra, rb = seen[sha_a].get(key, {}), seen[sha_b].get(key, {})
        r = Row(*key)
        for bag in set(ra) | set(rb):
            ta, tb = ra.get(bag, set()), rb.get(bag, set())
            r.a += len(ta)
            r.b += len(tb)
            r.both += len(ta & tb)
            r.only_a += len(ta - tb)
            r.only_b += len(tb - ta)
            fa, fb = min(ta, default=None), min(tb, default=None)
            if fa is not None and (fb is None or fa < fb):
                r.a_first += 1
            elif fb is not None and (fa is None or fb < fa):
                r.b_first += 1
        rows.append(r)
    return rows


def lines(rows: list[Row]) -> list[str]:
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
