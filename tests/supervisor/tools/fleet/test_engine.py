"""The engines of ``fleet replay``: the base install never imports Ray; ``--engine ray``
on a real local Ray cluster gives the local pool's dataset row for row, resumes
without reading a finished bag, and survives a Ray worker killed mid-task.

The Ray tests skip only where ``ray`` is not installed (CI installs the ``fleet`` extra
and sets SAFETY_SUPERVISOR_REQUIRE_RAY=1, which fails such a skip: tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.supervisor.tools.fleet.test_fleet_replay import (
    BAGS,
    VIOLATIONS,
    archive,
    fleet,
    four_bags_and_a_clean_run,
    query,
)
from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="ray is not installed (pip install 'safety-supervisor[fleet]')",
)
# Token authentication would keep a token in ~/.ray: these clusters are this test's own
RAY_ENV = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}

NO_RAY = """
import sys
from supervisor.cli import main
try:
    main(["fleet", "replay", "--help"])
except SystemExit:
    pass
code = main(sys.argv[1:])
print("RAY IMPORTED" if sys.modules.get("ray") is not None else "NO RAY", code)
"""


def probed(probe: str, args: list) -> subprocess.CompletedProcess[str]:
    """``fleet replay ARGS`` in a Python running ``probe``, the CLI and what it
    prints about the process at exit (NO_RAY, COMPILED_HERE)."""
    return subprocess.run(
        [sys.executable, "-c", probe, "fleet", "replay", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_cli_and_the_local_engine_never_import_ray(tmp_path):
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    args = [config(tmp_path), tmp_path / "fleet", "-o", tmp_path / "ds", "--jobs", "1"]
    run = probed(NO_RAY, args)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[-1] == "NO RAY 0", run.stdout
    assert "1 bags (1 read," in run.stdout


def test_engine_ray_without_ray_is_one_line_with_the_fix(tmp_path):
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    args = [config(tmp_path), tmp_path / "fleet", "-o", tmp_path / "ds", "--engine", "ray"]
    # ray made unimportable in this process only, whether or not it is installed
    run = probed("import sys; sys.modules['ray'] = None; " + NO_RAY, args)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "pip install 'safety-supervisor[fleet]'" in lines[0], run.stderr
    assert run.stdout.splitlines()[-1] == "NO RAY 1"
    assert not (tmp_path / "ds").exists()  # said before anything was done


def test_address_without_engine_ray_is_one_line(tmp_path):
    run = fleet(config(tmp_path), tmp_path, "-o", tmp_path / "ds", "--address", "x:1", ok=(1,))
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--engine ray" in lines[0], run.stderr


@needs_ray
@pytest.mark.parametrize(
    "address, said",
    [("127.0.0.1:{port}", "cannot reach the Ray cluster"), ("no-port", "is not HOST:PORT")],
)
def test_a_cluster_address_that_is_no_cluster_is_one_line(tmp_path, address, said):
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    address = address.format(port=_free_port())  # nothing listens there
    run = fleet_ray(
        config(tmp_path), tmp_path / "fleet", "-o", tmp_path / "ds", "--address", address, ok=(1,)
    )
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and said in lines[0], run.stderr
    assert not (tmp_path / "ds").exists()  # said before anything was done


@needs_ray
def test_a_local_cluster_that_cannot_start_is_one_line(tmp_path):
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    # a temporary directory too deep for Ray's Unix sockets (108 bytes a path)
    deep = tmp_path / ("t" * 120)
    deep.mkdir()
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(config(tmp_path)),
         str(tmp_path / "fleet"), "-o", str(tmp_path / "ds"), "--engine", "ray", "--jobs", "1"],
        capture_output=True, text=True, timeout=300, env={**RAY_ENV, "TMPDIR": str(deep)},
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1, run.stderr
    assert "cannot start a local Ray cluster" in lines[0] and "internal error" not in lines[0]
    assert not list(deep.iterdir())  # its temporary directory removed


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Head:
    address: str
    temp: Path  # its sessions' logs are here


@pytest.fixture
def ray_cluster(ray_head: Head) -> str:
    return ray_head.address


@pytest.fixture
def ray_head() -> Iterator[Head]:
    """A one-node Ray cluster of 2 CPUs started as ``ray start --head`` would be on a
    real head node.  Stopped by its process group (never ``ray stop``, which stops
    every cluster of this user)."""
    temp = tempfile.mkdtemp(prefix="ss-ray-")  # short: Ray's socket paths sit under it
    ray = Path(sys.executable).with_name("ray")
    proc = subprocess.Popen(
        [str(ray), "start", "--head", "--block", "--num-cpus", "2", "--port", str(_free_port()),
         "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", temp],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=RAY_ENV,
        start_new_session=True,
    )  # fmt: skip
    try:
        address, said = None, []
        assert proc.stdout is not None
        for line in proc.stdout:  # the head prints its address once it has started
            said.append(line)
            if m := re.search(r"ray start --address='([^']+)'", line):
                address = m.group(1)
                break
        assert address, "".join(said)
        yield Head(address, Path(temp))
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
        shutil.rmtree(temp, ignore_errors=True)


def fleet_ray(*args: str | Path, ok: tuple[int, ...] = (0, 1)) -> subprocess.CompletedProcess[str]:
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "replay", *map(str, args), "--engine", "ray"],
        capture_output=True,
        text=True,
        timeout=300,
        env=RAY_ENV,
    )
    assert run.returncode in ok, run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    return run


ROWS = "SELECT * FROM {} ORDER BY ALL"
BAG_ROWS = "SELECT * EXCLUDE (seconds, finished_ts) FROM {} ORDER BY ALL"


@needs_ray
@pytest.mark.slow
def test_a_ray_cluster_gives_the_local_pools_dataset_and_resumes(tmp_path, ray_cluster):
    bags = archive(tmp_path)  # both formats, a compressed bag, a damaged one, a broken one
    cfg = config(tmp_path)
    local, on_ray = tmp_path / "local", tmp_path / "ray"
    fleet(cfg, tmp_path / "fleet", "-o", local, "--jobs", "2")
    run = fleet_ray(cfg, tmp_path / "fleet", "-o", on_ray, "--address", ray_cluster)
    assert "7 bags (5 read, 0 skipped, 1 damaged, 1 failed)" in run.stdout, run.stdout
    want = query(ROWS.format(VIOLATIONS.format(local)))
    assert want and query(ROWS.format(VIOLATIONS.format(on_ray))) == want
    (n, distinct), *_ = query(
        f"SELECT count(*), count(DISTINCT (bag, requirement, tick)) FROM {VIOLATIONS.format(on_ray)}"
    )
    assert n == distinct == len(want)
    assert query(BAG_ROWS.format(BAGS.format(on_ray))) == query(BAG_ROWS.format(BAGS.format(local)))
    # Resume: a finished bag's bytes replaced (same size and times: read again, it would
    # fail) and one bag's row taken away, as an interrupted run leaves it.
    finished = next(bags["robot-a"][0].glob("*.mcap"))
    st = finished.stat()
    finished.write_bytes(os.urandom(st.st_size))
    os.utime(finished, ns=(st.st_atime_ns, st.st_mtime_ns))
    b3 = str(bags["robot-b"][0])
    (row,) = [
        f for f in (on_ray / "bags").glob("*.parquet")
        if query(f"SELECT bag FROM read_parquet('{f}')")[0][0] == b3
    ]  # fmt: skip
    row.unlink()
    run = fleet_ray(cfg, tmp_path / "fleet", "-o", on_ray, "--address", ray_cluster)
    assert "2 bags (1 read, 0 skipped, 0 damaged, 1 failed), 5 done before" in run.stdout
    assert query(ROWS.format(VIOLATIONS.format(on_ray))) == want
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(on_ray)}")[0] == (7, 7)


def _descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(d.name))
        except (OSError, ValueError, IndexError):
            continue  # not a process, or one that has just exited
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


@needs_ray
@pytest.mark.slow
def test_a_ray_worker_killed_mid_task_is_retried_and_the_dataset_is_whole(tmp_path):
    root, cfg, clean, killed = four_bags_and_a_clean_run(tmp_path)
    # the command starts its own local cluster of one CPU: one worker, one task at a time
    proc = _ray_fleet(cfg, root, killed)
    raylets: list[int] = []

    def a_worker_reading_a_bag() -> int | None:
        raylets[:] = [p for p in _descendants(proc.pid) if _named(p, b"raylet")]
        return _ray_worker_reading(proc.pid)

    out, err = _killed_once(proc, "a Ray worker reading a bag", a_worker_reading_a_bag)
    (raylet,) = raylets
    assert proc.returncode == 0 and "Traceback" not in err, err
    # stdout is the one summary line; Ray's word of the death is a plain line on stderr
    (summary,) = out.splitlines()
    assert "4 bags (4 read, 0 skipped, 0 damaged, 0 failed)" in summary
    assert "fleet replay: ray: " in err and "\x1b" not in err, err
    want = query(ROWS.format(VIOLATIONS.format(clean)))
    assert want and query(ROWS.format(VIOLATIONS.format(killed))) == want
    (n, distinct), *_ = query(
        f"SELECT count(*), count(DISTINCT (bag, requirement, tick)) FROM {VIOLATIONS.format(killed)}"
    )
    assert n == distinct == len(want)
    # the cluster the command started is shut down at its end
    with pytest.raises(ProcessLookupError):
        os.kill(raylet, 0)


def _ray_worker_reading(cli: int, bag: str | None = None) -> int | None:
    """A Ray worker of the command's own local cluster (``ray::`` in its process title)
    with a file of ``bag`` open, or of any bag: it is in the middle of a task."""
    for pid in _descendants(cli):
        try:
            if not Path(f"/proc/{pid}/cmdline").read_bytes().startswith(b"ray::"):
                continue
            fds = [os.readlink(f) for f in Path(f"/proc/{pid}/fd").iterdir()]
        except OSError:
            continue
        if any(f.startswith(bag + "/") if bag else f.endswith((".mcap", ".db3")) for f in fds):
            return pid
    return None


def _ray_fleet(cfg: Path, root: Path, out: Path) -> subprocess.Popen[str]:
    """``fleet replay --engine ray`` on a local cluster of one CPU that it starts: one
    worker, the tasks one at a time, in order."""
    return subprocess.Popen(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(out), "--jobs", "1", "--engine", "ray"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=RAY_ENV,
    )  # fmt: skip


def _killed_once(
    proc: subprocess.Popen[str], what: str, find: Callable[[], int | None]
) -> tuple[str, str]:
    """The process ``find`` names (once it does) SIGKILLed, and the command's output
    once it ends."""
    from rosutil import wait_until

    try:
        os.kill(wait_until(what, find, 120), signal.SIGKILL)
        return proc.communicate(timeout=300)
    finally:
        proc.kill()
        proc.wait()


@needs_ray
@pytest.mark.slow
def test_sigterm_stops_a_run_on_ray_as_ctrl_c_does(tmp_path):
    # ray.init makes SIGTERM the driver's sys.exit(15): the command's own handler is
    # put back, so SIGTERM (systemd, a CI job's time limit) stops the run as Ctrl-C
    # does: its local cluster stopped, one line on what the dataset holds, exit 130.
    from rosutil import wait_until

    root = tmp_path / "fleet"
    _twelve_bags(root)
    cfg, ds = config(tmp_path), tmp_path / "ds"
    proc = _ray_fleet(cfg, root, ds)
    try:
        wait_until("a Ray worker reading a bag", lambda: _ray_worker_reading(proc.pid), 120)
        cluster = _descendants(proc.pid)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130 and "Traceback" not in err, err
    written = len(list((ds / "bags").glob("*.parquet")))
    assert err.splitlines()[-1] == (
        f"fleet replay: interrupted: {written} of 12 bags done, 0 done before; "
        f"their rows in {ds}: the same command replays the rest"
    ), err
    assert out == "", out  # no summary: the run did not end
    wait_until(
        "the local cluster's processes gone",
        lambda: not any(Path(f"/proc/{p}").exists() and not _zombie(p) for p in cluster),
        60,
    )
    run = fleet_ray(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert f"{12 - written} bags (" in run.stdout and f"{written} done before" in run.stdout
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (12, 12)


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True  # gone


def _twelve_bags(root: Path) -> list[Path]:
    """b00..b11 of one robot, 40,000 messages each: in a window of 4 Ray tasks on one
    CPU, the first task is b00-b02."""
    bags = [root / "robot-a" / f"b{i:02d}" for i in range(12)]
    for i, bag in enumerate(bags):
        write_bag(bag, messages(10 + i, 40000))
    return bags


@needs_ray
@pytest.mark.slow
def test_a_ray_worker_killed_in_the_middle_of_a_task_of_several_bags_reruns_them_once(tmp_path):
    """A Ray task runs several bags (engine.RAY_BATCH): killed after its first bag, the
    task is retried whole, and each of its bags is written once, none lost."""

    root = tmp_path / "fleet"
    bags = _twelve_bags(root)
    cfg = config(tmp_path)
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    # one CPU: the tasks run one at a time, in order; 12 bags in a window of 4 tasks
    # make the first task b00-b02, so a worker reading b01 has finished b00 in it
    proc = _ray_fleet(cfg, root, killed)
    out, err = _killed_once(
        proc, "a Ray worker reading b01", lambda: _ray_worker_reading(proc.pid, str(bags[1]))
    )
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert "12 bags (12 read, 0 skipped, 0 damaged, 0 failed)" in out, out
    want = query(ROWS.format(VIOLATIONS.format(clean)))
    assert want and query(ROWS.format(VIOLATIONS.format(killed))) == want
    assert query(BAG_ROWS.format(BAGS.format(killed))) == query(BAG_ROWS.format(BAGS.format(clean)))


@needs_ray
@pytest.mark.slow
def test_a_bag_that_kills_its_ray_worker_each_time_fails_alone_not_its_task(tmp_path):
    """A bag whose worker dies on every attempt, in a Ray task of several bags: the
    task fails whole after Ray's retries, then each of its bags goes alone, so only
    that bag is failed and its neighbours are read."""
    import threading

    from supervisor.tools.fleet.engine import ATTEMPTS

    root = tmp_path / "fleet"
    bags = _twelve_bags(root)
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    # one CPU: 12 bags in a window of 4 tasks make the first task b00-b02
    proc = _ray_fleet(cfg, root, ds)
    kills = []

    def killer() -> None:  # every worker that opens b01 is killed, until the run ends
        while proc.poll() is None:
            victim = _ray_worker_reading(proc.pid, str(bags[1]))
            if victim:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(victim, signal.SIGKILL)
                    kills.append(victim)
            time.sleep(0.005)  # polling interval, not synchronisation

    thread = threading.Thread(target=killer)
    thread.start()
    try:
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
        proc.wait()
        thread.join()
    assert proc.returncode == 1 and "Traceback" not in err, err
    assert "12 bags (11 read, 0 skipped, 0 damaged, 1 failed)" in out, (out, kills)
    assert query(f"SELECT bag, reason FROM {BAGS.format(ds)} WHERE status <> 'read'") == [
        (str(bags[1]), f"its worker process died {ATTEMPTS} times")
    ]


def _named(pid: int, name: bytes) -> bool:
    try:
        argv0 = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
    except OSError:
        return False
    return argv0.endswith(b"/" + name)


COMPILED_HERE = """
import sys
from supervisor.cli import main
try:
    code = main(sys.argv[1:])
