"""The fleet bench (supervisor/tools/bench/fleet.py) on a small archive, as a user runs
it: every kind of bag made, every run's figures present, and the resume after a kill
reading none of the bags finished before it.  Speed is printed by the bench, never
asserted here."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("pyarrow")


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


@pytest.mark.slow
def test_a_small_fleet_bench_measures_each_run_and_resumes_without_reading_again(tmp_path):
    out = tmp_path / "fleet.json"
    run = subprocess.run(
        [sys.executable, "-m", "supervisor.tools.bench.fleet", "--bags", "50", "--robots", "5",
         "--messages", "3000", "--split-messages", "20000", "--skip-ray", "--rounds", "2",
         "--tmp", str(tmp_path), "--json", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    got = json.loads(out.read_text())
    assert got["kinds"] == {
        "mcap": 25, "sqlite3": 25, "violating": 10, "compressed": 3, "damaged": 1,
    }  # fmt: skip
    # the second round backwards: each ratio is of neighbours, taken both ways round
    assert [(r["round"], r["args"]) for r in got["runs"]] == [
        (1, "--jobs 1"), (1, "--jobs 2"), (2, "--jobs 2"), (2, "--jobs 1"),
    ]  # fmt: skip
    assert "over 2 rounds, speed-up from --jobs 1 to 2: median " in run.stdout, run.stdout
    for r in got["runs"]:
        assert r["exit"] == 1  # the damaged bag
        assert "50 bags (49 read, 0 skipped, 1 damaged, 0 failed)" in r["summary"]
        assert r["workers"] == int(r["args"].split()[-1])
        assert all(_positive(r[k]) for k in ("wall_s", "rate", "cpu_s", "peak_worker_mb"))
    resume = got["resume"]
    assert resume["killed"]["killed"] and 0 < resume["finished_at_kill"] < 50
    assert 1 <= resume["kills"] <= 3  # a kill after the last bag is tried again, sooner
    assert resume["read_again"] == 0 and resume["all_finished"] == 50
    assert f"{resume['finished_at_kill']} done before" in resume["resumed"]["summary"]
    for part in ("split", "split_mcap", "split_sqlite3"):
        assert all(_positive(v) for v in got[part]["ns_per_message"].values()), got[part]
    assert "goal >= 1.8x" in run.stdout and "goal <= 300 MB" in run.stdout
    assert not list(tmp_path.glob("fleet-bench-*"))  # its archive removed at the end


needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="ray is not installed (pip install 'safety-supervisor[fleet]')",
)
BENCH = [sys.executable, "-m", "supervisor.tools.bench.fleet", "--bags", "12", "--robots", "2",
         "--messages", "1000", "--split-messages", "2000"]  # fmt: skip


def _stat(pid: int | str) -> list[str]:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def _session(sid: int) -> list[int]:
    """The processes of session ``sid`` still running (a zombie has stopped)."""
    out = []
    for d in Path("/proc").iterdir():
        try:
            fields = _stat(d.name)
        except (OSError, IndexError):
            continue  # not a process, or one that has just exited
        if int(fields[3]) == sid and fields[0] != "Z":
            out.append(int(d.name))
    return out


def _bench(*args: str) -> subprocess.Popen[str]:
    """The bench in a session of its own: what it starts and leaves running is found
    there (its cluster's head starts a session of its own, named in its JSON)."""
    return subprocess.Popen(
        [*BENCH, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )  # fmt: skip


@needs_ray
@pytest.mark.slow
def test_the_bench_times_ray_on_a_running_cluster_apart_from_its_start_and_stop(tmp_path):
    out = tmp_path / "fleet.json"
    bench = _bench("--tmp", str(tmp_path), "--json", str(out))
    stdout, stderr = bench.communicate(timeout=600)
    assert bench.returncode == 0 and "Traceback" not in stderr, stderr
    got = json.loads(out.read_text())
    joins = "--jobs 2 --engine ray --address (a running cluster)"
    # the run on the running cluster beside --jobs 2, which it is judged against
    assert [r["args"] for r in got["runs"]] == [
        "--jobs 1", "--jobs 2", joins, "--jobs 2 --engine ray",
    ]  # fmt: skip
    for r in got["runs"]:
        assert "12 bags (12 read, 0 skipped, 0 damaged, 0 failed)" in r["summary"], r
        assert all(_positive(r[k]) for k in ("wall_s", "rate", "cpu_s", "peak_worker_mb")), r
    # the cluster's task workers, not its agents
    assert [r["workers"] for r in got["runs"] if r["args"] == joins] == [2]
    cluster = got["cluster"]
    assert _positive(cluster["start_s"]) and _positive(cluster["stop_s"])
    assert cluster["left"] == 0  # every process of the cluster stopped with its head
    assert f"started in {cluster['start_s']:.1f} s, stopped in" in stdout
    assert "Ray against the pool, on the running cluster:" in stdout
    # nothing outlives the bench: neither its cluster nor its runs
    assert not _session(cluster["pid"]) and not _session(bench.pid)
    assert not list(tmp_path.glob("fleet-bench-*"))


def _joining(bench: int) -> int | None:
    """The running cluster's head (``ray start --head``, a child of the bench) once a
    ``fleet replay --address`` run is on it."""
    heads, joins = [], False
    for d in Path("/proc").iterdir():
        try:
            fields, cmd = _stat(d.name), (d / "cmdline").read_bytes().split(b"\0")
        except (OSError, IndexError):
            continue
        if int(fields[1]) != bench:
            continue
        joins |= b"--address" in cmd and b"replay" in cmd
        if b"--head" in cmd:
            heads.append(int(d.name))
    return heads[0] if joins and heads else None


@needs_ray
@pytest.mark.slow
def test_a_bench_interrupted_during_the_run_on_its_cluster_leaves_no_process(tmp_path):
    from rosutil import wait_until

    bench = _bench("--tmp", str(tmp_path), "--messages", "40000")
    try:
        head = wait_until("the run on the bench's cluster", lambda: _joining(bench.pid), 300)
        os.kill(bench.pid, signal.SIGINT)  # Ctrl-C: the bench alone (its runs have sessions)
        _, stderr = bench.communicate(timeout=120)
    finally:
        bench.kill()
        bench.wait()
    assert bench.returncode == 130 and "Traceback" not in stderr, stderr
    assert "fleet: interrupted" in stderr
    assert not _session(head) and not _session(bench.pid)
    assert not list(tmp_path.glob("fleet-bench-*"))


def _fork_and_sleep() -> int:
    """A task that starts a child, as a worker starts ``cc --version``: between its fork
    and its exec the child has the worker's command line."""
    import time

    pid = os.fork()
    if pid == 0:
        time.sleep(60)
        os._exit(0)
    return pid


def test_a_workers_own_child_is_not_counted_as_a_worker():
    from concurrent.futures import ProcessPoolExecutor

    from supervisor.tools.bench.fleet import _workers
    from supervisor.tools.fleet import server

    # the pool's own fork server, stopped after: a later test of this process would
    # get it, with none of its preload (test_warm.py)
    try:
        with ProcessPoolExecutor(1, mp_context=server.serve()) as pool:
            grandchild = pool.submit(_fork_and_sleep).result()
            try:
                found = _workers(os.getpid())
                assert grandchild not in found
                assert len(found) == 1, found
            finally:
                os.kill(grandchild, signal.SIGKILL)
    finally:
        server.stop()


@pytest.mark.parametrize(
    ("flag", "value", "said"),
    [
        ("--tmp", "missing", "--tmp: not a directory: "),
        ("--json", "missing/fleet.json", "--json: not a directory: "),
        ("--config", "missing.yaml", "--config: no such file: "),
    ],
)
def test_a_bad_path_is_one_line_before_any_work(tmp_path, flag, value, said):
    run = subprocess.run(
        [sys.executable, "-m", "supervisor.tools.bench.fleet", "--bags", "2", "--robots", "1",
         flag, str(tmp_path / value)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert said in run.stderr.strip().splitlines()[-1], run.stderr
