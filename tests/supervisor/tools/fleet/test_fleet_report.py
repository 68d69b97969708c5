"""``fleet report`` end to end: datasets made by the real ``fleet replay`` over real
bags of two robots on three days (tests/support/fleetdata.py), the page written by
the real CLI and opened in headless Chromium, and what it shows checked against the
dataset read with DuckDB: counts per robot and day, bags per status, new and lost
against a baseline with a known difference, the per-bag pages its links lead to.
Hostile dataset text, a dataset too large to list, and damaged input too."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

import pytest
from browser import open_page
from fleetdata import fleet_archive, fleet_configs, fleet_replay

duckdb = pytest.importorskip("duckdb")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

VIOLATIONS = "read_parquet('{}/violations/**/*.parquet', hive_partitioning = true)"
BAGS = "read_parquet('{}/bags/*.parquet')"


def report(*args: str | Path, ok: tuple[int, ...] = (0,)) -> subprocess.CompletedProcess[str]:
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "report", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode in ok, run.stderr
    assert "Traceback" not in run.stderr and "internal error" not in run.stderr, run.stderr
    return run


def query(sql: str) -> list[tuple[Any, ...]]:
    return duckdb.sql(sql).fetchall()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The archive, both configs, and three datasets: ``before`` and ``after`` (one
    config each) and ``both`` (fleet replay --compare: before as A, after as B)."""
    tmp = tmp_path_factory.mktemp("fleet")
    fleet_archive(tmp / "archive")
    before, after = fleet_configs(tmp)
    out = {"tmp": tmp, "archive": tmp / "archive", "before.yaml": before, "after.yaml": after}
    for name, args in (
        ("before", [before]),
        ("after", [after]),
        ("both", [before, "--compare", after]),
    ):
        out[name] = tmp / name
        fleet_replay(args[0], tmp / "archive", "-o", out[name], "--jobs", "2", *args[1:])
    return out


