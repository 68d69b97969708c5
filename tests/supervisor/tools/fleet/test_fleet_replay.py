"""``fleet replay`` end to end: the real CLI in a real process pool over an archive of
real rosbag2 bags (MCAP and sqlite3, written with rosbags) of three robots, one of them
damaged; the dataset read back with DuckDB and checked against ``replay`` of each bag;
resume; ``--compare`` on a known difference."""

from __future__ import annotations

import contextlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zstandard

from supervisor.tools.replay.session import compare, replay_files
from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

duckdb = pytest.importorskip("duckdb")
pytest.importorskip("pyarrow")

VIOLATIONS = "read_parquet('{}/violations/**/*.parquet', hive_partitioning = true)"
BAGS = "read_parquet('{}/bags/*.parquet')"


def archive(tmp: Path) -> dict[str, list[Path]]:
    """Three robots, five good bags of both formats (one compressed), a damaged bag (its file
    garbage after the magic) and one that cannot be opened (its metadata garbage)."""
    root = tmp / "fleet"
    bags = {
        "robot-a": [
            write_bag(root / "robot-a" / "b1", messages(1, 1500)),
            write_bag(root / "robot-a" / "b2", messages(2, 1500), plugin="SQLITE3"),
        ],
        "robot-b": [write_bag(root / "robot-b" / "b3", messages(3, 1500))],
        "robot-c": [
            write_bag(root / "robot-c" / "day1" / "b4", messages(4, 1500), plugin="SQLITE3"),
            write_bag(root / "robot-c" / "day2" / "b5", messages(5, 1500)),
        ],
    }
    compress(bags["robot-b"][0])
    bad = write_bag(root / "robot-c" / "day2" / "bad", messages(6, 1500))
    mcap = next(bad.glob("*.mcap"))
    mcap.write_bytes(b"\x89MCAP0\r\n" + os.urandom(4000))  # the magic, then garbage
    broken = root / "robot-b" / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    return bags


def compress(bag: Path) -> None:
    """The bag compressed per file, as rosbag2's zstd file compressor leaves it."""
    (plain,) = bag.glob("*.mcap")
    packed = plain.with_name(plain.name + ".zstd")
    packed.write_bytes(zstandard.ZstdCompressor().compress(plain.read_bytes()))
    plain.unlink()
    meta = bag / "metadata.yaml"
    text = meta.read_text().replace(plain.name, packed.name)
    text = text.replace("compression_format: ''", "compression_format: zstd")
    meta.write_text(text.replace("compression_mode: ''", "compression_mode: FILE"))


def fleet(*args: str | Path, ok: tuple[int, ...] = (0, 1)) -> subprocess.CompletedProcess[str]:
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode in ok, run.stderr
    assert "Traceback" not in run.stderr
    return run


def query(sql: str) -> list[tuple]:
    return duckdb.sql(sql).fetchall()


