"""logging.durability (docs/reference/log.md): when the violation record is fsynced
relative to the halt.

- the key is checked where the config enters, one line with its position;
- the writer: under ``after_publish`` a record made on the loop's thread is written
  at once and fsynced at ``flush()``; under ``before_action`` before it returns
  (the syscalls of a real child process, seen by strace);
- the daemon under strace, with a real subscriber seeing the halt: the halt's DDS
  send comes between the record's ``write`` and its ``fsync`` with
  ``after_publish``, after the ``fsync`` with ``before_action``;
- a daemon SIGKILLed right after the halt is seen: the record is in the file and
  the hash chain verifies.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
from rosutil import ROOT, SROBOT, wait_until

needs_strace = pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def with_durability(tmp_path: Path, value: str) -> tuple[Path, int]:
    """srobot.yaml with ``logging.durability: value``; the key's line."""
    text = SROBOT.read_text().replace("  recent: 10\n", f"  recent: 10\n  durability: {value}\n")
    config = tmp_path / "c.yaml"
    config.write_text(text)
    return config, text.splitlines().index(f"  durability: {value}") + 1


# ------------------------------------------------------------------ the config key


@pytest.mark.parametrize("value", ["after_fsync", "'yes'", "1", "[before_action]", "''"])
def test_a_bad_durability_is_one_line_at_its_key(tmp_path: Path, value: str) -> None:
    config, line = with_durability(tmp_path, value)
    r = run_cli("check", str(config))
    assert r.returncode == 1, r
    assert f"{config}:{line}: logging.durability must be one of after_publish, before_action" in (
        r.stderr
    )
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("value", ["after_publish", "before_action"])
def test_each_durability_is_accepted(tmp_path: Path, value: str) -> None:
    from supervisor.config import load_config

    config, _ = with_durability(tmp_path, value)
    assert load_config(config).log_durability == value


def test_the_default_durability_is_after_publish() -> None:
    from supervisor.config import load_config

    assert "durability" not in SROBOT.read_text()
    assert load_config(SROBOT).log_durability == "after_publish"


# ------------------------------------------------------------------ the writer's syscalls


def _calls(trace: Path) -> list[tuple[int, str]]:
    """(thread id, call) of each line of an ``strace -f -o`` file, in order; a call
    strace had to split (``<unfinished ...>`` / ``<... resumed>``) counts where it
    started."""
    out = []
    for ln in trace.read_text().splitlines():
        m = re.match(r"(\d+)\s+(?:\d\d:\d\d:\d\d\.\d+\s+)?(.*)", ln)
        if m and not m.group(2).startswith("<..."):
            out.append((int(m.group(1)), m.group(2)))
    return out


# the record as violation() writes it, and from the step's row (the halt path's entry)
WAYS = {
    "violation": 'log.violation("R1", text="t", formula="f", tick=7, inputs={"x": 1})',
    "row": (
        'r = Row.of({"tick": 7, "x": 1}); '
        'log.violation_row(log.violation_template("R1", text="t", formula="f"), row=r, '
        'recent=[r], stale=[], policy_state="{}")'
    ),
}


