"""The dataset's writers (supervisor/tools/fleet/dataset.py, ``Writers``): files
written on threads, results given back in order once written, and a write that fails
stops the run as one line, as a write in the parent did; the files made durable in
groups (``Commits``), and a row a power loss damaged replayed with one line."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from tests.supervisor.tools.fleet.test_fleet_replay import BAGS, fleet, query
from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

pytest.importorskip("pyarrow")


def test_every_bag_is_written_once_and_counted_once_written(tmp_path):
    for i in range(12):
        write_bag(tmp_path / "fleet" / f"robot-{i % 3}" / f"b{i:02d}", messages(40 + i, 400))
    ds = tmp_path / "ds"
    run = fleet(config(tmp_path), tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(0,))
    assert "12 bags (12 read, 0 skipped, 0 damaged, 0 failed)" in run.stdout
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (12, 12)
    assert not list(ds.rglob(".*.tmp"))  # every file whole, no temporary left


def test_a_write_that_fails_mid_run_is_one_line(tmp_path):
    for i in range(3):
        write_bag(tmp_path / "fleet" / "robot-a" / f"b{i}", messages(50 + i, 1500))
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "violations").write_text("")  # a file where the violations' directory goes
    run = fleet(config(tmp_path), tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "cannot write the dataset" in lines[0], run.stderr
    assert "ds/violations" in lines[0] and "internal error" not in lines[0]
    assert run.stdout == ""  # no summary: the run stopped at the failed write


def _small_fleet(root: Path, n: int) -> None:
    for i in range(n):
        write_bag(root / f"robot-{i % 2}" / f"b{i:02d}", messages(200 + i, 120))


def _files(ds: Path) -> dict[str, list[tuple]]:
    """Each of the dataset's files by name, with its rows (the bags' without the
    task's time and ``finished_ts``, which differ from run to run)."""
    import pyarrow.parquet as pq

    out = {}
    for f in sorted(ds.rglob("*.parquet")):
        table = pq.read_table(f)
        if f.parent.name == "bags":
            table = table.drop_columns(["seconds", "finished_ts"])
        out[str(f.relative_to(ds))] = sorted(table.to_pylist(), key=str)
    return out