def test_an_archive_of_three_robots_is_one_dataset_as_replay_counts_it(tmp_path):
    bags = archive(tmp_path)
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    run = fleet(cfg, tmp_path / "fleet", "-o", ds, "--jobs", "2")
    assert run.returncode == 1  # two bags not read whole: the others are in
    summary = run.stdout.strip().splitlines()
    assert (
        summary == [summary[0]] and "7 bags (5 read, 0 skipped, 1 damaged, 1 failed)" in summary[0]
    )
    rows = query(f"SELECT robot, status, count(*) FROM {BAGS.format(ds)} GROUP BY ALL ORDER BY ALL")
    assert rows == [
        ("robot-a", "read", 2),
        ("robot-b", "failed", 1),
        ("robot-b", "read", 1),
        ("robot-c", "damaged", 1),
        ("robot-c", "read", 2),
    ]
    reasons = dict(query(f"SELECT status, reason FROM {BAGS.format(ds)} WHERE status <> 'read'"))
    assert "bad.mcap" in reasons["damaged"] and "broken/metadata.yaml" in reasons["failed"]
    # each robot's violations per requirement, as replay counts them bag by bag
    want: dict[tuple[str, str], int] = {}
    for robot, paths in bags.items():
        for p in paths:
            for q in replay_files(cfg, [p], None, None)["requirements"]:
                if q["violations"]:
                    want[(robot, q["id"])] = want.get((robot, q["id"]), 0) + q["violations"]
    got = query(f"SELECT robot, requirement, count(*) FROM {VIOLATIONS.format(ds)} GROUP BY ALL")
    assert {(r, q): n for r, q, n in got} == want and len(want) >= 3
    # the inputs that decided each verdict are JSON text, and the date its partition
    (n_bad_json,) = query(
        f"SELECT count(*) FROM {VIOLATIONS.format(ds)} "
        "WHERE json_extract(inputs, '$.speed') IS NULL OR strftime(recorded_ts, '%Y-%m-%d') <> CAST(date AS VARCHAR)"
    )[0]
    assert n_bad_json == 0
    # strict JSON for any reader: a NaN input (speeds are NaN now and then) is a string
    inputs = [
        json.loads(x, parse_constant=_no_constant)
        for (x,) in query(f"SELECT inputs FROM {VIOLATIONS.format(ds)}")
    ]
    assert "nan" in {str(i["speed"]) for i in inputs}


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def test_resume_reads_nothing_finished_and_adds_no_rows(tmp_path):
    bags = archive(tmp_path)
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    fleet(cfg, tmp_path / "fleet", "-o", ds, "--jobs", "2")
    before = query(f"SELECT count(*) FROM {VIOLATIONS.format(ds)}")[0][0]
    # A finished bag's bytes replaced (same size and times): read again, it would fail.
    done = next(bags["robot-a"][0].glob("*.mcap"))
    st = done.stat()
    done.write_bytes(os.urandom(st.st_size))
    os.utime(done, ns=(st.st_atime_ns, st.st_mtime_ns))
    # An interrupted run: one bag's row never written (its violation files were).
    b3 = str(bags["robot-b"][0])
    (key,) = [
        f for f in (ds / "bags").glob("*.parquet")
        if query(f"SELECT bag FROM read_parquet('{f}')")[0][0] == b3
    ]  # fmt: skip
    key.unlink()
    run = fleet(cfg, tmp_path / "fleet", "-o", ds, "--jobs", "2")
    # only the unfinished bag and the failed one (failed bags are tried again)
    assert "2 bags (1 read, 0 skipped, 0 damaged, 1 failed), 5 done before" in run.stdout
    assert query(f"SELECT count(*) FROM {VIOLATIONS.format(ds)}")[0][0] == before
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (7, 7)


def test_compare_counts_what_only_one_config_reports(tmp_path):
    bags = archive(tmp_path)
    a, b = config(tmp_path, "a.yaml", limit=2.0), config(tmp_path, "b.yaml", limit=2.3)
    run = fleet(a, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", b, "--jobs", "2")
    table = {}
    for line in run.stdout.splitlines()[3:]:
        req, robot, na, nb, only_a, only_b, both, _first = line.split()
        table[(req, robot)] = (int(na), int(nb), int(only_a), int(only_b), int(both))
    want: dict[tuple[str, str], list[int]] = {}
    for robot, paths in bags.items():
        for p in paths:
            for q in compare(a, b, [p], None)["requirements"]:
                if q["a"] or q["b"]:
                    w = want.setdefault((q["id"], robot), [0, 0, 0, 0, 0])
                    both = q["a"] - len(q["only_a"])
                    for i, n in enumerate(
                        (q["a"], q["b"], len(q["only_a"]), len(q["only_b"]), both)
                    ):
                        w[i] += n
    assert table == {k: tuple(v) for k, v in want.items()}
    # the known difference: a higher speed limit loses violations of 'limit' only
    assert all(table[("limit", r)][2] > 0 and table[("limit", r)][3] == 0 for r in bags)
    assert all(v[2] == v[3] == 0 for (q, _), v in table.items() if q != "limit")


def test_robot_from_a_rule_and_a_name_that_is_no_partition(tmp_path):
    write_bag(tmp_path / "data" / "unit-7" / "bags" / "b1", messages(1, 300))
    write_bag(tmp_path / "data" / "x=1" / "bags" / "b2", messages(2, 300))
    ds = tmp_path / "ds"
    run = fleet(config(tmp_path), tmp_path / "data", "-o", ds, "--robot-from", "data/{robot}/bags")
    assert run.returncode == 1
    rows = query(f"SELECT robot, status, reason FROM {BAGS.format(ds)} ORDER BY bag")
    assert rows[0][:2] == ("unit-7", "read")
    assert rows[1][:2] == ("", "failed") and "not a plain name" in rows[1][2]
    assert [p.name for p in (ds / "violations").iterdir()] == ["robot=unit-7"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["{cfg}", "{tmp}/nothing-here", "-o", "{tmp}/ds"], "no such directory, bag or match"),
        (["{cfg}", "{tmp}", "-o", "{tmp}/ds", "--robot-from", "x"], "must hold {robot} once"),
        (["{tmp}/none.yaml", "{tmp}/fleet", "-o", "{tmp}/ds"], "none.yaml"),
        (["{cfg}", "{cfg}", "-o", "{tmp}/ds"], "c.yaml: no bag here"),
        (
            ["{cfg}", "{tmp}/fleet", "-o", "{tmp}/ds", "--robot-from", "**x**{{robot}}"],
            "one * at most",
        ),
    ],
)
def test_bad_input_is_one_line(tmp_path, args, message):
    cfg = config(tmp_path)
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 50))
    run = fleet(*[a.format(cfg=cfg, tmp=tmp_path) for a in args], ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], run.stderr