finally:
    # the modules that compile a config and load its monitor: the workers' alone
    here = [m for m in ("supervisor.tools.replay.session", "monitors.backends.load")
            if m in sys.modules]
    print("COMPILED HERE" if here else "COMPILED BY THE WORKERS", here)
"""


def test_the_parent_leaves_the_configs_compile_to_the_pools_workers(tmp_path):
    """The parent compiled each config as the workers did, 0.5 s of its CPU per run,
    a serial part of every run (docs/BENCHMARKS.md, "Fleet"): the pool's workers
    compile it as they start, the parent waits for the first one's verdict, and a bad
    config is still one line with its place, before any bag is replayed."""
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    cfg = config(tmp_path)
    other = config(tmp_path, "other.yaml", limit=2.5)
    args = [cfg, tmp_path / "fleet", "-o", tmp_path / "ds", "--jobs", "2", "--compare", other]
    run = probed(COMPILED_HERE, args)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[-1] == "COMPILED BY THE WORKERS []", run.stdout
    assert "2 bags (2 read," in run.stdout
    # a bad requirement in the compared config: its file and line, nothing written
    other.write_text(other.read_text().replace("speed <= 2.5", "speed <=> 2.5"))
    bad = fleet(cfg, tmp_path / "fleet", "-o", tmp_path / "ds2", "--compare", other, ok=(1,))
    lines = [line for line in bad.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{other}:"), bad.stderr
    assert not (tmp_path / "ds2").exists()


@needs_ray
@pytest.mark.slow
@needs_ray
@pytest.mark.slow
def test_a_run_on_a_running_cluster_starts_no_more_workers_than_it_has_cpus(tmp_path, ray_head):
    """A warm-up task per CPU, submitted at once to a raylet with no idle worker for the
    job, started a third worker for every job after the cluster's first: it sat idle and
    was stopped 1.5 s later, 0.6 s of CPU on a 2-CPU machine (docs/BENCHMARKS.md,
    "Fleet").  The first job is not asked about: it takes the workers Ray starts for
    the cluster's first driver."""
    for i in range(4):
        write_bag(tmp_path / "fleet" / "robot-a" / f"b{i}", messages(i, 300))
    cfg = config(tmp_path)
    for run in range(3):
        fleet_ray(cfg, tmp_path / "fleet", "-o", tmp_path / f"ds{run}", "--address",
                  ray_head.address)  # fmt: skip
    logs = ray_head.temp / "session_latest" / "logs"
    workers: dict[str, set[str]] = {}
    for f in logs.glob("worker-*.out"):
        _, _, job, pid = f.stem.split("-")
        workers.setdefault(job, set()).add(pid)
    assert {workers.get(job, set()).__len__() for job in ("02000000", "03000000")} == {2}, workers