class Tags(HTMLParser):
    """Every element's tag, attributes and text, in order (for pages not opened in
    a browser)."""

    def __init__(self) -> None:
        super().__init__()
        self.elements: list[tuple[str, dict[str, str]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.elements.append((tag, {k: v or "" for k, v in attrs}))


def elements(html: str) -> list[tuple[str, dict[str, str]]]:
    p = Tags()
    p.feed(html)
    return p.elements


def test_the_page_shows_the_datasets_counts_and_links_each_bag_to_its_page(fleet, tmp_path):
    ds = fleet["after"]
    out = tmp_path / "site" / "fleet.html"
    run = report(
        ds, "-o", out, "--bags", tmp_path / "site" / "bags", "--config", fleet["after.yaml"]
    )
    assert run.stderr == ""  # a pipe, not a terminal: no progress
    assert run.stdout.startswith(f"wrote {out}: ")
    pw, page, console, requests = open_page(out.as_uri())
    try:
        # per requirement, robot and day, as DuckDB counts the dataset
        shown = page.evaluate(
            """[...document.querySelectorAll('section.heat-map')].flatMap(s =>
                [...s.querySelectorAll('tr[data-robot]')].flatMap(r =>
                  [...r.querySelectorAll('td[data-day]')].filter(c => c.textContent !== '')
                    .map(c => [s.dataset.requirement, r.dataset.robot, c.dataset.day,
                               +c.textContent])))"""
        )
        want = query(
            "SELECT requirement, robot, CAST(date AS VARCHAR), count(*) "
            f"FROM {VIOLATIONS.format(ds)} GROUP BY ALL ORDER BY ALL"
        )
        assert sorted(map(tuple, shown)) == want and len({w[2] for w in want}) == 3
        # the legend says what the colours mean in numbers
        assert "1000+" in page.locator("#heat-legend").inner_text()
        # the bags per robot and status, and the failed one's reason
        bags = page.evaluate(
            """[...document.querySelectorAll('tr.bag-robot')].flatMap(r =>
                [...r.querySelectorAll('td[data-status]')].filter(c => +c.textContent > 0)
                  .map(c => [r.dataset.robot, c.dataset.status, +c.textContent]))"""
        )
        assert sorted(map(tuple, bags)) == query(
            f"SELECT robot, status, count(*) FROM {BAGS.format(ds)} GROUP BY ALL ORDER BY ALL"
        )
        reason = page.locator("tr.not-read[data-status='failed']").inner_text()
        assert "broken/metadata.yaml" in reason
        # every bag listed links to its own incident page, a file beside the fleet page
        rows = page.evaluate(
            """[...document.querySelectorAll('section.heat-map')].flatMap(s =>
                [...s.querySelectorAll('tr.violation')].map(r => [s.dataset.requirement,
                  r.querySelector('a') && r.querySelector('a').getAttribute('href'),
                  r.querySelector('td.mono').textContent, +r.dataset.count]))"""
        )
        per_bag = dict(
            ((req, bag), n)
            for req, bag, n in query(
                f"SELECT requirement, bag, count(*) FROM {VIOLATIONS.format(ds)} GROUP BY ALL"
            )
        )
        assert len(rows) == len(per_bag)  # five bags with violations: all listed
        for req, href, bag, n in rows:
            assert href and not href.startswith(("/", "file:")), href
            target = (out.parent / unquote(urlsplit(href).path)).resolve()
            assert target.is_file() and target.parent == (tmp_path / "site" / "bags"), href
            # named from hashes: no dataset text reaches a path
            assert re.fullmatch(r"[0-9a-f]{32}\.html", target.name) and n == per_bag[(req, bag)]
        assert console == [], console
        assert requests == [out.as_uri()], requests
        # a linked page is report's page of that bag: the same count for each requirement
        req, href, bag, n = rows[0]
        page.goto((out.parent / unquote(href)).resolve().as_uri())
        got = page.locator(f".req-row[data-requirement='{req}']").get_attribute("data-violations")
        assert int(got or -1) == n
        assert page.locator("#timeline #axis text").count() > 2  # its script ran
        assert console == [], console
    finally:
        pw.stop()


def changes(html: str) -> dict[tuple[str, str], tuple[int, int]]:
    return {
        (a["data-requirement"], a["data-robot"]): (int(a["data-new"]), int(a["data-lost"]))
        for tag, a in elements(html)
        if tag == "tr" and a.get("class") == "change"
    }


def test_new_and_lost_against_a_baseline_as_duckdb_finds_them(fleet, tmp_path):
    before, after = fleet["before"], fleet["after"]
    out = tmp_path / "f.html"
    report(after, "-o", out, "--baseline", before)
    shown = changes(out.read_text())
    # new: in after only; lost: in before only (same bag content, requirement, time)
    diff = """SELECT requirement, robot, count(*) FROM {a} x WHERE NOT EXISTS (
                SELECT 1 FROM {b} y WHERE x.bag_sha256 = y.bag_sha256
                AND x.requirement = y.requirement AND x.recorded_ts = y.recorded_ts)
              GROUP BY ALL"""
    va, vb = VIOLATIONS.format(before), VIOLATIONS.format(after)
    new = {(q, r): n for q, r, n in query(diff.format(a=vb, b=va))}
    lost = {(q, r): n for q, r, n in query(diff.format(a=va, b=vb))}
    pairs = query(
        f"SELECT DISTINCT requirement, robot FROM {va} UNION SELECT DISTINCT requirement, robot FROM {vb}"
    )
    assert shown == {k: (new.get(k, 0), lost.get(k, 0)) for k in pairs}
    # the known difference: the raised limit loses violations of 'limit' on both robots
    assert shown[("limit", "robot-a")][1] > 0 and shown[("limit", "robot-b")][1] > 0
    assert all(v == (0, 0) for (q, _), v in shown.items() if q != "limit")
    assert not new
    # the lost ones are listed by bag, each bag's count as DuckDB finds it
    lost_bags = {
        (a["data-robot"], int(a["data-count"]))
        for tag, a in elements(out.read_text())
        if tag == "tr" and a.get("class") == "lost-violation"
    }
    by_bag = query(diff.format(a=va, b=vb).replace("requirement, robot,", "robot, bag,"))
    assert lost_bags == {(r, n) for r, _, n in by_bag} and len(by_bag) == 5
    # a dataset of fleet replay --compare, its baseline named by its config's hash: the same
    sha = query(f"SELECT DISTINCT config_sha256 FROM {va}")[0][0]
    out2 = tmp_path / "g.html"
    report(fleet["both"], "-o", out2, "--baseline", sha[:12])
    assert changes(out2.read_text()) == shown


HOSTILE_ROBOT = "<b id=pwn1>robot"
HOSTILE_REQ = "<img src=x onerror=alert(1)>"
# a bidi override and a terminal's escape: shown as escapes, never acted on
HOSTILE_BAG = "</td><script>alert(2)</script>\u202egpj.exe\x1b[2J"
SHOWN_BAG = "</td><script>alert(2)</script>\\u202egpj.exe\\x1b[2J"


def test_hostile_dataset_text_is_shown_as_text(fleet, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    from supervisor.tools.fleet.task import VIOLATIONS as SCHEMA

    part = ds / "violations" / f"robot={HOSTILE_ROBOT}" / "date=2026-06-09"
    part.mkdir(parents=True)
    row = {
        "bag": HOSTILE_BAG,
        "bag_sha256": "0" * 64,
        "requirement": HOSTILE_REQ,
        "tick": 1,
        "recorded_ts": 1_780_963_200 * 10**9,
        "config_sha256": query(f"SELECT any_value(config_sha256) FROM {BAGS.format(ds)}")[0][0],
        "inputs": "{}",
    }
    pq.write_table(
        pa.Table.from_pylist([row], schema=SCHEMA.remove(SCHEMA.get_field_index("date"))),
        part / "x.parquet",
    )
    out = tmp_path / "f.html"
    report(ds, "-o", out)
    pw, page, console, requests = open_page(out.as_uri())
    try:
        assert page.locator("img, script, #pwn1").count() == 0
        section = page.locator(
            "section.heat-map", has=page.locator(f"tr[data-robot='{HOSTILE_ROBOT}']")
        )
        assert section.get_attribute("data-requirement") == HOSTILE_REQ
        text = section.inner_text()
        assert HOSTILE_REQ in text and HOSTILE_ROBOT in text and SHOWN_BAG in text
        assert "\u202e" not in out.read_text() and "\x1b" not in out.read_text()
        assert console == [] and requests == [out.as_uri()], (console, requests)
    finally:
        pw.stop()


def test_a_dataset_too_large_to_list_makes_a_bounded_page(tmp_path):
    import pyarrow.dataset as pads

    from supervisor.tools.fleet.summary import MAX_DAYS, MAX_LISTED, MAX_ROBOTS

    robots, days, per_cell = 100, 60, 3
    n = robots * days * per_cell
    day0 = 1_780_272_000 * 10**9
    cells = [(r, d) for r in range(robots) for d in range(days) for _ in range(per_cell)]
    table = pa.table(
        {
            "bag": [f"/data/r{r}/d{d}" for r, d in cells],
            "bag_sha256": [f"{r:04d}{d:04d}" for r, d in cells],
            "requirement": ["limit"] * n,
            "tick": list(range(n)),
            "recorded_ts": pa.array(
                [day0 + d * 86_400 * 10**9 for _, d in cells], pa.timestamp("ns", tz="UTC")
            ),
            "config_sha256": ["c" * 64] * n,
            "inputs": ["{}"] * n,
            "robot": [f"r{r:03d}" for r, _ in cells],
            "date": [f"2026-{6 + d // 30:02d}-{d % 30 + 1:02d}" for _, d in cells],
        }
    )
    ds = tmp_path / "ds"
    (ds / "bags").mkdir(parents=True)
    pads.write_dataset(
        table,
        ds / "violations",
        format="parquet",
        max_partitions=robots * days,
        partitioning=pads.partitioning(
            pa.schema([("robot", pa.string()), ("date", pa.string())]), flavor="hive"
        ),
    )
    out = tmp_path / "f.html"
    report(ds, "-o", out)
    html = out.read_text()
    tags = elements(html)
    heat_rows = [a for t, a in tags if t == "tr" and "data-robot" in a and "class" not in a]
    heat_cells = [a for t, a in tags if t == "td" and "data-day" in a]
    assert len(heat_rows) == MAX_ROBOTS and len(heat_cells) == MAX_ROBOTS * MAX_DAYS
    listed = [a for t, a in tags if t == "tr" and a.get("class") == "violation"]
    assert len(listed) == MAX_LISTED
    assert (
        f"{robots - MAX_ROBOTS} more robot(s) with {(robots - MAX_ROBOTS) * days * per_cell:,} violation(s)"
        in html
    )
    assert (
        f"{days - MAX_DAYS} earlier day(s) with {(days - MAX_DAYS) * robots * per_cell:,} violation(s)"
        in html
    )
    assert f"{robots * days - MAX_LISTED:,} more bag(s) not listed" in html
    assert len(tags) < 3000 and len(html) < 400_000


def test_a_bag_changed_since_its_replay_gets_no_page(tmp_path):
    from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

    bag = write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 600))
    cfg = config(tmp_path)
    fleet_replay(cfg, tmp_path / "fleet", "-o", tmp_path / "ds")
    data = next(bag.glob("*.mcap"))
    st = data.stat()
    data.write_bytes(os.urandom(st.st_size))
    os.utime(data, ns=(st.st_atime_ns, st.st_mtime_ns))  # its names, sizes, times as replayed
    out = tmp_path / "f.html"
    report(tmp_path / "ds", "-o", out, "--bags", tmp_path / "pages", "--config", cfg)
    html = out.read_text()
    assert "its content is not the one replayed" in html
    assert not [a for t, a in elements(html) if t == "a"]
    assert list((tmp_path / "pages").iterdir()) == []


def test_a_dataset_naming_another_path_for_a_bag_chooses_no_reading(tmp_path):
    """The dataset is anybody's file: a bag's path rewritten to name a directory of a
    terabyte (sparse) had ``--bags`` hash it to the end, the command waiting without
    end; the path's files are now checked against the row's fingerprint first."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 600))
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    fleet_replay(cfg, tmp_path / "fleet", "-o", ds)
    huge = tmp_path / "huge"
    huge.mkdir()
    with open(huge / "b.mcap", "wb") as f:
        f.truncate(1 << 40)
    for f in [*ds.glob("bags/*.parquet"), *ds.glob("violations/*/*/*.parquet")]:
        table = pq.read_table(f, partitioning=None)
        at = table.schema.get_field_index("bag")
        pq.write_table(table.set_column(at, "bag", pa.array([str(huge)] * table.num_rows)), f)
    out = tmp_path / "f.html"
    report(ds, "-o", out, "--bags", tmp_path / "pages", "--config", cfg)
    assert "its files are not the ones replayed" in out.read_text()
    assert list((tmp_path / "pages").iterdir()) == []


@pytest.mark.parametrize(
    "make, args, message",
    [
        (None, ["{tmp}/none", "-o", "{tmp}/f.html"], "no such dataset directory"),
        ("plain-dir", ["{tmp}/d", "-o", "{tmp}/f.html"], "no bags/ directory"),
        ("bags:garbage", ["{tmp}/d", "-o", "{tmp}/f.html"], "x.parquet"),
        ("violations:garbage", ["{tmp}/d", "-o", "{tmp}/f.html"], "x.parquet"),
        ("violations:other-columns", ["{tmp}/d", "-o", "{tmp}/f.html"], "violations"),
        ("violations:no-partition", ["{tmp}/d", "-o", "{tmp}/f.html"], "x.parquet: not robot=R"),
        ("plain-ds", ["{tmp}/d", "-o", "{tmp}/f.html", "--baseline", "{tmp}/nope"], "nor the hash"),
        ("plain-ds", ["{tmp}/d", "-o", "{tmp}/f.html", "--baseline", "abcdef0123"], "matches 0"),
        (
            "plain-ds",
            ["{tmp}/d", "-o", "{tmp}/f.html", "--config", "{tmp}/c.yaml"],
            "--config is for --bags",
        ),
        ("plain-ds", ["{tmp}/d", "-o", "{tmp}"], "is a directory"),
    ],
)
def test_bad_input_is_one_line(tmp_path, make, args, message):
    d = tmp_path / "d"
    if make is not None:
        (d / "bags").mkdir(parents=True)
    if make == "plain-dir":
        (d / "bags").rmdir()
    elif make is not None and make.startswith(("bags:", "violations:")):
        table, what = make.split(":")
        where = d / table if table == "bags" else d / "violations" / "robot=r" / "date=2026-01-01"
        if what == "no-partition":
            where = d / "violations"
        where.mkdir(parents=True, exist_ok=True)
        if what == "garbage":
            (where / "x.parquet").write_bytes(b"PAR1garbagePAR1")
        elif what == "other-columns":
            pq.write_table(pa.table({"bag": [1], "tick": ["x"]}), where / "x.parquet")
        else:
            from supervisor.tools.fleet.task import VIOLATIONS as SCHEMA

            schema = SCHEMA.remove(SCHEMA.get_field_index("date"))
            pq.write_table(schema.empty_table(), where / "x.parquet")
            pq.write_table(
                pa.Table.from_pylist([{"bag": "b", "tick": 1}], schema=schema), where / "y.parquet"
            )
    (tmp_path / "c.yaml").write_text("component: x\n")
    run = report(*[a.format(tmp=tmp_path) for a in args], ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], run.stderr


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(40))
def test_a_damaged_parquet_file_is_one_line_never_an_internal_error(fleet, tmp_path, seed, capsys):
    """Bytes flipped, cut or inserted in one file of a real dataset (either table, or
    the baseline's): exit 0 (the damage missed what is read) or 1 with one line."""
    import random

    from supervisor.cli import main

    rng = random.Random(seed)
    ds, base = tmp_path / "ds", tmp_path / "base"
    shutil.copytree(fleet["after"], ds)
    shutil.copytree(fleet["before"], base)
    target = rng.choice(sorted(ds.rglob("*.parquet")) + sorted(base.rglob("*.parquet")))
    data = bytearray(target.read_bytes())
    kind = ("flip", "cut", "insert")[seed % 3]
    if kind == "flip":
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    elif kind == "cut":
        data = data[: rng.randrange(len(data))]
    else:
        at = rng.randrange(len(data))
        data[at:at] = rng.randbytes(rng.randint(1, 50))
    target.write_bytes(bytes(data))
    code = main(
        ["fleet", "report", str(ds), "-o", str(tmp_path / "f.html"), "--baseline", str(base)]
    )
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert (code, len(err)) in ((0, 0), (1, 1)), (kind, target, code, err)
    assert not err or "internal error" not in err[0]


def test_a_terminal_gets_progress_while_bag_pages_are_made(fleet, tmp_path):
    import pty

    leader, follower = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "supervisor", "fleet", "report", str(fleet["after"]), "-o",
         str(tmp_path / "f.html"), "--bags", str(tmp_path / "bags"), "--config",
         str(fleet["after.yaml"])],
        stdout=subprocess.PIPE, stderr=follower, text=True,
    )  # fmt: skip
    os.close(follower)
    shown = b""
    while chunk := _read(leader):
        shown += chunk
    out, _ = proc.communicate(timeout=300)
    os.close(leader)
    assert proc.returncode == 0
    pages = len(list((tmp_path / "bags").glob("*.html")))
    last = shown.decode().rstrip("\r\n").split("\r")[-1]
    assert pages == 5 and last.strip() == f"fleet report: bag page {pages}/{pages}", shown
    assert "\r" not in out and out.startswith("wrote ")


