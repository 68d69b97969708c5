"""The violation log under faults (docs/reference/faults.md): a full disk on a
real small tmpfs, and kill -9 of a real daemon at random moments."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from inproc import cli_main

from mitigations.violationlog.writer import Row, ViolationLog

CFG = "c0" * 32


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``safety-supervisor ARGS`` by the CLI's main in this process (tests/support/inproc.py):
    these tests read its lines, not the process's start."""
    return cli_main(*args)


@pytest.fixture
def small_fs(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs, mounted for the test and unmounted after it."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    mnt = tmp_path / "fs"
    mnt.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        pytest.skip(
            f"mount -t tmpfs is not permitted here (needs root that may mount): {r.stderr.strip()}"
        )
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def fill(path: Path) -> None:
    """Write ``path`` until the file system is full."""
    with open(path, "wb", buffering=0) as f:
        block = b"x" * 4096
        while True:
            try:
                f.write(block)
            except OSError as e:
                assert e.errno == errno.ENOSPC, e
                break
        for size in (512, 64, 1):  # the last bytes of a partly used page
            try:
                while True:
                    f.write(b"x" * size)
            except OSError:
                pass


def violation(log: ViolationLog, tick: int, way: str = "violation") -> bool:
    if way == "row":  # the halt path's entry (docs/reference/log.md#the-halt-path)
        template = log.violation_template(
            "state_req103",
            text="While classifier = 1 sRobot shall always satisfy OpState = 3",
            formula="H (classifier = 1 -> OpState = 3)",
        )
        assert template is not None
        row = Row.of({"tick": tick, "classifier": 1, "OpState": 2, "pad": "p" * 200})
        log.flush()  # as the daemon's loop does each turn: the chain's last hash is made
        written = log.violation_row(template, row=row, recent=[row], stale=[], policy_state="{}")
        assert written is not None
        return written
    return log.violation(
        "state_req103",
        text="While classifier = 1 sRobot shall always satisfy OpState = 3",
        formula="H (classifier = 1 -> OpState = 3)",
        tick=tick,
        inputs={"classifier": 1, "OpState": 2, "pad": "p" * 200},
        recent=[{"tick": tick, "classifier": 1}],
    )


def file_records(path: Path) -> list[dict]:
    out = []
    for line in path.read_bytes().split(b"\n"):
        try:
            out.append(json.loads(line))
        except ValueError:
            continue  # a fragment a full disk cut short (chained over)
    return out


@pytest.mark.parametrize("way", ["violation", "row"])
def test_full_disk_keeps_records_then_names_exactly_what_was_lost(
    small_fs: Path, capfd: pytest.CaptureFixture[str], way: str
) -> None:
    path = small_fs / "v.jsonl"
    log = ViolationLog(path, "sRobot", CFG, retry_buffer=20, retry_interval_s=3600)
    assert log.supervisor("start", pid=os.getpid())
    fill(small_fs / "filler")
    seqs = {}
    results = []
    for tick in range(100):
        results.append(violation(log, tick, way))
        seqs[tick] = log.seq
    # Monitoring went on; almost nothing could be written.
    assert results.count(False) >= 95
    assert 1 <= log.pending <= 21
    err = capfd.readouterr().err
    # Every record reached the journal (stderr), written or not.
    for tick in range(100):
        assert f"VIOLATION state_req103 tick={tick} " in err
    assert "NOT written: No space left on device" in err
    assert "dropped" in err and "logging.retry_buffer" in err

    os.unlink(small_fs / "filler")
    assert log.retry() == 0
    assert log.supervisor("after", n=1)
    log.close()

    recs = file_records(path)
    in_file = [r["seq"] for r in recs]
    assert in_file == sorted(in_file) and len(set(in_file)) == len(in_file)
    lost_recs = [r for r in recs if r.get("what") == "records_lost"]
    assert len(lost_recs) == 1, lost_recs
    lost = lost_recs[0]
    missing = {s for s in seqs.values() if s not in in_file}
    named = {s for a, b in lost["lost"] for s in range(a, b + 1)}
    assert missing and named == missing
    assert lost["count"] == len(missing)
    assert lost["reason"] == "No space left on device"
    assert lost["events"] == {"violation": len(missing)}
    assert lost["first_ts"] <= lost["last_ts"]
    # The records_lost record stands right where the lost records would have been.
    i = in_file.index(lost["seq"])
    assert in_file[i - 1] == min(missing) - 1 and lost["seq"] == max(missing) + 1
    # The first records of the outage were kept and written late, with their own time.
    kept = [r for r in recs if r["event"] == "violation"]
    assert [r["tick"] for r in kept] == [t for t, s in seqs.items() if s in in_file]

    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 0, r.stdout
    span = f"{min(missing)}-{max(missing)}"
    assert f"warning: {len(missing)} records (seq {span}) were never written: No space" in r.stdout
    assert f"chain intact, {len(missing)} records lost and accounted for" in r.stdout

    # Without the records_lost record the same gap is an error.
    lines = path.read_bytes().split(b"\n")
    j = next(k for k, ln in enumerate(lines) if b'"records_lost"' in ln)
    from mitigations.violationlog.format import seal_line

    # Replace it by an ordinary record, resealing every later line as a forger would.
    doctored = tmp = small_fs.parent / "doctored.jsonl"
    from mitigations.violationlog.format import sha256_hex

    out, prev = [], None
    for k, ln in enumerate(lines):
        if not ln:
            continue
        if k < j:
            out.append(ln + b"\n")
            continue
        rec = json.loads(ln) if ln.startswith(b"{") and ln.endswith(b"}") else None
        assert rec is not None
        if k == j:
            rec = {key: rec[key] for key in list(rec)[:6]} | {"what": "heartbeat"}
        rec.pop("line_sha256", None)
        rec["prev_sha256"] = prev or sha256_hex(out[-1])
        line = seal_line(json.dumps(rec, separators=(",", ":")).encode())
        prev = sha256_hex(line)
        out.append(line)
    tmp.write_bytes(b"".join(out))
    r = run_cli("logs", "--verify", str(doctored))
    assert r.returncode == 1, r.stdout
    assert f"{len(missing)} records missing (seq {span}) before this line" in r.stdout
    assert "chain intact" not in r.stdout


def test_periodic_retry_writes_the_queue_without_new_records(small_fs: Path) -> None:
    path = small_fs / "v.jsonl"
    log = ViolationLog(path, "sRobot", CFG, echo=False, retry_buffer=5, retry_interval_s=0.05)
    fill(small_fs / "filler")
    for tick in range(12):
        violation(log, tick)
    assert log.pending > 0
    os.unlink(small_fs / "filler")
    deadline = time.monotonic() + 10
    while log.pending and time.monotonic() < deadline:
        time.sleep(0.02)  # polling the retry thread's progress, not synchronisation
    assert log.pending == 0
    deadline = time.monotonic() + 10
    while (
        not any(r.get("what") == "records_lost" for r in file_records(path))
        and time.monotonic() < deadline
    ):
        time.sleep(0.02)
    recs = file_records(path)
    lost = [r for r in recs if r.get("what") == "records_lost"]
    assert len(lost) == 1 and lost[0]["seq"] == 13
    named = {s for a, b in lost[0]["lost"] for s in range(a, b + 1)}
    assert named == set(range(1, 13)) - {r["seq"] for r in recs}
    log.close()
    assert run_cli("logs", "--verify", str(path)).returncode == 0


def test_gap_is_reported_and_unaccounted_gap_fails(tmp_path: Path) -> None:
    """A record removed from the middle and the chain recomputed: --verify names
    the missing seq (the chain alone cannot show it)."""
    from mitigations.violationlog.format import seal_line, sha256_hex

    path = tmp_path / "v.jsonl"
    with ViolationLog(path, "sRobot", CFG, echo=False) as log:
        for tick in range(6):
            violation(log, tick)
    lines = path.read_bytes().splitlines(keepends=True)
    del lines[2]  # seq 3
    out, prev = [], sha256_hex(b"")
    for ln in lines:
        rec = json.loads(ln)
        rec.pop("line_sha256")
        rec["prev_sha256"] = prev
        line = seal_line(json.dumps(rec, separators=(",", ":")).encode())
        prev = sha256_hex(line)
        out.append(line)
    path.write_bytes(b"".join(out))
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 1
    assert f"{path}:3: 1 records missing (seq 3) before this line" in r.stdout
    assert "5 records, 1 records MISSING" in r.stdout


def test_seq_runs_on_across_rotation_and_restarts_with_a_new_writer(tmp_path: Path) -> None:
    path, rotated = tmp_path / "v.jsonl", tmp_path / "v.jsonl.1"
    log = ViolationLog(path, "sRobot", CFG, echo=False)
    violation(log, 1)
    violation(log, 2)
    os.rename(path, rotated)
    assert log.reopen()
    violation(log, 3)
    log.close()
    assert [r["seq"] for r in file_records(rotated)] == [1, 2]
    assert [r["seq"] for r in file_records(path)] == [3, 4]
    with ViolationLog(path, "sRobot", CFG, echo=False) as log2:  # a restart
        violation(log2, 4)
    assert [r["seq"] for r in file_records(path)] == [3, 4, 1]
    r = run_cli("logs", "--verify", str(rotated), str(path))
    assert r.returncode == 0, r.stdout
    assert "(rotation link intact)" in r.stdout
    # The old file's last record removed (and nothing else): the link names the
    # file that is gone, so verify of the pair reports it instead of a seq gap.
    ok = run_cli("logs", "--verify", str(path))
    assert ok.returncode == 0, ok.stdout


def _id() -> str:
    return uuid.uuid4().hex[:8]


# ------------------------------------------------------------------ a real daemon


def _ros() -> None:
    pytest.importorskip("rclpy")


LATCHED = (
    "    policy: {debounce_steps: 1, cooldown_ms: 1000, reset: after_mitigation}\n"
    "  - id: state_req201",
    "    policy: {debounce_steps: 1, latch: true, repeat_ms: 200, reset: after_mitigation}\n"
    "  - id: state_req201",
)


def _status_latched(d: Any, rid: str, timeout: float = 10) -> str:
    """Wait for a STATUS= notification that lists ``rid`` as latched."""
    from rosutil import wait_until

    start = len(d.notifications)

    def status() -> str | None:
        d.recv(0.2)
        for _, n in d.notifications[start:]:
            latched = n.split("latched=")[1].split()[0] if "latched=" in n else ""
            if "STATUS=" in n and rid in latched.split(","):
                return n
        return None

    return wait_until(f"STATUS with latched={rid}", status, timeout, d.explain)


@pytest.mark.ros
def test_sigusr1_reopens_only_and_sighup_during_a_reload_is_not_lost(
    tmp_path: Path, robot_node: Any
) -> None:
    _ros()
    import signal

    from rosutil import S0, VIOLATING, Daemon, Robot, variant, wait_until

    config = variant(tmp_path, LATCHED)
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        robot = Robot(robot_node)
        first = robot.violate(
            d, lambda r: r.get("requirement") == "state_req103", "state_req103 violated"
        )
        assert first["event"] == "violation"
        _status_latched(d, "state_req103")

        # logrotate: rename, then SIGUSR1 (the shipped snippet).
        rotated = tmp_path / "v.jsonl.1"
        os.rename(d.log, rotated)
        d.proc.send_signal(signal.SIGUSR1)
        link = d.wait_record(lambda r: r.get("what") == "log_reopened", "log_reopened")
        assert link["rotated"] is True and link["previous_last_sha256"]
        assert not [r for r in d.records() if r.get("what") == "reload"]
        _status_latched(d, "state_req103")
        # A new episode while latched: reported as such, actions not run again.
        robot.publish(S0)
        again = robot.until(
            VIOLATING,
            d,
            lambda r: (
                r["event"] == "violation"
                and r["requirement"] == "state_req103"
                and r["seq"] > link["seq"]
            ),
            "a violation of state_req103 after the reopen",
        )
        assert again["policy_state"]["latched"] is True
        assert again["policy_state"]["cooldown"] == "latched"

        # Two SIGHUPs, the second while the first reload still compiles: two reloads.
        d.proc.send_signal(signal.SIGHUP)
        d.wait_notify("RELOADING=1", timeout=5)
        d.proc.send_signal(signal.SIGHUP)
        wait_until(
            "two reloads",
            lambda: len([r for r in d.records() if r.get("what") == "reload"]) >= 2,
            60,
            d.explain,
        )
        reloads = [r for r in d.records() if r.get("what") == "reload"]
        assert [r["ok"] for r in reloads] == [True, True], reloads  # why, if refused
        assert all("state_req103" in r["kept_state"] for r in reloads)
        _status_latched(d, "state_req103")
        d.terminate()
    finally:
        d.close()
    r = run_cli("logs", "--verify", str(rotated), str(d.log))
    assert r.returncode == 0, r.stdout
    assert "(rotation link intact)" in r.stdout


@pytest.mark.ros
@pytest.mark.slow
def test_kill_9_at_random_moments_leaves_a_verifiable_log(tmp_path: Path, robot_node: Any) -> None:
    _ros()
    import random
    import signal

    from rosutil import VIOLATING, Daemon, Robot, variant

    rng = random.Random(20261123)
    config = variant(tmp_path)
    log = tmp_path / "v.jsonl"
    robot = Robot(robot_node)
    for i in range(3):
        run = tmp_path / f"run{i}"
        run.mkdir()
        (run / "v.jsonl").symlink_to(log)  # every run appends to the same file
        d = Daemon(run, config)
        try:
            d.wait_notify("READY=1", timeout=30)
            robot.matched()
            before = len(d.records())
            robot.until(
                VIOLATING,
                d,
                lambda r, n=before, d=d: r["event"] == "violation" and len(d.records()) > n,
                "violations being written",
            )
            end = time.monotonic() + rng.uniform(0.0, 0.6)
            while time.monotonic() < end:
                robot.publish(VIOLATING)  # as fast as we can: writes in flight when killed
            os.kill(d.proc.pid, signal.SIGKILL)
            d.proc.wait(timeout=10)
        finally:
            d.close()
        r = run_cli("logs", "--verify", str(log))
        errors = [ln for ln in r.stdout.splitlines() if ": warning: " not in ln]
        if r.returncode:
            # Only a torn last line, which the next writer closes.
            assert len(errors) == 1 and "incomplete final line" in errors[0], r.stdout
        else:
            assert "chain intact" in r.stdout, r.stdout
    with ViolationLog(log, "sRobot", CFG, echo=False) as closer:  # the next writer
        closer.supervisor("start", pid=os.getpid())
    r = run_cli("logs", "--verify", str(log))
    assert r.returncode == 0, r.stdout
    assert "chain intact" in r.stdout


@pytest.mark.parametrize("value", ["0", "-3", "lots", "1.5", "2000000"])
def test_retry_buffer_is_checked_at_its_line(tmp_path: Path, value: str) -> None:
    from rosutil import SROBOT

    text = SROBOT.read_text().replace("  recent: 10\n", f"  recent: 10\n  retry_buffer: {value}\n")
    config = tmp_path / "c.yaml"
    config.write_text(text)
    line = text.splitlines().index(f"  retry_buffer: {value}") + 1
    r = run_cli("check", str(config))
    assert r.returncode == 1
    assert f"{config}:{line}: logging: retry_buffer must be a whole number from 1" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.ros
def test_daemon_on_a_full_disk_keeps_monitoring_and_accounts_for_every_record(
    small_fs: Path, tmp_path: Path, robot_node: Any
) -> None:
    _ros()
    from rosutil import S0, VIOLATING, Daemon, Robot, variant, wait_until

    config = variant(tmp_path, ("  recent: 10\n", "  recent: 10\n  retry_buffer: 20\n"))
    run = tmp_path / "run"
    run.mkdir()
    log = small_fs / "v.jsonl"
    (run / "v.jsonl").symlink_to(log)
    d = Daemon(run, config)
    try:
        d.wait_notify("READY=1", timeout=30)
        robot = Robot(robot_node)
        robot.matched()
        robot.warm_up(d, S0)
        fill(small_fs / "filler")
        written_before = len(file_records(log))
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            robot.publish(VIOLATING, gap_before_trigger=0.005)
            time.sleep(0.05)  # the robot's publishing period
            robot.publish(S0, gap_before_trigger=0.005)
        # The outage reached the journal: violations on stderr, far more than the file holds.
        journal = d.stderr.read_text()
        echoed = journal.count("VIOLATION state_req103 ")
        assert echoed >= 10, journal[-2000:]
        assert "No space left on device" in journal
        assert d.proc.poll() is None  # still monitoring
        os.unlink(small_fs / "filler")
        lost = wait_until(
            "the records_lost record",
            lambda: next((r for r in file_records(log) if r.get("what") == "records_lost"), None),
            15,
            d.explain,
        )
        assert lost["reason"] == "No space left on device" and lost["count"] > 0
        d.terminate()
    finally:
        d.close()
    recs = file_records(log)
    assert len(recs) > written_before
    seqs = [r["seq"] for r in recs]
    named = {s for a, b in lost["lost"] for s in range(a, b + 1)}
    assert not named & set(seqs)
    assert sorted(set(seqs) | named) == list(range(1, max(seqs) + 1))  # nothing else missing
    in_file = sum(1 for r in recs if r["event"] == "violation")
    assert in_file + lost["events"].get("violation", 0) == journal_violations(d)
    r = run_cli("logs", "--verify", str(log))
    assert r.returncode == 0, r.stdout
    assert "records lost and accounted for" in r.stdout


def journal_violations(d: Any) -> int:
    """Violations the daemon echoed to stderr (the journal) over its whole run."""
    return d.stderr.read_text().count("VIOLATION ")