SYNCS = ("fsync", "fdatasync", "syncfs")


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_the_files_are_synced_in_groups_and_once_after_the_last_row(tmp_path):
    # Every sync call of the run's processes, and every rename: far fewer syncs than
    # bags (one a group, dataset.Commits, where each file and its directory were
    # fsynced), and one after the last row was renamed into place (Dataset.sync).
    n = 40
    root = tmp_path / "fleet"
    _small_fleet(root, n)
    cfg = config(tmp_path)
    clean = tmp_path / "clean"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))  # the monitor cached first
    ds, trace = tmp_path / "ds", tmp_path / "trace"
    subprocess.run(
        ["strace", "-f", "-qq", "-o", str(trace), "-e",
         f"trace={','.join(SYNCS)},rename,renameat,renameat2",
         sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(ds), "--jobs", "1", "--quiet"],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    lines = trace.read_text().splitlines()
    syncs = [i for i, line in enumerate(lines) if _call(line) in SYNCS and _returned(line)]
    rows = [
        i for i, line in enumerate(lines) if _call(line).startswith("rename") and "/bags/" in line
    ]
    assert len(rows) == n
    assert 1 <= len(syncs) <= n // 2, len(syncs)
    assert syncs[-1] > rows[-1]
    assert _files(ds) == _files(clean)
    assert len(_files(ds)) > n  # the violations' files too


def _call(line: str) -> str:
    """The system call an strace -f line is about (``PID name(...`` or
    ``PID <... name resumed>``)."""
    rest = line.split(maxsplit=1)[1] if " " in line else ""
    if rest.startswith("<... "):
        return rest[5:].split()[0]
    return rest.split("(", 1)[0]


def _returned(line: str) -> bool:
    return " = " in line and "unfinished" not in line


def _one_row_damaged(tmp_path: Path) -> tuple[Path, Path, Path, Path]:
    """Two bags replayed, then one's row emptied as a power loss leaves it: the
    archive, the config, the dataset and that row."""
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    row = sorted((ds / "bags").glob("*.parquet"))[0]
    row.write_bytes(b"")
    return root, cfg, ds, row


def test_a_row_a_power_loss_damaged_is_one_line_and_its_bag_is_replayed(tmp_path):
    # A power loss before a group's sync can leave a row file empty or cut short
    # (dataset.py): the next run says so in one line and replays those bags alone.
    n = 6
    root = tmp_path / "fleet"
    _small_fleet(root, n)
    cfg = config(tmp_path)
    clean, ds = tmp_path / "clean", tmp_path / "ds"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    rows = sorted((ds / "bags").glob("*.parquet"))
    empty, cut = rows[1], rows[4]
    empty.write_bytes(b"")
    whole = cut.read_bytes()
    cut.write_bytes(whole[: len(whole) // 2])
    run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, run.stderr
    assert str(empty) in lines[0] and "(and 1 more)" in lines[0] and "replayed" in lines[0]
    assert f"2 bags (2 read, 0 skipped, 0 damaged, 0 failed), {n - 2} done before" in run.stdout
    assert _files(ds) == _files(clean)
    again = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert again.stderr.strip() == ""
    assert f"0 bags (0 read, 0 skipped, 0 damaged, 0 failed), {n} done before" in again.stdout


def test_a_run_refused_at_the_lock_leaves_a_damaged_row_to_the_writer(tmp_path):
    # The damaged rows are the dataset's writer's to remove (Dataset.drop): a run
    # refused because another holds the lock writes nothing, that row included.
    import fcntl

    from supervisor.tools.fleet.dataset import LOCK

    root, cfg, ds, row = _one_row_damaged(tmp_path)
    before = sorted(str(p.relative_to(ds)) for p in ds.rglob("*.parquet"))
    fd = os.open(ds / LOCK, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # another run, writing
        run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(1,))
    finally:
        os.close(fd)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "being written by another fleet replay" in lines[0], lines
    assert row.exists() and row.stat().st_size == 0
    assert sorted(str(p.relative_to(ds)) for p in ds.rglob("*.parquet")) == before


def test_a_damaged_row_another_run_rewrote_before_the_lock_is_kept(tmp_path):
    # What an earlier run finished is read before the lock (the workers take it as they
    # start); a run with another config held there (its worker's compile stopped) while
    # a run of the first config replays the damaged row's bag and rewrites that row
    # (a row's name is its key): the held run, once it has the lock, removes only rows
    # that are damaged still, and the first config's row stays.

    from tests.supervisor.tools.fleet.test_fleet_replay import _workers, started, while_stopped

    root, cfg, ds, row = _one_row_damaged(tmp_path)
    other = tmp_path / "other.yaml"
    other.write_text(cfg.read_text() + "# another config: another identity\n")
    held = started(other, root, ds)

    def first_config_run() -> None:  # the held run waits for its compile, before the lock
        first = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
        assert "replayed" in first.stderr and row.stat().st_size > 0, first.stderr

    def worker() -> int | None:
        return next(iter(_workers(held.pid)), None)

    _out, err = while_stopped(held, worker, first_config_run)
    assert held.returncode == 0 and err.strip() == "", err
    assert row.stat().st_size > 0
    (n,) = query(f"SELECT count(*) FROM {BAGS.format(ds)} WHERE status = 'read'")[0]
    assert n == 4  # two bags, two configs


def test_a_damaged_row_of_a_bag_whose_files_changed_leaves_no_duplicates(tmp_path):
    # The damaged row's bag is now under another key (its files touched, as a copy
    # without -p leaves them): its old violation files were left beside the new ones
    # (each violation two rows), and the damaged row stayed, said on every run and
    # refused by fleet report for good.
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    cfg = config(tmp_path)
    clean, ds = tmp_path / "clean", tmp_path / "ds"
    fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    import pyarrow.parquet as pq

    row = next(r for r in (ds / "bags").glob("*.parquet") if list(ds.rglob(f"*/*/{r.name}")))
    bag = Path(pq.read_table(row)["bag"][0].as_py())
    row.write_bytes(b"")
    for f in bag.iterdir():
        os.utime(f, ns=(1, 1))  # its fingerprint new, none of its content
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert len([line for line in run.stderr.splitlines() if line.strip()]) == 1, run.stderr
    names = sorted(str(f.relative_to(ds)) for f in ds.rglob("*.parquet"))
    assert names == sorted(str(f.relative_to(clean)) for f in clean.rglob("*.parquet"))
    assert sorted(_files(ds).values(), key=str) == sorted(_files(clean).values(), key=str)
    again = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert again.stderr.strip() == ""
    report = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "report", ds, "-o", tmp_path / "r.html"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert report.returncode == 0, report.stderr


@pytest.mark.parametrize(
    "make, said",
    [
        ("link", "zz.parquet: a link"),  # another dataset's row, counted as finished here
        ("fifo", "zz.parquet: a FIFO"),
        ("directory", "zz: not a .parquet file here"),
    ],
)
def test_resume_refuses_what_fleet_replay_never_writes_in_the_bags_table(tmp_path, make, said):
    # The bags table is read one way by fleet replay's resume and by fleet report
    # (dataset.py, ``dataset_files``): a link, a FIFO or a stray directory is one line.
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    cfg = config(tmp_path)
    other, ds = tmp_path / "other", tmp_path / "ds"
    fleet(cfg, root, "-o", other, "--jobs", "1", ok=(0,))
    (ds / "bags").mkdir(parents=True)
    if make == "link":
        (ds / "bags" / "zz.parquet").symlink_to(next((other / "bags").iterdir()))
    elif make == "fifo":
        os.mkfifo(ds / "bags" / "zz.parquet")
    else:
        (ds / "bags" / "zz").mkdir()
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(ds), "--jobs", "1"],
        capture_output=True, text=True, timeout=120,  # a FIFO's wait fails here
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1 and said in lines[0], run.stderr
    assert str(ds / "bags") in lines[0] and "internal error" not in lines[0]
    assert not (ds / "violations").exists()  # said before any bag was replayed


def test_compare_reads_the_violations_as_fleet_report_does(tmp_path):
    # --compare's counts come from the dataset's violations, read by the same reader
    # as fleet report's (dataset.py, ``Dataset.violations``): a link in them is one
    # line, where pyarrow's discovery walked a loop without end.
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    a, b = config(tmp_path, "a.yaml", limit=2.0), config(tmp_path, "b.yaml", limit=2.3)
    ds = tmp_path / "ds"
    fleet(a, root, "-o", ds, "--compare", b, "--jobs", "1", ok=(0,))
    robot = next((ds / "violations").iterdir())
    (robot / "loop").symlink_to("..")
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(a), str(root), "-o",
         str(ds), "--compare", str(b), "--jobs", "1"],
        capture_output=True, text=True, timeout=120,  # a walk without end fails here
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1, run.stderr
    assert f"{robot}/loop: a link" in lines[0] and "internal error" not in lines[0]


def test_a_damaged_row_is_removed_through_no_link(tmp_path):
    # Removing a damaged row's violation files (Dataset.drop) lists them as every
    # other reading does: a partition that is a link to another directory is one
    # line, and nothing there is removed.
    root, cfg, ds, row = _one_row_damaged(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "date=2026-01-01").mkdir(parents=True)
    kept = elsewhere / "date=2026-01-01" / row.name
    kept.write_bytes(b"not this dataset's")
    (ds / "violations" / "robot=zz").symlink_to(elsewhere)
    run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "robot=zz: a link" in lines[0], run.stderr
    assert kept.read_bytes() == b"not this dataset's"


def test_a_row_the_reader_may_not_read_is_not_taken_for_a_power_loss(tmp_path):
    # An unreadable row (another user's dataset, mode 600) was called "empty or cut
    # short, as a power loss leaves it", with the hint to run again: that run would
    # take it for damage. It is one line saying why it cannot be read.
    root, cfg, ds, row = _one_row_damaged(tmp_path)
    fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))  # the damaged row replayed again
    # pytest's own directories are root's alone: the dataset is copied where all may look
    pub = Path(tempfile.mkdtemp(prefix="ss-fleet-unreadable-"))
    try:
        shown = pub / "ds"
        shutil.copytree(ds, shown)
        pub.chmod(0o755)
        row = shown / row.relative_to(ds)
        for d in shown.rglob("*"):
            d.chmod(0o755 if d.is_dir() else (0o600 if d == row else 0o644))
        _report_as_nobody(shown, row)
    finally:
        shutil.rmtree(pub)


