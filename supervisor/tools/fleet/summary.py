"""A fleet dataset read for ``fleet report``: the violations' counts per requirement,
robot and day, the bags table's counts and reasons, and against a baseline the
violations new and lost (compare.py), each list capped so that a dataset of millions
of rows makes a page of a bounded size (docs/reference/fleet.md, "fleet report").

The dataset is untrusted input: every file is read against the schema fleet replay
writes, and anything else is one ``UserError``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.tools.fleet.compare import Row, compare
from supervisor.tools.fleet.dataset import Budget, Dataset
from supervisor.tools.fleet.task import STATUSES

# What one page shows at most; the rest is counted ("N more").
MAX_REQUIREMENTS = 60
MAX_ROBOTS = 40  # rows of a heat map: the robots with the most violations
MAX_DAYS = 31  # columns of a heat map: the latest days
MAX_LISTED = 25  # violations listed per requirement (and per new/lost list)
MAX_REASONS = 50  # bags not read whole, with their reason
MAX_TEXT = 300  # characters of one dataset string shown on the page

HASH = re.compile(r"[0-9a-f]{8,64}")


@dataclass
class Violation:
    robot: str
    date: str
    requirement: str
    bag: str
    bag_sha256: str
    config_sha256: str
    tick: int  # the bag's first violation of the requirement
    recorded_ns: int
    count: int  # the bag's violations of the requirement


@dataclass
class HeatMap:
    """One requirement's (under one config) violations per robot and day."""

    requirement: str
    config_sha256: str
    total: int
    robots: list[str]  # shown rows, most violations first
    days: list[str]  # shown columns, oldest first
    cells: dict[tuple[str, str], int]
    robots_left: int = 0  # robots not shown, and their violations
    robots_left_count: int = 0
    days_left: int = 0
    days_left_count: int = 0
    listed: list[Violation] = field(default_factory=list)  # the top bags
    bags: int = 0  # bags with a violation


@dataclass
class Changes:
    """Against a baseline: per requirement and robot (compare.py), and the first new
    and lost violations of each requirement."""

    base_label: str
    new_label: str
    rows: list[Row]
    new: dict[str, tuple[int, list[Violation]]]  # requirement -> bags, the top bags
    lost: dict[str, tuple[int, list[Violation]]]
    bags_compared: int
    bags_one_side: int


@dataclass
class Summary:
    root: Path
    configs: list[str]
    violations: int
    maps: list[HeatMap]
    maps_left: int
    statuses: dict[str, int]  # bags per status
    messages: int
    per_robot: dict[str, dict[str, int]]  # robot -> status -> bags
    not_read: list[tuple[str, str, str, str]]  # robot, bag, status, reason
    not_read_left: int
    changes: Changes | None = None
    # the bags table's identity columns (bag, config_sha256, bag_sha256, fingerprint):
    # what ``fleet report --bags`` checks a bag on disk against before reading it
    identities: pa.Table | None = None


def check_dataset(root: Path) -> None:
    """A directory fleet replay wrote: it has its bags table."""
    if not root.is_dir():
        raise UserError("no such dataset directory", file=str(root))
    if not (root / "bags").is_dir():
        raise UserError(
            "not a fleet dataset (no bags/ directory)",
            file=str(root),
            hint="give the directory fleet replay -o wrote",
        )


def read_bags(root: Path, budget: Budget) -> pa.Table:
    """The bags table, read as fleet replay's resume reads it (dataset.py): a row a
    power loss damaged is one line naming it, as the page would count its bag as
    not finished without a word."""
    return Dataset(root, make=False).bags(budget=budget)


def read_violations(root: Path, budget: Budget) -> pa.Table:
    """Every violation row with its robot and date, as fleet replay's ``--compare``
    reads them (dataset.py, ``Dataset.violations``), within ``budget``."""
    return Dataset(root, make=False).violations(budget)


def summarize(root: Path, baseline: str | None) -> Summary:
    check_dataset(root)
    budget = Budget()  # the dataset's and the baseline's, all they decode
    bags = read_bags(root, budget)
    table = read_violations(root, budget)
    configs = sorted(set(_configs(table)) | set(_configs(bags)))
    changes = None
    if baseline is not None:
        changes = _changes(root, table, bags, configs, baseline, budget)
    maps = _maps(table)
    statuses = dict.fromkeys(STATUSES, 0)
    per_robot: dict[str, dict[str, int]] = {}
    # counted by Arrow, not row by row: a Python object per row of a bags table of
    # millions of rows took gigabytes past the decoding budget (``Budget``)
    counts = bags.group_by(["robot", "status"]).aggregate([([], "count_all")])
    for c in counts.sort_by([("robot", "ascending"), ("status", "ascending")]).to_pylist():
        statuses[c["status"]] = statuses.get(c["status"], 0) + c["count_all"]
        per_robot.setdefault(c["robot"], {})[c["status"]] = c["count_all"]
    columns = ["robot", "bag", "status", "reason"]
    others = bags.filter(pc.not_equal(bags["status"], "read")).select(columns)
    order = [(c, "ascending") for c in columns]
    not_read = [tuple(r.values()) for r in others.sort_by(order)[:MAX_REASONS].to_pylist()]
    # summed as decimals: an int64 sum wraps past 2**63 without a word
    messages = int(pc.sum(pc.cast(bags["messages"], pa.decimal128(38, 0))).as_py() or 0)
    return Summary(
        root,
        configs,
        table.num_rows,
        maps[:MAX_REQUIREMENTS],
        max(0, len(maps) - MAX_REQUIREMENTS),
        statuses,
        messages,
        dict(sorted(per_robot.items())),
        not_read,  # type: ignore[arg-type] - four strings each
        max(0, others.num_rows - MAX_REASONS),
        changes,
        bags.select(["bag", "config_sha256", "bag_sha256", "fingerprint"]),
    )