def test_a_dataset_that_cannot_be_written_is_one_line(tmp_path):
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 200))
    (tmp_path / "file").write_text("")
    run = fleet(config(tmp_path), tmp_path / "fleet", "-o", tmp_path / "file" / "ds", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "file/ds" in lines[0] and "internal error" not in lines[0], lines


@pytest.mark.parametrize("table", ["bags", "violations/robot=r1/date=2026-01-01"])
@pytest.mark.parametrize("data", [b"PAR1garbagePAR1", b"x" * 100, b""])
def test_a_damaged_dataset_is_one_line(tmp_path, table, data):
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 200))
    touch = tmp_path / "ds" / table / "x.parquet"
    touch.parent.mkdir(parents=True)
    touch.write_bytes(data)
    cfg, other = config(tmp_path), config(tmp_path, "d.yaml", limit=2.3)
    run = fleet(cfg, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", other, ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and ("x.parquet" in lines[0] or "ds/bags" in lines[0]), lines
    assert "internal error" not in lines[0]


def test_jobs_is_a_small_positive_number(tmp_path):
    run = fleet(config(tmp_path), tmp_path, "-o", tmp_path / "ds", "--jobs", "0", ok=(2,))
    assert "not a number of processes" in run.stderr


def _workers(parent: int) -> list[int]:
    """The pool's worker processes: children of the fork server that ``parent``
    started (engine.py, ``LocalEngine``)."""
    procs: dict[int, tuple[int, bytes]] = {}
    for d in Path("/proc").iterdir():
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            procs[int(d.name)] = (ppid, (d / "cmdline").read_bytes())
        except (OSError, ValueError, IndexError):
            continue  # not a process, or one that has just exited
    servers = {p for p, (pp, cmd) in procs.items() if pp == parent and b"forkserver" in cmd}
    return [p for p, (pp, _) in procs.items() if pp in servers]


def _reading_a_bag(parent: int, bag: Path | None = None) -> int | None:
    """A worker that has a bag's file open (``bag``'s if given): it is in the middle
    of a task."""
    for pid in _workers(parent):
        try:
            fds = [os.readlink(f) for f in Path(f"/proc/{pid}/fd").iterdir()]
        except OSError:
            continue
        if any(f.endswith((".mcap", ".db3")) and f.startswith(str(bag or "")) for f in fds):
            return pid
    return None


def four_bags_and_a_clean_run(tmp_path: Path) -> tuple[Path, Path, Path, Path]:
    """Four 40,000-message bags of two robots, long enough to kill a worker in one,
    and a clean run's dataset to compare with: the archive, the config, the clean
    dataset and the path for the killed run's."""
    root = tmp_path / "fleet"
    for i in range(4):
        write_bag(root / f"robot-{i % 2}" / f"b{i}", messages(10 + i, 40000))
    cfg = config(tmp_path)
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    return root, cfg, clean, killed


def started(cfg: Path, root: Path, out: Path) -> subprocess.Popen[str]:
    """``fleet replay --jobs 1`` running in the background, its output piped, in a
    session of its own (``os.killpg`` stops it and its workers)."""
    return subprocess.Popen(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(out), "--jobs", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip


def with_worker(
    proc: subprocess.Popen[str], worker: Callable[[], int | None], act: Callable[[int], None]
) -> tuple[str, str]:
    """``act`` done to the worker that ``worker`` finds (its pid), then the run
    (``started``) let go on to its end: its stdout and stderr.  The run's session is
    killed whatever happens."""
    from rosutil import wait_until

    try:
        act(wait_until("the worker", worker, 120))
        return proc.communicate(timeout=300)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def worker_killed(proc: subprocess.Popen[str], bag: Path | None = None) -> tuple[str, str]:
    """The run's worker killed (SIGKILL) while it reads a bag (``bag`` if given)."""
    return with_worker(
        proc, lambda: _reading_a_bag(proc.pid, bag), lambda pid: os.kill(pid, signal.SIGKILL)
    )


def while_stopped(
    proc: subprocess.Popen[str], worker: Callable[[], int | None], meanwhile: Callable[[], None]
) -> tuple[str, str]:
    """``meanwhile`` done while the run's worker is stopped (SIGSTOP)."""

    def act(pid: int) -> None:
        os.kill(pid, signal.SIGSTOP)
        meanwhile()
        os.kill(pid, signal.SIGCONT)

    return with_worker(proc, worker, act)


def test_a_worker_killed_mid_task_is_retried_and_the_dataset_is_whole(tmp_path):

    root, cfg, clean, killed = four_bags_and_a_clean_run(tmp_path)
    proc = started(cfg, root, killed)
    out, err = worker_killed(proc)
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert "4 bags (4 read, 0 skipped, 0 damaged, 0 failed)" in out
    per_bag = (
        "SELECT bag, requirement, count(*), count(DISTINCT tick) FROM {} GROUP BY ALL ORDER BY ALL"
    )
    want = query(per_bag.format(VIOLATIONS.format(clean)))
    assert want and query(per_bag.format(VIOLATIONS.format(killed))) == want
    assert all(n == distinct for _, _, n, distinct in want)


def test_an_earlier_runs_row_is_not_taken_for_this_runs_by_its_clock(tmp_path):
    # A worker killed mid-task: a bag whose row it committed in this run is done, any
    # other is retried.  An earlier run's failed row, written when the clock read later
    # than it does now (set back since, as a robot's clock can be), is not this run's:
    # the bag is retried and read, not counted failed from the old row.
    from unittest import mock

    from supervisor.tools.fleet.archive import list_archive
    from supervisor.tools.fleet.dataset import Dataset
    from supervisor.tools.fleet.task import BagResult, BagTask
    from tests.supervisor.tools.fleet.test_engine import _identity

    root = tmp_path / "fleet"
    bag = write_bag(root / "robot-a" / "b", messages(7, 40000))
    cfg, ds = config(tmp_path), tmp_path / "ds"
    (ref,) = list_archive([str(root)])
    task = BagTask(str(bag), "robot-a", str(cfg), _identity(cfg), None, ref.fingerprint)
    later = time.time_ns() + 86_400 * 10**9  # a day ahead of the clock as it is now
    with mock.patch("time.time_ns", return_value=later):
        Dataset(ds).write(BagResult(task, "failed", "an earlier run's"), "robot-a", ref.fingerprint)
    proc = started(cfg, root, ds)
    out, err = worker_killed(proc, bag)
    assert proc.returncode == 0, out + err
    assert "1 bags (1 read, 0 skipped, 0 damaged, 0 failed)" in out, out


def test_a_second_run_on_a_dataset_being_written_is_one_line(tmp_path):
    """Two runs writing one dataset would replay every bag twice, and each would
    take the other's unfinished files for an interrupted run's: the second is one
    line and writes nothing, the first goes on to a whole dataset."""
    from rosutil import wait_until

    root, cfg, clean, ds = four_bags_and_a_clean_run(tmp_path)
    first = started(cfg, root, ds)
    try:
        wait_until("a worker reading a bag", lambda: _reading_a_bag(first.pid), 120)
        second = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(1,))
        out, err = first.communicate(timeout=300)
    finally:
        first.kill()
        first.wait()
    lines = [line for line in second.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "being written by another fleet replay" in lines[0], lines
    assert str(ds) in lines[0] and second.stdout == ""
    assert first.returncode == 0 and "4 bags (4 read, 0 skipped" in out, err
    per_bag = "SELECT bag, requirement, count(*) FROM {} GROUP BY ALL ORDER BY ALL"
    assert query(per_bag.format(VIOLATIONS.format(ds))) == query(
        per_bag.format(VIOLATIONS.format(clean))
    )


def test_an_interrupted_runs_unfinished_files_are_removed_by_the_next(tmp_path):
    """A writer killed between its temporary file and the rename (supervisor/files.py)
    leaves a hidden ``.K.parquet.XXXX.tmp`` that no reader lists and nothing else
    would remove: the next run removes those, and only those."""
    import tempfile

    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 500))
    cfg, ds = config(tmp_path), tmp_path / "ds"
    fleet(cfg, tmp_path / "fleet", "-o", ds, ok=(0,))
    (row,) = (ds / "bags").glob("*.parquet")
    (part,) = (ds / "violations").glob("robot=*/date=*/*.parquet")
    left = []
    for done in (row, part):  # as files._write names them, a killed writer's
        fd, name = tempfile.mkstemp(dir=done.parent, prefix=f".{done.name}.", suffix=".tmp")
        os.write(fd, b"PAR1 half a file")
        os.close(fd)
        left.append(Path(name))
    kept = [ds / "bags" / ".notes.tmp", ds / "bags" / ".keep"]
    for k in kept:
        k.write_text("not fleet replay's")
    run = fleet(cfg, tmp_path / "fleet", "-o", ds, ok=(0,))
    assert "removed 2 unfinished files of an interrupted run" in run.stderr, run.stderr
    assert not any(f.exists() for f in left) and all(k.exists() for k in kept)
    assert "0 bags (0 read, 0 skipped, 0 damaged, 0 failed), 1 done before" in run.stdout
    again = fleet(cfg, tmp_path / "fleet", "-o", ds, ok=(0,))
    assert "removed" not in again.stderr