def _report_as_nobody(ds: Path, row: Path) -> None:
    r = subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-m",
         "supervisor", "fleet", "report", str(ds), "-o", "/dev/null", "--quiet"],
        capture_output=True, text=True, timeout=300, env={**os.environ, "HOME": "/nonexistent"},
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = r.stderr.strip().splitlines()
    assert len(said) == 1 and str(row) in said[0] and "Permission denied" in said[0], r.stderr
    assert "power loss" not in said[0], r.stderr


def _good_and_bad(tmp_path: Path) -> tuple[Path, Path, Path, Path]:
    """A small fleet's archive, config, dataset, and a copy of it to damage."""
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    cfg = config(tmp_path, limit=2.0)
    good, bad = tmp_path / "good", tmp_path / "bad"
    fleet(cfg, root, "-o", good, "--jobs", "1", ok=(0,))
    shutil.copytree(good, bad)
    return root, cfg, good, bad


def _tampered(ds: Path, table: str, column: str, value: object) -> Path:
    """The first file of ``table`` with every value of ``column`` replaced by
    ``value`` (None: null; bytes: raw bytes in the string column); the file."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    f = sorted(ds.glob("bags/*.parquet" if table == "bags" else "violations/*/*/*.parquet"))[0]
    t = pq.read_table(f, partitioning=None)
    at = t.schema.get_field_index(column)
    if isinstance(value, bytes):  # pyarrow builds no such array checked: view its bytes
        values = pa.array([value] * t.num_rows, pa.binary()).view(pa.string())
    else:
        values = pa.array([value] * t.num_rows, t.schema.field(at).type)
    pq.write_table(t.set_column(at, column, values), f)
    return f


@pytest.mark.parametrize(
    "table, column, value, said",
    [
        ("violations", "requirement", None, "column requirement has null values"),
        ("violations", "config_sha256", None, "column config_sha256 has null values"),
        ("violations", "bag", None, "column bag has null values"),
        (
            "violations",
            "requirement",
            b"r\xff\xfe",
            "column requirement has text that is not UTF-8",
        ),
        ("bags", "robot", b"\xc3(", "column robot has text that is not UTF-8"),
        ("bags", "status", None, "column status has null values"),
        ("bags", "status", "weird", "status 'weird' is none of read, skipped, damaged, failed"),
        ("bags", "messages", -1, "messages is below zero"),
    ],
)
def test_nulls_and_text_not_utf8_are_one_line_naming_the_column(
    tmp_path, table, column, value, said
):
    """fleet replay writes neither (its empty texts are ""); the page's sorting and
    decoding of them ended in an internal error (exit 3), as report and as baseline."""
    _, _, good, bad = _good_and_bad(tmp_path)
    f = _tampered(bad, table, column, value)
    for args in ([str(bad)], [str(good), "--baseline", str(bad)]):
        run = subprocess.run(
            [sys.executable, "-m", "supervisor", "fleet", "report", *args, "-o",
             str(tmp_path / "f.html"), "--quiet"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        lines = [line for line in run.stderr.splitlines() if line.strip()]
        assert run.returncode == 1 and len(lines) == 1, run.stderr
        assert lines[0].startswith(f"{f}: ") and said in lines[0], lines[0]


@pytest.mark.parametrize("table, column", [("bags", "status"), ("violations", "requirement")])
def test_a_column_name_not_utf8_in_a_footer_is_one_line(tmp_path, table, column):
    """The footer's names are decoded as pyarrow reads them: one byte flipped in one
    ended fleet report, and the resume, in an internal error (exit 3)."""
    root, cfg, good, bad = _good_and_bad(tmp_path)
    f = sorted(bad.glob("bags/*.parquet" if table == "bags" else "violations/*/*/*.parquet"))[0]
    data = bytearray(f.read_bytes())
    data[data.rfind(column.encode()) + 1] = 0xF3  # the last: the footer's
    f.write_bytes(bytes(data))
    said = "its footer has a name that is not UTF-8"
    for args in (
        ["report", str(bad)],
        ["report", str(good), "--baseline", str(bad)],
        ["replay", str(cfg), str(root), "-o", str(bad), "--jobs", "1"],
    ):
        if args[0] == "replay" and table != "bags":
            continue  # the resume reads the bags' rows alone
        run = subprocess.run(
            [sys.executable, "-m", "supervisor", "fleet", *args, "--quiet"]
            + (["-o", str(tmp_path / "f.html")] if args[0] == "report" else []),
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        lines = [line for line in run.stderr.splitlines() if line.strip()]
        assert run.returncode == 1 and len(lines) == 1, (args, run.stderr)
        assert lines[0].startswith(f"{f}: ") and said in lines[0], lines[0]


def test_compares_table_shows_the_datasets_text_escaped_and_cut(tmp_path):
    """A requirement with a terminal's escapes (a window title, clear screen) and 5,000
    characters went to the terminal as it was."""
    root = tmp_path / "fleet"
    _small_fleet(root, 2)
    a, b = config(tmp_path, "a.yaml", limit=2.0), config(tmp_path, "b.yaml", limit=2.3)
    ds = tmp_path / "ds"
    fleet(a, root, "-o", ds, "--compare", b, "--jobs", "1", ok=(0,))
    _tampered(ds, "violations", "requirement", "\x1b]0;pwned\x07\x1b[2J" + "r" * 5000)
    run = fleet(a, root, "-o", ds, "--compare", b, "--jobs", "1", ok=(0,))
    assert "\x1b" not in run.stdout and "\x07" not in run.stdout
    assert "\\x1b]0;pwned\\x07\\x1b[2J" in run.stdout
    assert max(len(line) for line in run.stdout.splitlines()) < 300, run.stdout


# A file listed as a regular one (``dataset_files``), then swapped before it is read:
# the reader is handed the stale listing, as a swap in that window would leave it.
SWAPPED = """
import os, sys
from pathlib import Path
from monitors.errors import UserError
from supervisor.tools.fleet import dataset
ds, table, make = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
where = ds / table
levels = () if table == "bags" else ("robot", "date")
listed = dataset.dataset_files(where, levels)
victim = Path(listed[0])
victim.unlink()
if make == "fifo":
    os.mkfifo(victim)