def _read(fd: int) -> bytes:
    try:
        return os.read(fd, 4096)
    except OSError:  # EIO: the child closed the terminal
        return b""


@pytest.mark.parametrize(
    "make, said",
    [
        ("loop", "/loop: a link"),  # pyarrow's discovery walked it without end
        ("link-file", "bags/zz.parquet: a link"),  # another dataset's row, counted as this one's
        ("fifo", ": a FIFO"),  # left out without a word
        ("extra-partition", "extra=1: not a .parquet file here"),  # its rows added to the day's
        ("robot-file", "violations/stray.parquet: not robot=R"),
        ("table-link", "ds/violations: a link"),  # another dataset's rows, read as this one's
    ],
)
def test_a_dataset_of_links_fifos_or_other_directories_is_one_line(fleet, tmp_path, make, said):
    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    robot = ds / "violations" / "robot=robot-a"
    day = next(robot.iterdir())
    if make == "loop":
        (robot / "loop").symlink_to("..")
        (ds / "violations" / "robot=robot-b" / "loop").symlink_to("../..")
    elif make == "link-file":
        (ds / "bags" / "zz.parquet").symlink_to(next((fleet["before"] / "bags").iterdir()))
    elif make == "fifo":
        os.mkfifo(day / "zz.parquet")
    elif make == "extra-partition":
        (day / "extra=1").mkdir()
        shutil.copy(next(day.glob("*.parquet")), day / "extra=1" / "x.parquet")
    elif make == "table-link":
        shutil.rmtree(ds / "violations")
        (ds / "violations").symlink_to(fleet["before"] / "violations")
    else:
        shutil.copy(next(day.glob("*.parquet")), ds / "violations" / "stray.parquet")
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "supervisor",
            "fleet",
            "report",
            str(ds),
            "-o",
            str(tmp_path / "f.html"),
        ],
        capture_output=True,
        text=True,
        timeout=120,  # a walk without end fails here, not at the suite's timeout
    )
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1 and said in lines[0], run.stderr
    assert str(ds) in lines[0] and "internal error" not in lines[0]