def test_a_bag_of_other_topics_and_a_copy_of_a_finished_bag_are_skipped(tmp_path):
    root = tmp_path / "fleet"
    first = write_bag(root / "robot-a" / "b1", messages(1, 500))
    write_bag(root / "robot-a" / "cameras", [(10**9 + i, "/extra", "img") for i in range(50)])
    cfg, ds = config(tmp_path), tmp_path / "ds"
    run = fleet(cfg, root / "robot-a", "-o", ds, "--robot-from", "fleet/{robot}/**", ok=(0,))
    assert "2 bags (1 read, 1 skipped, 0 damaged, 0 failed)" in run.stdout
    # the same bag under another robot's path: hashed, found done, not replayed
    copy = root / "robot-b" / "b1"
    shutil.copytree(first, copy)
    run = fleet(cfg, root, "-o", ds, ok=(0,))
    assert "1 bags (0 read, 1 skipped, 0 damaged, 0 failed), 2 done before" in run.stdout
    rows = dict(query(f"SELECT bag, reason FROM {BAGS.format(ds)} WHERE status = 'skipped'"))
    assert "hold no message on the config's topics" in rows[str(root / "robot-a" / "cameras")]
    assert rows[str(copy)] == "already replayed with this config"
    (robots,) = query(f"SELECT list(DISTINCT robot ORDER BY robot) FROM {VIOLATIONS.format(ds)}")[0]
    assert robots == ["robot-a"]


