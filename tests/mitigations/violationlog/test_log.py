"""mitigations.violationlog.writer (the violation log writer) on real files, verified through the CLI."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from inproc import cli_main

from mitigations.violationlog.format import EMPTY_SHA256
from mitigations.violationlog.reader import verify_bytes
from mitigations.violationlog.writer import ViolationLog
from monitors.errors import UserError

REPO = Path(__file__).resolve().parents[3]
CFG = "c0" * 32
TS_RE = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{6}Z$")


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``safety-supervisor ARGS`` by the CLI's main in this process (tests/support/inproc.py):
    these tests read its lines, not the process's start."""
    return cli_main(*args)


def new_log(path: Path, **kw) -> ViolationLog:
    kw.setdefault("echo", False)
    return ViolationLog(path, "sRobot", CFG, **kw)


def violation(log: ViolationLog, tick: int, req: str = "state_req103", **kw) -> bool:
    return log.violation(
        req,
        text="upon classifier = 1 the sRobot shall immediately satisfy OpState = 2",
        formula="H (classifier = 1 -> OpState = 2)",
        tick=tick,
        inputs={"classifier": 1, "distance_to_target": 2, "OpState": 2, "speed": 0.5, "uvc": True},
        recent=[{"classifier": 0}, {"classifier": 1}],
        stale=[],
        policy_state={"policy": "on_trigger"},
        **kw,
    )


def write_sample(path: Path, n: int = 6) -> list[bytes]:
    with new_log(path) as log:
        log.supervisor("start", pid=os.getpid())
        for tick in range(1, n - 1):
            violation(log, tick)
        log.mitigation("state_req103", action="stop_uvc", kind="topic", ok=True, latency_ms=1.25)
    lines = path.read_bytes().splitlines(keepends=True)
    assert len(lines) == n
    return lines


def records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_bytes().splitlines()]


# ------------------------------------------------------------------ schema and chain