@pytest.mark.parametrize("damage", ["empty", "cut"])
def test_a_row_a_power_loss_damaged_is_one_line_naming_its_file(fleet, tmp_path, damage):
    # fleet report reads the bags table as fleet replay's resume does (dataset.py):
    # a row file a power loss left empty or cut short is named, with what to do.
    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    row = sorted((ds / "bags").glob("*.parquet"))[2]
    whole = row.read_bytes()
    row.write_bytes(b"" if damage == "empty" else whole[: len(whole) // 2])
    run = report(ds, "-o", tmp_path / "f.html", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and str(row) in lines[0], run.stderr
    assert "empty or cut short" in lines[0] and "fleet replay" in lines[0]


def _bomb(path: Path, config_sha256: str, rows: int, text: int) -> None:
    """A violations file of ``rows`` rows whose ``bag`` is one string of ``text``
    bytes: dictionary-encoded, it is stored once, and decodes to rows × text."""
    from supervisor.tools.fleet.task import VIOLATIONS as SCHEMA

    bag = pa.DictionaryArray.from_arrays(pa.array([0] * rows, pa.int32()), pa.array(["x" * text]))
    columns = {"bag": bag}  # kept as dictionary codes here: decoded, it is the bomb
    for f in SCHEMA:
        if f.name not in ("bag", "date"):
            value = {"tick": 1, "recorded_ts": 1_780_272_000 * 10**9}.get(f.name, "{}")
            columns[f.name] = pa.array([value] * rows, f.type)
    columns["config_sha256"] = pa.array([config_sha256] * rows, pa.string())
    # as fleet replay's files are read: their Arrow types are Parquet's own (string);
    # its codec, snappy, stores the string in about a twentieth of its size
    pq.write_table(pa.table(columns), path, compression="snappy", store_schema=False)


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _lie(path: Path, size: int) -> None:
    """The footer of ``path`` says every column chunk of ``size`` bytes, as a hostile
    file may: each i64 of that value (Thrift's compact protocol: a zigzag varint) is
    made 100, padded to its length, which pyarrow reads and never checks."""
    data = bytearray(path.read_bytes())
    start = len(data) - 8 - int.from_bytes(data[-8:-4], "little")
    was, now = _varint(size << 1), bytearray(_varint(100 << 1))
    while len(now) < len(was):
        now[-1] |= 0x80
        now.append(0)
    at = data.find(was, start)
    assert at > 0
    while at > 0:
        data[at : at + len(was)] = now
        at = data.find(was, at + 1)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("footer", ["true", "lying"])
def test_a_parquet_decode_bomb_is_one_line_naming_it(fleet, tmp_path, footer):
    # 6 GiB decoded from a file of a few hundred KB, more than the dataset's bound
    # (dataset.py, MAX_DECODED_BYTES): refused before it is decoded, also when its
    # footer says its columns are small.  Run under an address-space limit, so that
    # a report that decodes it fails here at once instead of taking the machine's
    # memory.
    import resource

    from supervisor.tools.fleet.dataset import MAX_DECODED_BYTES

    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    (sha,) = set(pq.read_table(ds / "bags").column("config_sha256").to_pylist())
    day = ds / "violations" / "robot=robot-a" / "date=2026-06-01"
    bomb = day / ("b" * 32 + ".parquet")
    _bomb(bomb, sha, rows=6 * 1024, text=2**20)
    assert bomb.stat().st_size < 1_000_000 and 6 * 2**30 > MAX_DECODED_BYTES
    if footer == "lying":
        column = pq.ParquetFile(bomb).metadata.row_group(0).column(0)
        assert column.path_in_schema == "bag"
        _lie(bomb, column.total_uncompressed_size)
        assert pq.ParquetFile(bomb).metadata.row_group(0).column(0).total_uncompressed_size == 100
    limit = 3 * 2**30

    def capped() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "report", str(ds), "-o",
         str(tmp_path / "f.html")],
        capture_output=True, text=True, timeout=300, preexec_fn=capped,
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1, run.stderr
    assert str(bomb) in lines[0] and "decodes to more than" in lines[0], lines[0]
    assert "internal error" not in lines[0] and "Traceback" not in run.stderr


def test_a_file_of_another_codec_is_not_the_datasets(fleet, tmp_path):
    # zstd or gzip expand a page of a few KB to gigabytes before any row of it is
    # counted: a file compressed other than as fleet replay writes it is refused.
    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    victim = next((ds / "violations").rglob("*.parquet"))
    pq.write_table(pq.read_table(victim), victim, compression="zstd")
    line = _refused(ds, tmp_path)
    assert str(victim) in line and "compressed as ZSTD" in line, line


def test_a_file_is_read_only_if_the_budget_has_room_for_its_columns_decompressed(fleet):
    # snappy expands a page at most about 21 times: that much of what the columns read
    # of a row group store must fit in what the reading may still decode, before a
    # page is decompressed (the columns left on disk, as ``inputs``, do not count)
    from monitors.errors import UserError
    from supervisor.tools.fleet.dataset import _READ, EXPANDS, Budget, read_file

    victim = next((fleet["after"] / "violations").rglob("*.parquet"))
    meta = pq.ParquetFile(victim).metadata
    assert meta.num_row_groups == 1
    group = meta.row_group(0)
    chunks = [group.column(c) for c in range(group.num_columns)]
    stored = sum(k.total_compressed_size for k in chunks if k.path_in_schema in _READ.names)
    assert stored < sum(k.total_compressed_size for k in chunks)  # inputs left out
    room = EXPANDS * stored
    assert read_file(victim, _READ, Budget(room), "violations table").num_rows > 0
    with pytest.raises(UserError, match="decodes to more than") as e:
        read_file(victim, _READ, Budget(room - 1), "violations table")
    assert e.value.file == str(victim)


def test_a_prefix_encoded_text_behind_a_footer_that_says_plain_is_one_line(fleet, tmp_path):
    # A prefix encoding (DELTA_BYTE_ARRAY: each value the previous one's prefix and a
    # suffix) decodes to far more than it stores.  The footer's list of encodings is
    # the file's word and pyarrow decodes each page by its own header, so a footer
    # that says PLAIN does not make it one: the text columns are read as dictionary
    # codes (dataset.py, read_file), which pyarrow cannot build from such pages.
    from supervisor.tools.fleet.task import VIOLATIONS as SCHEMA

    ds = tmp_path / "ds"
    shutil.copytree(fleet["after"], ds)
    victim = next((ds / "violations").rglob("*.parquet"))
    table = pq.read_table(victim)
    text = [f.name for f in SCHEMA if f.name in table.column_names and f.name != "bag"]
    pq.write_table(table, victim, use_dictionary=text, column_encoding={"bag": "DELTA_BYTE_ARRAY"})
    chunk = pq.ParquetFile(victim).metadata.row_group(0).column(0)
    assert chunk.path_in_schema == "bag" and "DELTA_BYTE_ARRAY" in chunk.encodings
    # Thrift's compact protocol: the list<i32> (RLE, DELTA_BYTE_ARRAY), made (RLE, PLAIN)
    data = bytearray(victim.read_bytes())
    start = len(data) - 8 - int.from_bytes(data[-8:-4], "little")
    at = data.index(bytes([0x25, 3 << 1, 7 << 1]), start)
    data[at + 2] = 0
    victim.write_bytes(bytes(data))
    chunk = pq.ParquetFile(victim).metadata.row_group(0).column(0)
    assert set(chunk.encodings) == {"RLE", "PLAIN"}, chunk.encodings
    line = _refused(ds, tmp_path)
    assert str(victim) in line and "not a fleet dataset's violations" in line, line


def _refused(ds: Path, tmp_path: Path) -> str:
    """``fleet report`` of ``ds``'s one line, exit 1."""
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "report", str(ds), "-o",
         str(tmp_path / "f.html")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1, run.stderr
    return lines[0]