def test_a_terminal_gets_a_progress_line_and_a_pipe_does_not(tmp_path):
    import pty

    for i in range(3):
        write_bag(tmp_path / "fleet" / "robot-a" / f"b{i}", messages(i, 300))
    cfg = config(tmp_path)
    leader, follower = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(tmp_path / "fleet"),
         "-o", str(tmp_path / "ds"), "--jobs", "1"],
        stdout=subprocess.PIPE, stderr=follower, text=True,
    )  # fmt: skip
    os.close(follower)
    shown = b""
    while chunk := _read(leader):
        shown += chunk
    out, _ = proc.communicate(timeout=120)
    os.close(leader)
    assert proc.returncode == 0
    last = shown.decode().rstrip("\r\n").split("\r")[-1]  # the pty writes \n as \r\n
    assert "fleet: 3/3 bags, 0 failed, " in last and "messages/s, ETA 0:00:00" in last
    assert len(out.splitlines()) == 1 and "\r" not in out
    # without a terminal (a pipe, as here for stdout and in CI): no progress at all
    run = fleet(cfg, tmp_path / "fleet", "-o", tmp_path / "ds2", ok=(0,))
    assert run.stderr == ""


def _read(fd: int) -> bytes:
    try:
        return os.read(fd, 4096)
    except OSError:  # EIO: the child closed the terminal
        return b""