def test_on_a_ray_cluster_the_parent_leaves_the_configs_compile_to_its_workers(
    tmp_path, ray_cluster
):
    """As with the pool: the parent compiled each config before joining the cluster, a
    serial part of every run (docs/BENCHMARKS.md, "Fleet"); the cluster's workers now
    compile it as they start, and a bad config is still one line with its place."""
    write_bag(tmp_path / "fleet" / "robot-a" / "b1", messages(1, 300))
    cfg = config(tmp_path)
    other = config(tmp_path, "other.yaml", limit=2.5)
    args = [cfg, tmp_path / "fleet", "-o", tmp_path / "ds", "--compare", other, "--engine",
            "ray", "--address", ray_cluster]  # fmt: skip
    run = subprocess.run(
        [sys.executable, "-c", COMPILED_HERE, "fleet", "replay", *map(str, args)],
        capture_output=True, text=True, timeout=300, env=RAY_ENV,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[-1] == "COMPILED BY THE WORKERS []", run.stdout
    assert "2 bags (2 read," in run.stdout
    other.write_text(other.read_text().replace("speed <= 2.5", "speed <=> 2.5"))
    bad = fleet_ray(
        cfg, tmp_path / "fleet", "-o", tmp_path / "ds2", "--compare", other, "--address",
        ray_cluster, ok=(1,),
    )  # fmt: skip
    lines = [line for line in bad.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{other}:"), bad.stderr
    assert not (tmp_path / "ds2").exists()


def test_the_local_pools_workers_start_before_the_tasks_and_run_them(tmp_path):
    """``start`` starts the workers (their imports overlap the parent's compile and
    listing); ``results`` runs the tasks on those same workers, no second pool, and
    ``close`` stops workers that no run took."""
    import multiprocessing

    from supervisor.tools.fleet.engine import LocalEngine
    from supervisor.tools.fleet.task import BagTask

    cfg = config(tmp_path)
    bags = [write_bag(tmp_path / f"b{i}", messages(i, 300)) for i in range(4)]
    engine = LocalEngine(2)
    engine.start(frozenset())
    warm = {f.result(timeout=120)[0] for f in engine.warm}  # each a worker's pid
    # forked by one fork server, which imported the tasks' modules once for both
    (server,) = {
        int(Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[1]) for p in warm
    }
    assert server != os.getpid()
    seen: set[int] = set()
    tasks = [BagTask(str(b), "r", str(cfg), _identity(cfg)) for b in bags]
    for result in engine.results(tasks, frozenset()):
        assert result.status == "read", result.reason
        seen |= {p.pid for p in multiprocessing.active_children()}
    assert warm <= seen and len(seen) == 2  # the started workers, no other
    idle = LocalEngine(4)
    idle.start(frozenset(), 2)  # no more workers than tasks to come
    assert len(idle.warm) == 2
    started = {f.result(timeout=120)[0] for f in idle.warm}
    idle.close()
    assert not started & {p.pid for p in multiprocessing.active_children()}
    assert not Path(f"/proc/{server}").exists()  # the server stopped too: nothing outlives a run
    idle.start(frozenset(), 0)  # nothing to run: nothing started
    assert not idle.warm and not multiprocessing.active_children()


def _identity(cfg: Path) -> str:
    """The config's identity as the run takes it (it imports nothing: its bytes'
    SHA-256), which a task must carry to be replayed (task.py, ``CHANGED``)."""
    return hashlib.sha256(cfg.read_bytes()).hexdigest()


class _Taken(list):  # type: ignore[type-arg]
    """A task list that counts the tasks an engine has taken from it."""

    taken = 0

    def __iter__(self):  # type: ignore[no-untyped-def]
        for t in super().__iter__():
            self.taken += 1
            yield t


def test_the_local_pool_keeps_a_window_of_tasks_in_flight_not_the_archive(tmp_path):
    """Every task submitted at once made each wait() look at every pending future,
    a parent cost growing with the square of the bags; a few per worker are in
    flight, and every task still gives one result."""
    from supervisor.tools.fleet.engine import WINDOW_PER_JOB, LocalEngine
    from supervisor.tools.fleet.task import BagTask

    cfg = config(tmp_path)
    bag = write_bag(tmp_path / "b", messages(1, 200))
    # one bag under many paths: each path is a task of its own
    tasks = _Taken(BagTask(str(bag), "r", str(cfg), _identity(cfg)) for _ in range(30))
    paths = []
    for i, result in enumerate(LocalEngine(1).results(tasks, frozenset())):
        assert result.status == "read", result.reason
        assert tasks.taken <= WINDOW_PER_JOB + i + 1  # one more taken as each ends
        paths.append(result.task.bag)
    assert len(paths) == 30 and tasks.taken == 30


MKDIRS = {83, 258}  # x86_64: mkdir, mkdirat


def _held_in_mkdir(root: int) -> int | None:
    """A thread below ``root`` held by strace at the entry of a mkdir: with ``-P``,
    only that of the dataset's bags directory, made for the first bag's row.  Every
    other mkdir stops at strace too, for as long as strace takes to let it go (under
    load, long enough to be seen): a thread is held only if it is still there half a
    second later."""
    seen = [t for t in _threads() if _in_mkdir(t)]
    if not seen:
        return None
    time.sleep(0.5)
    for task in seen:
        if _in_mkdir(task) and _below(int(task.parent.parent.name), root):
            return int(task.name)
    return None


def _threads() -> list[Path]:
    """Every thread on the machine (/proc/PID/task/TID).  A process may exit between
    the listing of /proc and that of its threads (pathlib's glob does not allow for it:
    CI once failed on a vanished /proc/PID/task)."""
    out = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            out.extend((d / "task").iterdir())
        except OSError:
            continue  # exited meanwhile
    return out


def _in_mkdir(task: Path) -> bool:
    """The thread ``task`` (/proc/PID/task/TID) stopped by its tracer in a mkdir."""
    try:
        stat = (task / "stat").read_text().rsplit(")", 1)[1].split()
        number = (task / "syscall").read_text().split()[0]
    except (OSError, IndexError):
        return False  # exited meanwhile
    return stat[0] == "t" and number.isdigit() and int(number) in MKDIRS


def _below(pid: int, root: int) -> bool:
    while pid > 1:
        if pid == root:
            return True
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            return False
    return False


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_a_worker_killed_between_a_bags_violations_and_its_row_leaves_it_to_the_rerun(
    tmp_path,
):
    # The pool's worker writes its bag's files (engine.py): strace holds it as it
    # makes the bags directory for the bag's row (a fresh dataset's first), its
    # violations already durable, and the worker is killed there (SIGKILL), the run
    # with it.  (strace's -P matches a rename by its first path, a random name.)
    from rosutil import wait_until

    from supervisor.tools.fleet.archive import list_archive
    from supervisor.tools.fleet.dataset import Dataset

    root = tmp_path / "fleet"
    write_bag(root / "robot-a" / "b1", messages(21, 20000))
    cfg = config(tmp_path)
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    (bag,) = list_archive([str(root)], None)
    key = Dataset.key(_identity(cfg), bag.fingerprint)
    row = killed / "bags" / f"{key}.parquet"
    hold = "mkdir,mkdirat"
    proc = subprocess.Popen(
        ["strace", "-f", "-qq", "-o", "/dev/null", "-P", str(row.parent), "-e", f"trace={hold}",
         "-e", f"inject={hold}:delay_enter=300000000",
         sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(killed), "--jobs", "1", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
    )  # fmt: skip
    try:
        held = wait_until(
            "a thread held before the bag's row", lambda: _held_in_mkdir(proc.pid), 120
        )
        server = int(Path(f"/proc/{held}/stat").read_text().rsplit(")", 1)[1].split()[1])
        assert b"forkserver" in Path(f"/proc/{server}/cmdline").read_bytes(), (
            "the row is committed by a pool worker, not by the command"
        )
        assert list(killed.glob(f"violations/robot=robot-a/date=*/{key}.parquet"))
        assert not row.exists()
        os.kill(held, signal.SIGKILL)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert not row.exists()
    run = fleet(cfg, root, "-o", killed, "--jobs", "1", ok=(0,))
    assert "1 bags (1 read, 0 skipped, 0 damaged, 0 failed), 0 done before" in run.stdout
    per_bag = "SELECT requirement, count(*), count(DISTINCT tick) FROM {} GROUP BY ALL ORDER BY ALL"
    want = query(per_bag.format(VIOLATIONS.format(clean)))
    assert want and query(per_bag.format(VIOLATIONS.format(killed))) == want
    assert all(n == distinct for _, n, distinct in want)
    assert query(f"SELECT status, count(*) FROM {BAGS.format(killed)} GROUP BY ALL") == [
        ("read", 1)
    ]


# Calls of several bags (engine.py, ``LocalEngine``): --jobs 1 makes a call of 8 bags
# once 32 are left to send, so 40 tiny bags run in calls of 8, then shorter ones.
CALLS_OF_8 = 40


# the 4th bag of the second call (b08 to b15)
LATE = 11


def _tiny_fleet(root: Path) -> list[Path]:
    """``CALLS_OF_8`` tiny bags b00.. of one robot, in the order the engine sends them;
    b11 (``LATE``) alone recorded a day later, so that its violations alone make
    their partition's directory (``date=1970-01-02``)."""
    day = 86_400 * 10**9
    return [
        write_bag(
            root / "robot-a" / f"b{i:02d}",
            [(t + day, topic, v) for t, topic, v in messages(100 + i, 1500)]
            if i == LATE
            else messages(100 + i, 120),
        )
        for i in range(CALLS_OF_8)
    ]


def _stopped(root: int, other_than: int = 0) -> int | None:
    """A process below ``root`` stopped whole by strace's injected SIGSTOP (every
    thread stopped, one at a mkdir) and still so a moment later: each thread also
    passes through a tracing stop at every syscall strace sees, and on a loaded
    machine all of them were once caught in one at an earlier mkdir (CI)."""
    first = _stopped_now(root, other_than)
    if first is None:
        return None
    time.sleep(0.5)
    return first if _stopped_now(root, other_than) == first else None


def _stopped_now(root: int, other_than: int) -> int | None:
    for d in Path("/proc").glob("[0-9]*"):
        pid = int(d.name)
        if pid == other_than or not _below(pid, root):
            continue
        try:
            threads = list((d / "task").iterdir())
            states = [(t / "stat").read_text().rsplit(")", 1)[1].split()[0] for t in threads]
            calls = [(t / "syscall").read_text().split()[0] for t in threads]
        except (OSError, IndexError):
            continue  # exited meanwhile
        if all(s == "t" for s in states) and any(c.isdigit() and int(c) in MKDIRS for c in calls):
            return pid
    return None


def _rows(ds: Path, cfg: Path, root: Path) -> dict[str, Path]:
    """Each bag's row file in ``ds`` (bag name -> path), whether written or not."""
    from supervisor.tools.fleet.archive import list_archive
    from supervisor.tools.fleet.dataset import Dataset

    sha = _identity(cfg)
    return {
        Path(b.path).name: ds / "bags" / f"{Dataset.key(sha, b.fingerprint)}.parquet"
        for b in list_archive([str(root)], None)
    }


def _finished(row: Path) -> object:
    return query(f"SELECT finished_ts FROM read_parquet('{row}')")[0][0]


def _strace(*args: str) -> list[str]:
    return ["strace", "-f", "-qq", "-o", "/dev/null", *args]


PER_BAG = (
    "SELECT bag, requirement, count(*), count(DISTINCT tick) FROM {} GROUP BY ALL ORDER BY ALL"
)


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_a_worker_killed_mid_call_keeps_the_bags_it_committed_and_retries_the_rest(tmp_path):
    # strace stops (SIGSTOP) the worker as its writer thread makes the directory of
    # b11's violations, the 4th bag of the second call: the first call's bags (b00 to
    # b07) are committed, their group synced at the call's end; b08 to b10 have their
    # violations written and wait for their group's sync for their rows
    # (dataset.Commits), b11 to b15 have none; the worker is SIGKILLed there.  The
    # retry's worker is stopped there too (strace counts per process), and let go
    # (SIGCONT).  The committed bags count once, as read, and are not written again;
    # the rest of the call is retried.
    from rosutil import wait_until

    root = tmp_path / "fleet"
    _tiny_fleet(root)
    cfg = config(tmp_path)
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    fleet(cfg, root, "-o", clean, "--jobs", "1", ok=(0,))
    rows = _rows(killed, cfg, root)
    late_violations = killed / "violations" / "robot=robot-a" / "date=1970-01-02"
    proc = subprocess.Popen(
        _strace("-P", str(late_violations), "-e", "trace=mkdir,mkdirat",
                "-e", "inject=mkdir,mkdirat:signal=STOP:when=1",
                sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root),
                "-o", str(killed), "--jobs", "1", "--quiet"),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        committed = [f"b{i:02d}" for i in range(8)]
        worker = wait_until(f"the worker stopped at b{LATE}", lambda: _stopped(proc.pid), 120)
        assert all(rows[b].exists() for b in committed)
        before = {b: _finished(rows[b]) for b in committed}
        assert not any(rows[f"b{i:02d}"].exists() for i in range(8, CALLS_OF_8))
        os.kill(worker, signal.SIGKILL)
        retry = wait_until(f"the retry at b{LATE}", lambda: _stopped(proc.pid, worker), 120)
        os.kill(retry, signal.SIGCONT)
        out, err = proc.communicate(timeout=300)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert "Traceback" not in err, err
    assert f"{CALLS_OF_8} bags ({CALLS_OF_8} read, 0 skipped, 0 damaged, 0 failed)" in out, out
    assert {b: _finished(rows[b]) for b in committed} == before  # not written again
    want = query(PER_BAG.format(VIOLATIONS.format(clean)))
    assert any(bag.endswith(f"b{LATE}") for bag, *_ in want)
    assert query(PER_BAG.format(VIOLATIONS.format(killed))) == want
    assert all(n == distinct for _, _, n, distinct in want)
    assert query(
        f"SELECT status, count(*), count(DISTINCT bag) FROM {BAGS.format(killed)} GROUP BY ALL"
    ) == [("read", CALLS_OF_8, CALLS_OF_8)]


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_a_bag_that_kills_its_worker_each_time_fails_alone(tmp_path):
    # strace SIGKILLs whichever process opens b03's file: its worker dies on every
    # attempt.  b03 ends failed after ATTEMPTS deaths; every other bag, of its call or
    # of the calls in flight beside it, ends read.
    from supervisor.tools.fleet.engine import ATTEMPTS

    root = tmp_path / "fleet"
    bags = _tiny_fleet(root)
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    (poison,) = bags[3].glob("*.mcap")
    run = subprocess.run(
        _strace("-P", str(poison), "-e", "trace=openat", "-e", "inject=openat:signal=KILL",
                sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root),
                "-o", str(ds), "--jobs", "1", "--quiet"),
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 1 and "Traceback" not in run.stderr, run.stderr
    n = CALLS_OF_8
    assert f"{n} bags ({n - 1} read, 0 skipped, 0 damaged, 1 failed)" in run.stdout, run.stdout
    assert query(f"SELECT bag, reason FROM {BAGS.format(ds)} WHERE status <> 'read'") == [
        (str(bags[3]), f"its worker process died {ATTEMPTS} times")
    ]
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (n, n)


TWO_POISONS = """
import argparse, sys
from pathlib import Path
from supervisor.tools.fleet import server
from supervisor.tools.fleet.command import _replay
from supervisor.tools.fleet.dataset import Dataset
from supervisor.tools.fleet.engine import LocalEngine
cfg, root, ds = sys.argv[1:4]
args = argparse.Namespace(config=cfg, compare=None, archives=[root], robot_from=None,
                          output=ds, quiet=True)
# one bag a call and one call per worker: a bag retried on its last attempt runs beside
# a fresh bag, which may be the next one that kills its worker
engine = LocalEngine(2, Path(ds), batch=1, window=1)
try:
    sys.exit(_replay(args, engine, None, Dataset(Path(ds), make=False).done(), set(), sys.stdout))
finally:
    engine.close()
    server.stop()
"""


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_two_bags_that_kill_their_workers_fail_and_no_bag_beside_them(tmp_path):
    # strace SIGKILLs whichever process opens b00's or b04's file.  Each death takes
    # down the bag beside it too; a bag on its last attempt is failed only when its
    # call was the only one in flight, so the healthy bags all end read.
    from supervisor.tools.fleet.engine import ATTEMPTS

    root = tmp_path / "fleet"
    bags = _tiny_fleet(root)
    for extra in bags[12:]:
        shutil.rmtree(extra)
    bags = bags[:12]
    cfg = config(tmp_path)
    ds = tmp_path / "ds"
    poisons = [next(bags[i].glob("*.mcap")) for i in (0, 4)]
    run = subprocess.run(
        _strace("-P", str(poisons[0]), "-P", str(poisons[1]), "-e", "trace=openat",
                "-e", "inject=openat:signal=KILL",
                sys.executable, "-c", TWO_POISONS, str(cfg), str(root), str(ds)),
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 1 and "Traceback" not in run.stderr, run.stderr
    assert "12 bags (10 read, 0 skipped, 0 damaged, 2 failed)" in run.stdout, run.stdout
    # ORDER BY: the two bags fail in whichever order their last attempts end.
    failed = f"SELECT bag, reason FROM {BAGS.format(ds)} WHERE status <> 'read' ORDER BY bag"
    assert query(failed) == [
        (str(bags[0]), f"its worker process died {ATTEMPTS} times"),
        (str(bags[4]), f"its worker process died {ATTEMPTS} times"),
    ]


def test_the_local_pool_with_the_parent_writing_gives_the_workers_dataset(tmp_path):
    """``LocalEngine(writes_to=None)``: results come back with their tables and the
    parent writes them (``Writers``, as for Ray); the same rows as the workers write."""
    import argparse

    from supervisor.tools.fleet import server
    from supervisor.tools.fleet.command import _replay
    from supervisor.tools.fleet.dataset import Dataset
    from supervisor.tools.fleet.engine import LocalEngine

    archive(tmp_path)  # both formats, a compressed bag, a damaged one, a broken one
    cfg = config(tmp_path)
    by_workers, by_parent = tmp_path / "workers", tmp_path / "parent"
    fleet(cfg, tmp_path / "fleet", "-o", by_workers, "--jobs", "2")
    args = argparse.Namespace(
        config=str(cfg), compare=None, archives=[str(tmp_path / "fleet")], robot_from=None,
        output=str(by_parent), quiet=True,
    )  # fmt: skip
    engine = LocalEngine(2, writes_to=None)
    try:
        code = _replay(args, engine, None, Dataset(by_parent, make=False).done(), set(), sys.stdout)
    finally:
        engine.close()
        server.stop()
    assert code == 1  # the damaged and the broken bag, as the workers' run says
    want = query(ROWS.format(VIOLATIONS.format(by_workers)))
    assert want and query(ROWS.format(VIOLATIONS.format(by_parent))) == want
    want_bags = query(BAG_ROWS.format(BAGS.format(by_workers)))
    assert len(want_bags) == 7 and query(BAG_ROWS.format(BAGS.format(by_parent))) == want_bags


def _group(pgid: int) -> list[int]:
    """The live processes of process group ``pgid``."""
    out = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if stat[0] != "Z" and int(stat[2]) == pgid:
            out.append(int(d.name))
    return out


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_or_sigterm_twice_stops_the_workers_at_once_and_leaves_no_process(tmp_path, sig):
    # Ctrl-C (SIGINT to the command) mid-run, or SIGTERM (systemd, a CI job's time
    # limit, timeout(1)): the pool's workers are stopped at once, not left to finish
    # the calls they hold (8 bags each); a second signal during the shutdown leaves no
    # worker and no fork server behind; one line says what was done and that the same
    # command resumes; a rerun finishes the rest, each bag once.
    from rosutil import wait_until

    from tests.supervisor.tools.fleet.test_fleet_replay import _workers

    root = tmp_path / "fleet"
    first = write_bag(root / "robot-a" / "b00", messages(7, 20000))
    for i in range(1, CALLS_OF_8):  # copies, each a content of its own: a task each
        shutil.copytree(first, root / "robot-a" / f"b{i:02d}")
        # (an exact copy is skipped as one, archive.py's ``copies``)
        (root / "robot-a" / f"b{i:02d}" / "copy.txt").write_text(f"{i}\n")
    cfg, ds = config(tmp_path), tmp_path / "ds"
    proc = subprocess.Popen(
        [sys.executable, "-m", "supervisor", "fleet", "replay", str(cfg), str(root), "-o",
         str(ds), "--jobs", "1", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    rows = ds / "bags"
    try:
        workers = wait_until(
            "the first bag committed",
            lambda: rows.is_dir() and any(rows.glob("*.parquet")) and _workers(proc.pid),
            120,
        )
        at_stop = len(list(rows.glob("*.parquet")))
        os.kill(proc.pid, sig)
        wait_until(
            "the workers stopped",
            lambda: not any(Path(f"/proc/{w}").exists() for w in workers),
            60,
        )
        if proc.poll() is None:
            os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
        wait_until("no process of the command's left", lambda: not _group(proc.pid), 30)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert proc.returncode == 130 and "Traceback" not in err, err
    # at most the bag whose row was being written as the signal came
    written = len(list(rows.glob("*.parquet")))
    assert written <= at_stop + 1
    # one line, what the dataset holds, and nothing else (not multiprocessing's
    # "leaked semaphore" of a process killed)
    assert err.splitlines() == [
        f"fleet replay: interrupted: {written} of {CALLS_OF_8} bags done, 0 done before; "
        f"their rows in {ds}: the same command replays the rest"
    ], err
    run = fleet(cfg, root, "-o", ds, "--jobs", "1", ok=(0,))
    assert f"{CALLS_OF_8} bags" not in run.stdout and "0 failed" in run.stdout, run.stdout
    assert query(f"SELECT count(*), count(DISTINCT bag) FROM {BAGS.format(ds)}")[0] == (
        CALLS_OF_8,
        CALLS_OF_8,
    )