else:
    victim.symlink_to(sys.argv[4])
dataset.dataset_files = lambda *_: listed
try:
    if table == "bags":
        dataset.Dataset(ds, make=False).done()
    else:
        dataset.Dataset(ds, make=False).violations()
except UserError as e:
    print(e)
    sys.exit(1)
"""


@pytest.mark.parametrize("table", ["bags", "violations"])
@pytest.mark.parametrize("make", ["fifo", "link"])
def test_a_file_swapped_after_the_listing_is_one_line_not_a_wait(tmp_path, table, make):
    root = tmp_path / "fleet"
    for i in range(2):
        write_bag(root / f"robot-{i}" / f"b{i}", messages(300 + i, 1500))
    ds, other = tmp_path / "ds", tmp_path / "other"
    cfg = config(tmp_path)
    fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    fleet(cfg, root, "-o", other, "--jobs", "1", ok=(0,))
    # the link: to the same file of another dataset, which reads as a good one
    twin = next((other / table).rglob("*.parquet"))
    assert list((ds / "violations").rglob("*.parquet")), "the bags must violate"
    run = subprocess.run(
        [sys.executable, "-c", SWAPPED, ds, table, make, twin],
        capture_output=True, text=True, timeout=60,  # a FIFO's open waited for ever
    )  # fmt: skip
    assert run.returncode == 1, (run.stdout, run.stderr)
    said = "a FIFO" if make == "fifo" else "a link"
    assert f"{said}, not a file fleet replay writes" in run.stdout, run.stdout
    assert "Traceback" not in run.stderr