def test_a_robot_named_by_digits_stays_its_name_in_compare(tmp_path):
    # hive partition values read back as text: "007" is not the number 7
    write_bag(tmp_path / "fleet" / "007" / "b1", messages(1, 300))
    a, b = config(tmp_path, "a.yaml", limit=2.0), config(tmp_path, "b.yaml", limit=2.3)
    run = fleet(a, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", b, ok=(0,))
    robots = {line.split()[1] for line in run.stdout.splitlines()[3:]}
    assert robots == {"007"}, run.stdout


def test_compare_with_a_config_of_the_same_bytes_is_one_line(tmp_path):
    """Its bags were replayed twice under one config hash (the summary counted six
    bags for three rows) and compared with themselves."""
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 50))
    cfg = config(tmp_path)
    copy = tmp_path / "copy.yaml"
    copy.write_bytes(cfg.read_bytes())
    run = fleet(cfg, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", copy, ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "copy.yaml" in lines[0] and "same bytes" in lines[0], run.stderr
    assert not (tmp_path / "ds").exists()  # said before anything is replayed


def test_an_edited_import_replays_the_bags_again(tmp_path):
    """The dataset is keyed by the config with the files it imports: a changed
    ``variables_from`` file under an unchanged config is not "done before"."""
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 200))
    write_bag(tmp_path / "fleet" / "r1" / "b2", messages(2, 200))
    cfg = tmp_path / "c.yaml"
    text = config(tmp_path).read_text()
    speed = "  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}\n"
    assert speed in text
    text = text.replace(speed, "").replace(
        "variables:\n", "variables_from: speed.txt\nvariables:\n"
    )
    cfg.write_text(text)
    imported = tmp_path / "speed.txt"
    imported.write_text('("speed","double","/speed","double")\n')
    ds = tmp_path / "ds"
    first = fleet(cfg, tmp_path / "fleet", "-o", ds)
    assert "2 bags (2 read, 0 skipped, 0 damaged, 0 failed), 0 done before" in first.stdout
    imported.write_text('("speed","float","/speed","double")\n')  # speed judged as float
    again = fleet(cfg, tmp_path / "fleet", "-o", ds)
    assert "2 bags (2 read, 0 skipped, 0 damaged, 0 failed), 0 done before" in again.stdout
    assert query(f"SELECT count(DISTINCT config_sha256), count(*) FROM {BAGS.format(ds)}")[0] == (
        2,
        4,
    )


@pytest.mark.parametrize("other", ["fifo", "/dev/zero"])
def test_compare_with_a_fifo_or_a_device_is_one_line_not_a_hang(tmp_path, other):
    """--compare's same-bytes check read both paths whole: a FIFO hung the run, and
    /dev/zero filled memory to an internal error (exit 3).  The child's address
    space is bounded so that a regression fails here, not the machine."""
    write_bag(tmp_path / "fleet" / "r1" / "b1", messages(1, 50))
    cfg = config(tmp_path)
    if other == "fifo":
        other = str(tmp_path / "fifo")
        os.mkfifo(other)
    args = [cfg, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", other]
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30)),
    )
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode in (1, 2) and len(lines) == 1 and other in lines[0], run.stderr