@needs_strace
@pytest.mark.parametrize("way", sorted(WAYS))
@pytest.mark.parametrize("durability", ["after_publish", "before_action"])
def test_the_writer_fsyncs_after_the_actions_or_before_them(
    tmp_path: Path, durability: str, way: str
) -> None:
    """The daemon's loop in miniature: a violation on ``defer_thread``, the action
    (here a marker write), then ``flush()``."""
    path = tmp_path / "v.log"
    child = textwrap.dedent(f"""
        import os, threading
        from mitigations.violationlog.writer import Row, ViolationLog
        log = ViolationLog({str(path)!r}, "sRobot", "00", echo=False,
                           durability={durability!r})
        log.defer_thread = threading.get_ident()
        {WAYS[way]}
        os.write(1, b"THE-HALT\\n")
        log.flush()
        os.write(1, b"FLUSHED\\n")
        log.close()
    """)
    trace = tmp_path / "strace.txt"
    argv = ["strace", "-f", "-e", "trace=write,fsync,fdatasync", "-s", "120", "-o", str(trace)]
    r = subprocess.run(
        [*argv, sys.executable, "-c", child],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if r.returncode != 0 and "ptrace" in r.stderr:
        pytest.skip(f"strace cannot trace here: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    calls = [c for _, c in _calls(trace)]

    def index(pred: Any) -> int:
        return next(i for i, c in enumerate(calls) if pred(c))

    write = index(lambda c: '"event\\":\\"violation' in c)
    fd = calls[write].split("(")[1].split(",")[0]
    halt = index(lambda c: "THE-HALT" in c)
    flushed = index(lambda c: "FLUSHED" in c)
    first_fsync = index(lambda c: c.startswith(f"fsync({fd})"))
    assert write < halt < flushed
    if durability == "after_publish":
        assert halt < first_fsync < flushed, calls
    else:
        assert write < first_fsync < halt, calls


def test_the_chain_hash_of_the_last_line_is_made_at_flush_not_before_the_next_halt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The loop's flush(), after a turn's halts, makes the chain's hash of the last
    line written, so the next violation hashes only its own line (its seal) before
    its halt; the chain is the same and verifies."""
    import threading

    import mitigations.violationlog.writer as writer
    from mitigations.violationlog.writer import ViolationLog

    path = tmp_path / "v.log"
    log = ViolationLog(path, "sRobot", "00", echo=False)
    log.defer_thread = threading.get_ident()
    made: list[bytes] = []
    real = writer.sha256_hex
    monkeypatch.setattr(writer, "sha256_hex", lambda b: made.append(b) or real(b))
    for tick in range(3):
        log.violation("R1", text="t", formula="f", tick=tick, inputs={"x": 1})
        log.mitigation("R1", action="halt", kind="publish", ok=True, latency_ms=0.1)
        before = len(made)
        log.flush()  # the turn's end: fsync, then the last line's chain hash
        assert len(made) == before + 1
        assert made[-1] == path.read_bytes().splitlines(keepends=True)[-1]
    chained = len(made)
    log.violation("R1", text="t", formula="f", tick=3, inputs={"x": 1})
    assert len(made) == chained  # no hash of an earlier line on the violation's way
    log.close()
    r = run_cli("logs", "--verify", str(path))
    assert r.returncode == 0, r.stdout + r.stderr


def test_a_pending_fsync_is_done_before_the_durability_changes_or_the_file_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A reload may switch to before_action, logrotate may move the file, between a
    record's write and the loop's flush(): neither leaves that record unsynced.
    (The fsync call is counted at the writer's seam; the real order is shown by the
    strace tests here.)"""
    import threading

    import mitigations.violationlog.writer as writer
    from mitigations.violationlog.writer import ViolationLog

    synced: list[int] = []
    real = writer.os.fsync
    monkeypatch.setattr(writer.os, "fsync", lambda fd: (synced.append(fd), real(fd))[1])
    path = tmp_path / "v.log"
    log = ViolationLog(path, "sRobot", "00", echo=False)
    assert log.durability == "after_publish"
    log.defer_thread = threading.get_ident()

    def violation() -> None:
        assert log.violation("R1", text="t", formula="f", tick=1, inputs={"x": 1})

    violation()
    assert synced == []  # written, its fsync waits for flush()
    log.durability = "before_action"
    assert len(synced) == 1
    violation()
    assert len(synced) == 2  # before_action: before the call returns
    with pytest.raises(ValueError, match="after_publish, before_action"):
        log.durability = "later"
    log.durability = "after_publish"
    violation()
    assert len(synced) == 2
    path.rename(tmp_path / "v.log.1")
    assert log.reopen()
    assert len(synced) == 3  # the old file's pending record, before it is left
    log.flush()
    assert len(synced) == 4  # the new file's link record (log_reopened)
    log.close()
    r = run_cli("logs", "--verify", str(tmp_path / "v.log.1"), str(path))
    assert r.returncode == 0, r


# ------------------------------------------------------------------ the daemon


REQ103 = (
    "on_violation: [record]\n"
    "    policy: {debounce_steps: 1, cooldown_ms: 1000, reset: after_mitigation}\n"
    "  - id: state_req201",
    "on_violation: [stop_robot]\n"
    "    policy: {debounce_steps: 1, cooldown_ms: 1000, reset: after_mitigation}\n"
    "  - id: state_req201",
)
TRACED = "write,fsync,fdatasync,sendto,sendmsg,futex"


def _halt_daemon(
    tmp_path: Path,
    durability: str | None,
    strace: Path | None = None,
    inject: str = "",
    stale_ms: int = 500,
) -> Any:
    """The sRobot daemon whose state_req103 publishes the halt (every other
    requirement only records), optionally under ``strace -f`` (``inject``: its
    ``-e inject=`` fault); ``stale_ms``: its inputs' stale limit."""
    from rosutil import Daemon, variant

    edits = [REQ103, ("  stale_after_ms: 500 ", f"  stale_after_ms: {stale_ms} ")]
    if durability is not None:
        edits.append(("  recent: 10\n", f"  recent: 10\n  durability: {durability}\n"))
    config = variant(tmp_path, *edits)

    class Traced(Daemon):
        def spawn(self, tmp: Path, argv: list[str], env: dict[str, str], *, cwd: Path) -> None:
            if strace is not None:
                argv = ["strace", "-f", "-tt", "-yy", "-s", "400", "-e", f"trace={TRACED}",
                        *(["-e", f"inject={inject}"] if inject else []),
                        "-o", str(strace), *argv]  # fmt: skip
            super().spawn(tmp, argv, env, cwd=cwd)

    d = Traced(tmp_path, config)
    d.wait_notify("READY=1", timeout=60)
    return d


def _daemon_pid(d: Any) -> int:
    """The daemon's own pid, in the group of its child process (under strace, the
    group holds strace too)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            pgid = os.getpgid(int(entry.name))
        except (OSError, ProcessLookupError):
            continue
        if (
            pgid == d.proc.pid
            and b"supervisor" in argv
            and b"run" in argv
            and b"strace" not in argv[0]
        ):
            return int(entry.name)
    raise AssertionError(f"no daemon process in group {d.proc.pid}")


def _state(pid: int) -> str:
    """A process's state letter (Z: killed, not reaped yet), "" when it is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return ""


def _see_the_halt(tmp_path: Path, robot_node: Any, d: Any) -> dict[str, Any]:
    """Violate state_req103 until a real subscriber receives the halt (True on
    /sRobotHalt); the violation record."""
    from rosutil import Robot, spin_until
    from std_msgs.msg import Bool

    halts: list[bool] = []
    robot_node.create_subscription(Bool, "/sRobotHalt", lambda m: halts.append(m.data), 10)
    robot = Robot(robot_node)
    v = robot.violate(
        d, lambda r: r["event"] == "violation" and r["requirement"] == "state_req103", "violation"
    )
    spin_until(robot_node, "the halt", lambda: True in halts, 10)
    return v


def _is_dds_send(call: str) -> bool:
    """A DDS sample leaving the process: a UDP datagram, or the wake-up of a reader
    in another process through Fast DDS's shared-memory transport (a futex shared
    between processes: Python's and the C library's own locks are private)."""
    if call.startswith(("sendto(", "sendmsg(")):
        return "<UDP" in call.split(",", 1)[0]
    return call.startswith("futex(") and ", FUTEX_WAKE, " in call


@pytest.mark.ros
@needs_strace
@pytest.mark.parametrize("durability", ["after_publish", "before_action"])
def test_the_daemon_sends_the_halt_before_or_after_the_fsync(
    tmp_path: Path, robot_node: Any, durability: str
) -> None:
    trace = tmp_path / "strace.txt"
    d = _halt_daemon(tmp_path, None if durability == "after_publish" else durability, trace)
    try:
        v = _see_the_halt(tmp_path, robot_node, d)
        os.kill(_daemon_pid(d), signal.SIGTERM)
        d.wait_notify("STOPPING=1", timeout=20)
        assert d.proc.wait(timeout=30) == 0, d.explain()
    finally:
        d.close()
    calls = _calls(trace)
    log = str(d.log)
    # the halt's violation record's write: other requirements' records (no action)
    # may come first, and their fsync with no send before it
    at = next(
        i
        for i, (_, c) in enumerate(calls)
        if c.startswith("write(") and log in c and '\\"requirement\\":\\"state_req103' in c
    )
    loop = calls[at][0]  # the daemon's monitoring thread
    after = [(i, c) for i, (tid, c) in enumerate(calls) if i > at and tid == loop]
    fsync = next(i for i, c in after if c.startswith("fsync(") and log in c)
    send = next(i for i, c in after if _is_dds_send(c))
    mitigation = next(i for i, c in after if '\\"event\\":\\"mitigation' in c)
    shown = "\n".join(c for _, c in calls[at : max(fsync, send, mitigation) + 1])
    assert send < mitigation, shown  # the halt is out before its record is made
    if durability == "after_publish":
        assert send < fsync, shown
    else:
        assert fsync < send, shown
    assert v["requirement"] == "state_req103"


@pytest.mark.ros
@needs_strace
def test_a_daemon_killed_after_the_halt_leaves_the_record_and_an_intact_chain(
    tmp_path: Path, robot_node: Any
) -> None:
    """The record's fsync is held back (strace delays every fsync by 3 s), so the
    daemon is SIGKILLed after the halt and before the record reached the disk: what
    survives is the page cache's copy, as after any crash of the process."""
    trace = tmp_path / "strace.txt"
    # Inputs never go stale here: a 3 s fsync blocks the loop, and each stale input's
    # record would block it 3 s more (on a loaded machine, past the wait for the halt).
    d = _halt_daemon(tmp_path, None, trace, inject="fsync:delay_enter=3000000", stale_ms=600_000)
    try:
        v = _see_the_halt(tmp_path, robot_node, d)
        pid = _daemon_pid(d)
        os.kill(pid, signal.SIGKILL)
        # The kill takes effect when strace's delay ends, and then the fsync is
        # skipped (a fatal signal is pending at the syscall's entry).
        wait_until("the daemon's end", lambda: _state(pid) in ("Z", "X", ""), 30)
        d.proc.wait(timeout=30)  # strace, once it has written its last lines
    finally:
        d.close()
    # Only the log's writer fsyncs; a completed one (whole, or resumed) after the last
    # violation's write would mean the kill came after the record was on disk.  Earlier
    # records' fsyncs (the start's, a first violation's) may complete: the loop waits
    # in each, and the last violation comes only after them.
    traced = trace.read_text().splitlines()
    last = max(
        i for i, ln in enumerate(traced) if "write(" in ln and '\\"event\\":\\"violation' in ln
    )
    done = [ln for ln in traced[last:] if re.search(r"fsync.*\) = 0\b", ln)]
    assert not done, f"an fsync returned before the kill: {done}"
    lines = d.log.read_bytes().splitlines()
    assert any(b'"event":"violation"' in ln and f'"seq":{v["seq"]}'.encode() in ln for ln in lines)
    r = run_cli("logs", "--verify", str(d.log))
    assert r.returncode == 0, r
    assert "chain intact" in r.stdout, r.stdout


# ------------------------------------------------------------------ replay


def test_replay_writes_the_daemons_order_under_either_durability(tmp_path: Path) -> None:
    """Replay runs the daemon's core and writer: each violation's record comes before
    its (dry-run) mitigation records, and the order does not depend on when the
    fsync comes."""
    from mitigations.violationlog.reader import iter_records
    from tests.supervisor.tools.replay.test_replay import CONFIG, messages, write_bag

    bag = write_bag(tmp_path / "bag", messages(7, 3000))
    text = CONFIG.format(policy="on_message", trigger="", limit=2.0)
    drop = ("ts", "_ts", "prev_sha256", "seq", "line_sha256", "config_sha256", "config")
    runs = []
    for mode in ("after_publish", "before_action"):
        (tmp_path / mode).mkdir()
        cfg = tmp_path / mode / "c.yaml"
        cfg.write_text(text + f"logging: {{durability: {mode}}}\n")
        out = tmp_path / mode / "v.jsonl"
        r = run_cli("replay", str(cfg), str(bag), "-o", str(out))
        assert r.returncode in (0, 1) and out.exists(), r.stderr  # 1: violations found
        runs.append([{k: v for k, v in x.items() if k not in drop} for x in iter_records(str(out))])
    assert runs[0] == runs[1]
    seen: set[str] = set()
    acted = 0
    for x in runs[0]:
        if x["event"] == "violation":
            seen.add(x["requirement"])
        elif x["event"] == "mitigation" and x.get("stage") == "violation":
            assert x["requirement"] in seen, x  # its violation's record came first
            acted += 1
    assert acted