def _configs(table: pa.Table) -> list[str]:
    """The configs' hashes a table names, each once."""
    return [c for c in pc.unique(table.column("config_sha256")).to_pylist() if c]


def _per_bag(table: pa.Table, keys: list[str] | None = None) -> pa.Table:
    """Violations counted per requirement, config, robot, bag (and ``keys``): the one
    pass over the rows; everything the page shows comes from this smaller table."""
    by = ["requirement", "config_sha256", "robot", "bag_sha256", "bag", *(keys or [])]
    g = table.group_by(by).aggregate(
        [([], "count_all"), ("recorded_ts", "min"), ("tick", "min"), ("date", "min")]
    )
    return g.rename_columns([*by, "count", "first_ts", "first_tick", "first_date"]).set_column(
        len(by) + 1, "first_ts", pc.cast(g["recorded_ts_min"], pa.int64())
    )


def _maps(table: pa.Table) -> list[HeatMap]:
    """One heat map per requirement and config. The rows are grouped once (per bag
    and day); the maps and lists are made from the groups, never from the rows."""
    per_bag_day = _per_bag(table, ["date"])
    keys = ["requirement", "config_sha256", "robot", "date"]
    grouped = per_bag_day.group_by(keys).aggregate([("count", "sum")]).to_pylist()
    per_bag = _regroup(per_bag_day)
    by_req: dict[tuple[str, str], dict[tuple[str, str], int]] = {}
    for g in grouped:
        by_req.setdefault((g["requirement"], g["config_sha256"]), {})[(g["robot"], g["date"])] = g[
            "count_sum"
        ]
    maps = []
    for (req, sha), cells in by_req.items():
        per_robot: dict[str, int] = {}
        per_day: dict[str, int] = {}
        for (robot, day), n in cells.items():
            per_robot[robot] = per_robot.get(robot, 0) + n
            per_day[day] = per_day.get(day, 0) + n
        robots = sorted(per_robot, key=lambda r: (-per_robot[r], r))
        days = sorted(per_day)
        shown_r, shown_d = robots[:MAX_ROBOTS], days[-MAX_DAYS:]
        maps.append(
            HeatMap(
                req,
                sha,
                sum(cells.values()),
                shown_r,
                shown_d,
                {k: n for k, n in cells.items() if k[0] in set(shown_r) and k[1] in set(shown_d)},
                len(robots) - len(shown_r),
                sum(per_robot[r] for r in robots[MAX_ROBOTS:]),
                len(days) - len(shown_d),
                sum(per_day[d] for d in days[: len(days) - len(shown_d)]),
            )
        )
    maps.sort(key=lambda m: (-m.total, m.requirement, m.config_sha256))
    for m in maps[:MAX_REQUIREMENTS]:
        mine = per_bag.filter(
            pc.and_(
                pc.equal(per_bag["requirement"], m.requirement),
                pc.equal(per_bag["config_sha256"], m.config_sha256),
            )
        )
        m.listed = _top(mine)
        m.bags = pc.count_distinct(mine["bag_sha256"]).as_py()
    return maps


def _regroup(per_bag_day: pa.Table) -> pa.Table:
    """Per bag and day to per bag."""
    by = ["requirement", "config_sha256", "robot", "bag_sha256", "bag"]
    g = per_bag_day.group_by(by).aggregate(
        [("count", "sum"), ("first_ts", "min"), ("first_tick", "min"), ("first_date", "min")]
    )
    return g.rename_columns([*by, "count", "first_ts", "first_tick", "first_date"])


def _top(per_bag: pa.Table) -> list[Violation]:
    """The ``MAX_LISTED`` bags with the most violations, each as its first violation
    with the bag's count."""
    if per_bag.num_rows == 0:
        return []
    top = per_bag.take(
        pc.select_k_unstable(
            per_bag,
            k=min(MAX_LISTED, per_bag.num_rows),
            sort_keys=[("count", "descending"), ("robot", "ascending"), ("bag", "ascending")],
        )
    )
    rows = sorted(top.to_pylist(), key=lambda r: (-r["count"], r["robot"], r["bag"]))
    return [
        Violation(
            r["robot"],
            r["first_date"],
            r["requirement"],
            r["bag"],
            r["bag_sha256"],
            r["config_sha256"],
            r["first_tick"],
            r["first_ts"],
            r["count"],
        )
        for r in rows
    ]