def test_copies_skipped_before_their_firsts_were_replayed_do_not_lose_that_content(tmp_path):
    # A run stopped after the copies' skipped rows were durable and before their firsts'
    # (the parent writes a copy's row after its first's result, but the two commit on
    # their own): the next run replays the firsts, as their content's violations are
    # in no row yet, never skips them as "already replayed with this config".  The
    # copies' rows are written here as that run left them.
    from supervisor.tools.fleet.archive import content_hash, list_archive
    from supervisor.tools.fleet.dataset import Dataset
    from supervisor.tools.fleet.task import BagTask, copy_of
    from tests.supervisor.tools.fleet.test_engine import _identity

    root = tmp_path / "fleet"
    firsts = [write_bag(root / "robot-a" / f"z{i:02d}", messages(10 + i, 300)) for i in range(3)]
    copies = [root / "robot-b" / f.name for f in firsts]
    for f, c in zip(firsts, copies, strict=True):
        shutil.copytree(f, c)
    cfg, ds = config(tmp_path), tmp_path / "ds"
    refs = {b.path: b for b in list_archive([str(root)])}
    for f, c in zip(firsts, copies, strict=True):
        fp = refs[str(c)].fingerprint
        task = BagTask(str(c), "robot-b", str(cfg), _identity(cfg), None, fp)
        Dataset(ds).write(copy_of(task, str(f), content_hash(c)), "robot-b", fp)
    run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert "3 bags (3 read, 0 skipped, 0 damaged, 0 failed), 3 done before" in run.stdout
    done = dict(query(f"SELECT bag, status FROM {BAGS.format(ds)}"))
    assert {done[str(f)] for f in firsts} == {"read"}, done
    (n,) = query(f"SELECT count(DISTINCT bag) FROM {VIOLATIONS.format(ds)}")[0]
    assert n == len(firsts)


@pytest.mark.parametrize(
    ("first_is", "said", "run", "again"),
    [
        # the copy read; the first, under a new fingerprint, skipped: its content is done
        ("rewritten", "changed during the run", "2 read, 0 skipped, 0 damaged, 1 failed",
         "2 bags (1 read, 1 skipped, 0 damaged, 0 failed), 1 done before"),
        ("removed", "which failed", "1 read, 0 skipped, 0 damaged, 2 failed",
         "1 bags (1 read, 0 skipped, 0 damaged, 0 failed), 1 done before"),
    ],
    ids=["rewritten", "removed"],
)  # fmt: skip
def test_a_copy_whose_first_changed_or_failed_during_the_run_is_failed_and_replayed_next(
    tmp_path, first_is, said, run, again
):
    # A copy is found by its content's hash before any task, and skipped as replayed
    # with its first (by path).  Its first rewritten or removed in between (the worker
    # held stopped in an earlier bag): the copy's content is in no row; the copy is
    # failed, not skipped, and the next run replays it.
    root = tmp_path / "fleet"
    slow = write_bag(root / "robot-a" / "a", messages(99, 40000))  # long enough to stop in
    first = write_bag(root / "robot-a" / "z", messages(1, 300))
    copy = root / "robot-b" / "z"
    shutil.copytree(first, copy)
    cfg, ds = config(tmp_path), tmp_path / "ds"
    proc = started(cfg, root, ds)

    def change() -> None:  # the first's path changed before its task
        shutil.rmtree(first)
        if first_is == "rewritten":
            write_bag(first, messages(2, 300))

    out, err = while_stopped(proc, lambda: _reading_a_bag(proc.pid, slow), change)
    assert proc.returncode == 1 and "Traceback" not in err, err
    assert f"3 bags ({run})" in out, out
    rows = {bag: (status, reason) for bag, status, reason in query(
        f"SELECT bag, status, reason FROM {BAGS.format(ds)}"
    )}  # fmt: skip
    assert rows[str(copy)][0] == "failed" and said in rows[str(copy)][1], rows
    second = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert again in second.stdout, second.stdout
    (robots,) = query(f"SELECT list(DISTINCT robot ORDER BY robot) FROM {VIOLATIONS.format(ds)}")[0]
    assert robots == ["robot-a", "robot-b"]