def test_records_have_the_contract_schema(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    with new_log(path) as log:
        assert log.supervisor("start", pid=123)
        assert violation(log, 42)
        assert log.mitigation(
            "state_req103",
            action="stop",
            kind="topic",
            ok=False,
            error="timeout",
            latency_ms=12.5,
            attempt=2,
        )
        assert log.reset("state_req103", reason="operator")
        log.config_sha256 = "d1" * 32
        assert log.supervisor("reload", ok=True, why="SIGHUP")
    recs = records(path)
    assert [r["event"] for r in recs] == [
        "supervisor",
        "violation",
        "mitigation",
        "reset",
        "supervisor",
    ]
    for r in recs:
        assert list(r)[:6] == [
            "ts",
            "event",
            "component",
            "config_sha256",
            "prev_sha256",
            "seq",
        ]
        assert list(r)[-1] == "line_sha256"
        assert TS_RE.match(r["ts"]), r["ts"]
        assert r["component"] == "sRobot"
    assert [r["config_sha256"] for r in recs] == [CFG] * 4 + ["d1" * 32]
    assert [r["seq"] for r in recs] == [1, 2, 3, 4, 5]
    v = recs[1]
    assert v["requirement"] == "state_req103" and v["tick"] == 42
    assert v["inputs"] == {
        "classifier": 1,
        "distance_to_target": 2,
        "OpState": 2,
        "speed": 0.5,
        "uvc": True,
    }
    assert v["recent"] == [{"classifier": 0}, {"classifier": 1}]
    assert v["stale"] == [] and v["policy_state"] == {"policy": "on_trigger"}
    assert "text" in v and "formula" in v
    m = recs[2]
    assert (m["action"], m["kind"], m["ok"], m["error"], m["latency_ms"], m["attempt"]) == (
        "stop",
        "topic",
        False,
        "timeout",
        12.5,
        2,
    )
    assert recs[3]["reason"] == "operator"
    assert recs[0]["what"] == "start" and recs[4]["what"] == "reload" and recs[4]["why"] == "SIGHUP"
    # the chain, recomputed here independently of supervisor.tools.logs
    lines = path.read_bytes().splitlines(keepends=True)
    assert recs[0]["prev_sha256"] == hashlib.sha256(b"").hexdigest()
    for prev_line, rec in zip(lines, recs[1:], strict=False):
        assert rec["prev_sha256"] == hashlib.sha256(prev_line).hexdigest()


def test_chain_verifies_through_the_cli(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    write_sample(path)
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.strip() == f"{path}: 6 records, chain intact"


def _edit_byte(lines: list[bytes]) -> tuple[list[bytes], int]:
    line = bytearray(lines[2])
    i = line.index(b"classifier = 1")  # inside the "text" value
    line[i] = ord("C")
    return lines[:2] + [bytes(line)] + lines[3:], 3


def _edit_and_reseal(lines: list[bytes]) -> tuple[list[bytes], int]:
    # someone who knows line_sha256 and recomputes it: caught by the next line's prev
    from mitigations.violationlog.format import seal_line

    rec = json.loads(lines[2])
    rec["tick"] = 99
    del rec["line_sha256"]
    body = json.dumps(rec, separators=(",", ":")).encode()
    return lines[:2] + [seal_line(body)] + lines[3:], 4


def _edit_prev(lines: list[bytes]) -> tuple[list[bytes], int]:
    line = bytearray(lines[4])
    i = line.index(b'"prev_sha256":"') + len(b'"prev_sha256":"')
    line[i] = ord("f" if line[i] != ord("f") else "e")
    return lines[:4] + [bytes(line)] + lines[5:], 5


TAMPERING = {
    "edit a byte in line 3": (_edit_byte, "line was edited"),
    "edit line 3 and recompute its line_sha256": (_edit_and_reseal, "a line before it was removed"),
    "delete line 3": (lambda ls: (ls[:2] + ls[3:], 3), "a line before it was removed"),
    "delete line 1": (lambda ls: (ls[1:], 1), "first line(s) were removed"),
    "insert a copy of line 2 as line 4": (lambda ls: (ls[:3] + [ls[1]] + ls[3:], 4), "inserted"),
    "insert an empty line as line 2": (
        lambda ls: (ls[:1] + [b"\n"] + ls[1:], 2),
        "not a log record",
    ),
    "truncate the last line": (lambda ls: (ls[:5] + [ls[5][:-20]], 6), "incomplete final line"),
    "edit prev_sha256 of line 5": (_edit_prev, "line was edited"),
}


@pytest.mark.parametrize("case", list(TAMPERING))
def test_tampering_is_detected_at_the_right_line(tmp_path: Path, case: str) -> None:
    path = tmp_path / "v.log"
    lines = write_sample(path)
    tamper, reason = TAMPERING[case]
    new_lines, lineno = tamper(lines)
    assert new_lines != lines
    path.write_bytes(b"".join(new_lines))
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 1, r.stdout + r.stderr
    first = r.stdout.splitlines()[0]
    assert first.startswith(f"{path}:{lineno}: "), first
    assert reason in first, first
    assert "chain intact" not in r.stdout


# ------------------------------------------------------------------ durability


def test_violation_is_in_the_file_when_the_call_returns(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    log = new_log(path)
    for tick in range(3):
        assert violation(log, tick)
        # a separate open file description, as a second process would have
        with open(path, "rb") as f:
            last = f.read().splitlines()[-1]
        assert json.loads(last)["tick"] == tick
    log.close()


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_fsync_comes_after_the_write_and_before_violation_returns(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    child = textwrap.dedent(f"""
        import os
        from mitigations.violationlog.writer import ViolationLog
        log = ViolationLog({str(path)!r}, "sRobot", "00", echo=False)
        log.reset("R1", reason="marker-reset")
        os.write(1, b"AFTER-RESET\\n")
        log.violation("R1", text="t", formula="f", tick=7, inputs={{"x": 1}})
        os.write(1, b"AFTER-VIOLATION\\n")
        log.mitigation("R1", action="a", kind="topic", ok=True, latency_ms=1.0)
        os.write(1, b"AFTER-MITIGATION\\n")
        log.close()
    """)
    trace = tmp_path / "strace.txt"
    r = subprocess.run(
        [
            "strace",
            "-f",
            "-e",
            "trace=write,fsync,fdatasync",
            "-s",
            "120",
            "-o",
            str(trace),
            sys.executable,
            "-c",
            child,
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if r.returncode != 0 and "ptrace" in r.stderr:
        pytest.skip(f"strace cannot trace here: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    calls = [ln.split(None, 1)[1].lstrip() for ln in trace.read_text().splitlines() if " " in ln]
    calls = [c for c in calls if c.startswith(("write(", "fsync(", "fdatasync("))]

    def index(pred) -> int:
        return next(i for i, c in enumerate(calls) if pred(c))

    reset_w = index(lambda c: '"event\\":\\"reset' in c)
    fd = calls[reset_w].split("(")[1].split(",")[0]
    after_reset = index(lambda c: "AFTER-RESET" in c)
    viol_w = index(lambda c: '"event\\":\\"violation' in c)
    after_viol = index(lambda c: "AFTER-VIOLATION" in c)
    mit_w = index(lambda c: '"event\\":\\"mitigation' in c)
    after_mit = index(lambda c: "AFTER-MITIGATION" in c)
    fsyncs = [i for i, c in enumerate(calls) if c.startswith(f"fsync({fd})")]
    assert not [i for i in fsyncs if reset_w < i < after_reset]  # reset: no fsync needed
    assert [i for i in fsyncs if viol_w < i < after_viol], calls
    assert [i for i in fsyncs if mit_w < i < after_mit], calls


# ------------------------------------------------------------------ threads, rotation, restart


def test_concurrent_writers_produce_whole_lines_and_an_intact_chain(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    log = new_log(path)
    n_threads, per_thread = 8, 40
    big = [{"classifier": i, "pad": "x" * 300} for i in range(20)]  # ~7 KB lines
    start = threading.Barrier(n_threads)

    def worker(k: int) -> None:
        start.wait()
        for i in range(per_thread):
            if i % 2:
                log.reset(f"R{k}", reason=f"r{i}")
            else:
                log.violation(f"R{k}", text="t", formula="f", tick=i, inputs={"k": k}, recent=big)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    log.close()
    assert log.failed_writes == 0
    data = path.read_bytes()
    assert data.endswith(b"\n")
    recs = [json.loads(line) for line in data.splitlines()]
    assert len(recs) == n_threads * per_thread
    for k in range(n_threads):
        assert sorted(
            r["tick"] for r in recs if r["requirement"] == f"R{k}" and "tick" in r
        ) == list(range(0, per_thread, 2))
    res = verify_bytes(str(path), data)
    assert res.intact and res.records == n_threads * per_thread, res.errors


def test_reopen_after_logrotate_create_mode(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    rotated = tmp_path / "v.log.1"
    log = new_log(path)
    for tick in range(3):
        violation(log, tick)
    os.rename(path, rotated)  # logrotate: rename, then SIGHUP
    violation(log, 3)  # before the signal arrives: still the old file
    assert log.reopen()
    violation(log, 4)
    log.reset("state_req103", reason="r")
    log.close()
    old, new = records(rotated), records(path)
    assert [r.get("tick") for r in old] == [0, 1, 2, 3]
    assert new[0]["what"] == "log_reopened" and new[0]["rotated"] is True
    assert new[0]["prev_sha256"] == EMPTY_SHA256  # each file is its own chain
    last_old = rotated.read_bytes().splitlines(keepends=True)[-1]
    assert new[0]["previous_last_sha256"] == hashlib.sha256(last_old).hexdigest()
    assert [r.get("tick") for r in new[1:]] == [4, None]
    r = run_cli("logs", "--verify", str(rotated), str(path))
    assert r.returncode == 0, r.stdout
    assert f"{rotated}: 4 records, chain intact" in r.stdout
    assert f"{path}: 3 records, chain intact" in r.stdout
    assert f"{path}:1: continues {rotated}" in r.stdout


def test_reopen_without_rotation_continues_the_same_chain(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    log = new_log(path)
    violation(log, 1)
    assert log.reopen()
    violation(log, 2)
    log.close()
    recs = records(path)
    assert recs[1]["what"] == "log_reopened" and recs[1]["rotated"] is False
    assert "previous_last_sha256" not in recs[1]
    assert verify_bytes(str(path), path.read_bytes()).records == 3


def test_restart_appends_and_keeps_the_chain(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    write_sample(path)
    with new_log(path) as log:
        violation(log, 100)
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 0 and "7 records, chain intact" in r.stdout, r.stdout


def test_line_cut_by_a_crash_is_terminated_on_restart(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    lines = write_sample(path)
    path.write_bytes(b"".join(lines[:5]) + lines[5][:50])  # crash in the middle of a write
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 1 and f"{path}:6: incomplete final line" in r.stdout
    with new_log(path) as log:
        violation(log, 7)
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 0, r.stdout
    assert f"{path}:6: warning: incomplete record" in r.stdout
    assert f"{path}: 6 records, chain intact" in r.stdout
    assert json.loads(path.read_bytes().splitlines()[-1])["tick"] == 7


def test_copytruncate_restarts_the_chain(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    log = new_log(path)
    violation(log, 1)
    violation(log, 2)
    os.truncate(path, 0)  # logrotate copytruncate, without a signal
    violation(log, 3)
    log.close()
    res = verify_bytes(str(path), path.read_bytes())
    assert res.intact and res.records == 1, res.errors


# ------------------------------------------------------------------ values, errors, echo


def test_nan_and_inf_are_written_as_strict_json(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    with new_log(path) as log:
        log.violation(
            "R",
            text="t",
            formula="f",
            tick=1,
            inputs={"a": float("nan"), "b": float("inf"), "c": float("-inf"), "d": 1.5},
            recent=[{"a": float("nan")}],
            policy_state={"x": (float("inf"), 2)},
        )

    def reject(name: str) -> None:
        raise AssertionError(f"non-standard JSON constant {name}")

    rec = json.loads(path.read_bytes(), parse_constant=reject)
    assert rec["inputs"] == {"a": "nan", "b": "inf", "c": "-inf", "d": 1.5}
    assert rec["recent"] == [{"a": "nan"}]
    assert rec["policy_state"] == {"x": ["inf", 2]}


def test_unwritable_path_is_a_clear_user_error(tmp_path: Path) -> None:
    missing = tmp_path / "no-such-dir" / "v.log"
    with pytest.raises(UserError) as e:
        new_log(missing)
    assert str(e.value).startswith(f"{missing}: cannot open the violation log")
    assert "No such file or directory" in str(e.value) and "LogsDirectory" in str(e.value)
    with pytest.raises(UserError) as e:
        new_log(tmp_path)
    assert str(e.value).startswith(f"{tmp_path}: cannot open the violation log")


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_full_disk_is_reported_and_counted_not_raised(capfd) -> None:
    log = ViolationLog("/dev/full", "sRobot", CFG)  # every write fails with ENOSPC
    assert violation(log, 1) is False
    assert (
        log.mitigation("state_req103", action="a", kind="topic", ok=True, latency_ms=1.0) is False
    )
    assert log.failed_writes == 2 and log.pending == 2  # kept in memory, retried
    err = capfd.readouterr().err
    assert "violation record seq=1 NOT written: No space left on device; kept in memory" in err
    # the record still reaches journald as a readable line
    assert "VIOLATION state_req103 tick=1 classifier=1" in err
    log.close()


def test_human_readable_echo(tmp_path: Path, capfd) -> None:
    stream = io.StringIO()
    with ViolationLog(tmp_path / "v.log", "sRobot", CFG, echo=stream) as log:
        log.violation(
            "state_req103",
            text="t",
            formula="f",
            tick=42,
            inputs={"classifier": 1, "distance_to_target": 2, "OpState": 2},
        )
        log.mitigation(
            "state_req103", action="stop", kind="topic", ok=False, error="timeout", latency_ms=3.0
        )
        log.supervisor("input_stale", variable="classifier")
    assert stream.getvalue().splitlines() == [
        "VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2 OpState=2",
        "MITIGATION state_req103 topic:stop FAILED (timeout) latency_ms=3.0 attempt=1",
        "SUPERVISOR input_stale variable=classifier",
    ]
    with new_log(tmp_path / "quiet.log") as log:  # echo=False
        violation(log, 1)
    assert capfd.readouterr().err == ""


def test_reserved_field_names_do_not_overwrite_the_header(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    with new_log(path) as log:
        log.supervisor("reload", event="x", prev_sha256="y", ok=False, why="bad config")
    rec = records(path)[0]
    assert rec["event"] == "supervisor" and rec["prev_sha256"] == EMPTY_SHA256
    assert rec["event_"] == "x" and rec["prev_sha256_"] == "y"
    assert verify_bytes(str(path), path.read_bytes()).intact


def test_write_after_close_is_counted_not_raised(tmp_path: Path) -> None:
    log = new_log(tmp_path / "v.log")
    log.close()
    assert violation(log, 1) is False
    assert log.failed_writes == 1