def _changes(
    root: Path, table: pa.Table, bags: pa.Table, configs: list[str], baseline: str, budget: Budget
) -> Changes:
    """The baseline: another dataset (one config each), or the hash (a prefix of 8
    or more hex digits) of one of this dataset's two configs (fleet replay --compare)."""
    other = Path(baseline)
    if other.is_dir():
        check_dataset(other)
        obags = read_bags(other, budget)
        otable = read_violations(other, budget)
        mine = _one_config(root, table, bags)
        theirs = _one_config(other, otable, obags)
        # relabelled: two datasets may hold the same config (a re-run, another archive)
        a = otable.set_column(_col(otable), "config_sha256", _label(otable, "A"))
        b = table.set_column(_col(table), "config_sha256", _label(table, "B"))
        compared = _finished(obags) & _finished(bags)
        rows = compare(pa.concat_tables([a, b]), "A", "B", compared)
        one_side = len(_finished(obags) ^ _finished(bags))
        labels = f"{other} (config {theirs[:12]})", f"{root} (config {mine[:12]})"
        return _changes_of(rows, otable, table, compared, one_side, *labels)
    if not HASH.fullmatch(baseline):
        raise UserError(
            "no such dataset directory, nor the hash of one of the dataset's configs",
            file=printable(baseline)[:MAX_TEXT],
            hint="--baseline takes a dataset fleet replay wrote, or a config hash "
            "(8 or more hex digits) of a dataset made with fleet replay --compare",
        )
    hits = [c for c in configs if c.startswith(baseline)]
    if len(hits) != 1 or len(configs) != 2:
        raise UserError(
            f"--baseline {baseline}: matches {len(hits)} of the dataset's {len(configs)} "
            "config(s); it must name one of exactly two",
            file=str(root),
        )
    base = hits[0]
    (new,) = [c for c in configs if c != base]
    compared = _finished(bags, base) & _finished(bags, new)
    one_side = len(_finished(bags, base) ^ _finished(bags, new))
    rows = compare(table, base, new, compared)
    ta = table.filter(pc.equal(table["config_sha256"], base))
    tb = table.filter(pc.equal(table["config_sha256"], new))
    labels = f"config {base[:12]}", f"config {new[:12]}"
    return _changes_of(rows, ta, tb, compared, one_side, *labels)


def _changes_of(
    rows: list[Row],
    ta: pa.Table,
    tb: pa.Table,
    compared: set[str],
    one_side: int,
    base_label: str,
    new_label: str,
) -> Changes:
    """``ta``, ``tb``: the baseline's and the new side's violations (their own config
    hashes kept, for the links to each bag's page)."""
    ta, tb = _only(ta, compared), _only(tb, compared)
    keys = ["bag_sha256", "requirement", "recorded_ts"]
    new = tb.join(ta.select(keys), keys=keys, join_type="left anti")
    lost = ta.join(tb.select(keys), keys=keys, join_type="left anti")
    return Changes(
        base_label,
        new_label,
        rows,
        _per_requirement(new),
        _per_requirement(lost),
        len(compared),
        one_side,
    )


def _only(table: pa.Table, bags: set[str]) -> pa.Table:
    """The rows of ``bags``; the table itself when it has no other (the usual case:
    a filter of a million rows costs more than the check)."""
    if bags.issuperset(pc.unique(table["bag_sha256"]).to_pylist()):
        return table
    return table.filter(pc.is_in(table["bag_sha256"], pa.array(sorted(bags), pa.string())))


def _per_requirement(table: pa.Table) -> dict[str, tuple[int, list[Violation]]]:
    per_bag = _per_bag(table)
    out = {}
    reqs = sorted(set(per_bag.column("requirement").to_pylist()))
    for req in reqs[:MAX_REQUIREMENTS]:
        mine = per_bag.filter(pc.equal(per_bag["requirement"], req))
        out[req] = (mine.num_rows, _top(mine))
    return out


def _one_config(root: Path, table: pa.Table, bags: pa.Table) -> str:
    configs = sorted(set(_configs(table)) | set(_configs(bags)))
    if len(configs) != 1:
        raise UserError(
            f"holds {len(configs)} configs; a dataset compared with --baseline DIR holds one",
            file=str(root),
            hint="with fleet replay --compare, give --baseline one config's hash instead",
        )
    return configs[0]


def _col(table: pa.Table) -> int:
    return table.schema.get_field_index("config_sha256")


def _label(table: pa.Table, label: str) -> pa.Array:
    return pa.array([label] * table.num_rows, pa.string())


def _finished(bags: pa.Table, sha: str | None = None) -> set[str]:
    """The content hashes of the bags a config has judged (read or damaged)."""
    ok = pc.is_in(bags["status"], pa.array(["read", "damaged"]))
    if sha is not None:
        ok = pc.and_(ok, pc.equal(bags["config_sha256"], sha))
    return {h for h in bags.filter(ok).column("bag_sha256").to_pylist() if h}