def test_two_copies_of_a_bag_in_one_run_are_replayed_once(tmp_path):
    # The same content under two robots' paths in one run: the first (by path) is
    # replayed, the other is a skipped row naming it, so no violation is two rows.
    root = tmp_path / "fleet"
    first = write_bag(root / "robot-a" / "b1", messages(1, 500))
    write_bag(root / "robot-a" / "b2", messages(2, 500))
    copy = root / "robot-b" / "b1"
    shutil.copytree(first, copy)  # other inodes and times, the same bytes
    cfg, ds = config(tmp_path), tmp_path / "ds"
    run = fleet(cfg, root, "-o", ds, "--jobs", "2", ok=(0,))
    assert "3 bags (2 read, 1 skipped, 0 damaged, 0 failed), 0 done before" in run.stdout
    rows = {bag: (status, reason) for bag, status, reason in query(
        f"SELECT bag, status, reason FROM {BAGS.format(ds)}"
    )}  # fmt: skip
    assert rows[str(first)] == ("read", "")
    assert rows[str(copy)][0] == "skipped" and str(first) in rows[str(copy)][1]
    (robots,) = query(f"SELECT list(DISTINCT robot ORDER BY robot) FROM {VIOLATIONS.format(ds)}")[0]
    assert robots == ["robot-a"]
    (shas,) = query(
        f"SELECT count(*) FROM {BAGS.format(ds)} GROUP BY config_sha256, bag_sha256, status "
        "ORDER BY 1 DESC LIMIT 1"
    )[0]
    assert shas == 1  # each content read once per config
    again = fleet(cfg, root, "-o", ds, "--jobs", "2", ok=(0,))
    assert "0 bags (0 read, 0 skipped, 0 damaged, 0 failed), 3 done before" in again.stdout


def test_a_cache_that_cannot_be_used_is_said_once_and_a_full_stderr_changes_nothing(tmp_path):
    """Every worker (and the fork server) said the start-up cache's warning, and with
    stderr on a full disk the first worker's failed write ended the run (exit 3)."""
    root = tmp_path / "fleet"
    for i in range(3):
        write_bag(root / "robot-a" / f"b{i}", messages(i, 300))
    cfg = config(tmp_path)
    (tmp_path / "a-file").write_text("")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "a-file" / "cache")}
    env.pop("STATE_DIRECTORY", None)
    argv = [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root)]
    run = subprocess.run(
        [*argv, "-o", str(tmp_path / "ds1"), "--jobs", "2"],
        capture_output=True, text=True, timeout=300, env=env,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    said = [s for s in run.stderr.splitlines() if "start-up cache" in s]
    assert len(said) == 1 and "a-file" in said[0], run.stderr
    with open("/dev/full", "w") as full:
        run = subprocess.run(
            [*argv, "-o", str(tmp_path / "ds2"), "--jobs", "2"],
            stdout=subprocess.PIPE, stderr=full, text=True, timeout=300, env=env,
        )  # fmt: skip
    assert run.returncode == 0, run.stdout
    assert "3 bags (3 read" in run.stdout


def test_a_resumed_run_writes_nothing_through_a_link_planted_in_the_dataset(tmp_path):
    """A dataset handed over with ``violations/robot=R`` linked elsewhere: the resumed
    run wrote the replayed bags' files into the link's target, without a word."""
    for i in range(2):
        write_bag(tmp_path / "fleet" / "robot-a" / f"b{i}", messages(i, 1500))
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    fleet(cfg, tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(0,))
    robot = ds / "violations" / "robot=robot-a"
    assert list(robot.rglob("*.parquet"))  # the bags have violations to write again
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.rmtree(robot)
    robot.symlink_to(elsewhere)
    for row in (ds / "bags").glob("*.parquet"):
        row.unlink()  # as a run interrupted before its rows
    run = fleet(cfg, tmp_path / "fleet", "-o", ds, "--jobs", "2", ok=(1,))
    assert list(elsewhere.rglob("*")) == [], list(elsewhere.rglob("*"))
    said = [s for s in run.stderr.splitlines() if s.strip()]
    assert said == [f"{robot}: a link, not a directory fleet replay writes"], run.stderr
