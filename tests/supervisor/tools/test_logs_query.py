"""``logs`` as a query tool on a log of hundreds of records written by the real
writer across two rotations (rename + reopen, as logrotate's create mode does; the
oldest file gzipped): time filters (absolute and relative), requirement, event,
--failed, --json, --summary, -n, --verify, and --follow as a subprocess."""

from __future__ import annotations

import gzip
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from mitigations.violationlog import writer
from mitigations.violationlog.writer import ViolationLog
from supervisor.cli import main
from supervisor.tools import logs

ROOT = Path(__file__).resolve().parents[3]
T0 = datetime(2026, 11, 20, 0, 0, tzinfo=UTC)
STEP = timedelta(minutes=1)  # one record a minute: 300 records span 5 hours


class _Clock:
    """The writer's clock, one STEP per record, so record times are known."""

    t = T0

    @classmethod
    def stamp(cls) -> str:
        """As the writer's ``_now`` writes a time: UTC, six digits of microseconds."""
        cls.t += STEP
        return cls.t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _write(log: ViolationLog, i: int) -> None:
    """Record ``i`` of a varied stream: violations of three requirements, their
    mitigations (every 7th failed), confirmations (every 5th not in effect)."""
    req = f"R{(i // 6) % 3}"
    kind = i % 6
    if kind in (0, 3):
        log.violation(req, text="t", formula="f", tick=i, inputs={"x": i})
    elif kind in (1, 4):
        ok = i % 7 != 0
        log.mitigation(
            req, action="stop", kind="publish", ok=ok, error=None if ok else "boom", latency_ms=1.0
        )
    elif kind == 2:
        ok = i % 5 != 0
        log.mitigation(req, action="confirm:OpState", kind="confirm", ok=ok, latency_ms=9.0)
    else:
        log.supervisor("input_stale", input="x", detail=f"silent {i}")


@pytest.fixture
def rotated(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """v.jsonl.2.gz (oldest), v.jsonl.1, v.jsonl: 300 records and 2 log_reopened."""
    monkeypatch.setattr(_Clock, "t", T0)
    monkeypatch.setattr(writer, "_now", _Clock.stamp)
    live = tmp_path / "v.jsonl"
    with ViolationLog(live, "sRobot", "ab" * 32, echo=False) as log:
        for i in range(300):
            if i in (100, 200):  # logrotate: shift the old files, rename, reopen
                one = tmp_path / "v.jsonl.1"
                if one.exists():
                    one.rename(tmp_path / "v.jsonl.2")
                live.rename(one)
                assert log.reopen()
            _write(log, i)
    two = tmp_path / "v.jsonl.2"
    with two.open("rb") as src, gzip.open(tmp_path / "v.jsonl.2.gz", "wb") as dst:
        shutil.copyfileobj(src, dst)
    lines = two.read_text().splitlines() + (tmp_path / "v.jsonl.1").read_text().splitlines()
    lines += live.read_text().splitlines()
    two.unlink()
    files = [str(tmp_path / n) for n in ("v.jsonl.2.gz", "v.jsonl.1", "v.jsonl")]
    return {"files": files, "lines": lines, "recs": [json.loads(x) for x in lines]}


def _json(capsys) -> list[str]:
    return capsys.readouterr().out.splitlines()


def _ts(rec: dict[str, Any]) -> datetime:
    return datetime.fromisoformat(rec["ts"])


def test_files_in_chronological_order_whatever_the_command_line(rotated, capsys) -> None:
    files = rotated["files"]
    assert len(rotated["lines"]) == 302
    for order in (files, files[::-1], [files[1], files[2], files[0]]):
        assert main(["logs", "--json", *order]) == 0
        assert _json(capsys) == rotated["lines"]  # as stored, in the order written
    assert main(["logs", *files[::-1]]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["TIME", "EVENT", "REQUIREMENT", "DETAILS"]
    assert [row.split()[0] for row in table[1:]] == [r["ts"] for r in rotated["recs"]]


def test_absolute_times(rotated, capsys) -> None:
    since, until = T0 + 50 * STEP, T0 + 250 * STEP
    files = rotated["files"]
    argv = ["logs", "--json", "--since", since.isoformat(), "--until", until.isoformat()]
    assert main([*argv, *files]) == 0
    want = [
        x
        for x, r in zip(rotated["lines"], rotated["recs"], strict=True)
        if since <= _ts(r) <= until
    ]
    assert _json(capsys) == want and len(want) > 150  # across both rotations
    # a time without a zone is UTC; minutes only
    assert main(["logs", "--json", "--since", "2026-11-20T04:10", *files]) == 0
    assert len(_json(capsys)) == sum(_ts(r) >= T0 + 250 * STEP for r in rotated["recs"])


def test_relative_times(rotated, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    now = T0 + 302 * STEP  # the last record's time
    monkeypatch.setattr(logs, "_now", lambda: now)
    recs = rotated["recs"]
    for arg, since in [
        ("-1h", now - timedelta(hours=1)),
        ("-30min", now - timedelta(minutes=30)),
        ("2 hours ago", now - timedelta(hours=2)),
        ("-1h 30min", now - timedelta(minutes=90)),
        ("today", T0),
    ]:
        assert main(["logs", "--json", "--since", arg, *rotated["files"]]) == 0, arg
        assert len(_json(capsys)) == sum(_ts(r) >= since for r in recs), arg
    assert main(["logs", "--json", "--until", "-4h", *rotated["files"]]) == 0
    assert len(_json(capsys)) == sum(_ts(r) <= now - timedelta(hours=4) for r in recs)
    assert (
        main(["logs", "--json", "--since", "yesterday", "--until", "today", *rotated["files"]]) == 0
    )
    assert _json(capsys) == []
    assert main(["logs", "--json", "--since", "now", *rotated["files"]]) == 0
    assert len(_json(capsys)) == 1


def test_parse_when() -> None:
    now = datetime(2026, 11, 23, 14, 30, 15, tzinfo=UTC)
    p = logs.parse_when
    assert p("now", now) == now
    assert p("-2h", now) == now - timedelta(hours=2)
    assert p("-30min", now) == now - timedelta(minutes=30)
    assert p("-1d", now) == now - timedelta(days=1)
    assert p("+10s", now) == now + timedelta(seconds=10)
    assert p("2 hours ago", now) == now - timedelta(hours=2)
    assert p("1 week ago", now) == now - timedelta(weeks=1)
    assert p("-1.5h", now) == now - timedelta(minutes=90)
    assert p("today", now) == datetime(2026, 11, 23, tzinfo=UTC)
    assert p("yesterday", now) == datetime(2026, 11, 22, tzinfo=UTC)
    assert p("2026-11-21", now) == datetime(2026, 11, 21, tzinfo=UTC)
    assert p("2026-11-21T14:00+01:00", now) == datetime(2026, 11, 21, 13, tzinfo=UTC)
    for bad in ("-2 fortnights", "2 hours", "ago", "last tuesday", "-", "-3M"):
        with pytest.raises(ValueError, match="not a time"):
            p(bad, now)


def test_requirement_event_failed(rotated, capsys) -> None:
    files, recs = rotated["files"], rotated["recs"]
    assert main(["logs", "--json", "--requirement", "R1", "--event", "violation", *files]) == 0
    got = [json.loads(x) for x in _json(capsys)]
    assert got == [r for r in recs if r.get("requirement") == "R1" and r["event"] == "violation"]
    assert main(["logs", "--json", "--failed", *files]) == 0
    failed = [json.loads(x) for x in _json(capsys)]
    assert failed == [r for r in recs if r["event"] == "mitigation" and not r["ok"]]
    assert {r["kind"] for r in failed} == {"publish", "confirm"}
    assert main(["logs", "--failed", "--requirement", "R2", "--since", "-1000d", *files]) == 0
    rows = capsys.readouterr().out.splitlines()[1:]
    assert rows and all(" R2 " in row and "FAILED" in row for row in rows)
    assert len(rows) == sum(1 for r in failed if r["requirement"] == "R2")


def test_summary_with_filters(rotated, capsys) -> None:
    files, recs = rotated["files"], rotated["recs"]
    since = T0 + 100 * STEP
    assert main(["logs", "--summary", "--since", since.isoformat(), *files]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["REQUIREMENT", "VIOLATIONS", "FIRST", "LAST", "MIT_OK", "MIT_FAILED"]
    sel = [r for r in recs if _ts(r) >= since]
    for row in out[1:]:
        req, n, first, last, ok, bad = row.split()
        v = [r for r in sel if r.get("requirement") == req and r["event"] == "violation"]
        m = [r for r in sel if r.get("requirement") == req and r["event"] == "mitigation"]
        assert (int(n), first, last) == (len(v), v[0]["ts"], v[-1]["ts"])
        assert (int(ok), int(bad)) == (sum(r["ok"] for r in m), sum(not r["ok"] for r in m))
    assert main(["logs", "--summary", "--json", "--failed", *files]) == 0
    rows = [json.loads(x) for x in _json(capsys)]
    assert [r["requirement"] for r in rows] == ["R0", "R1", "R2"]
    assert all(r["violations"] == 0 and r["mitigations_ok"] == 0 for r in rows)
    assert sum(r["mitigations_failed"] for r in rows) == sum(
        r["event"] == "mitigation" and not r["ok"] for r in recs
    )


def test_lines(rotated, capsys) -> None:
    assert main(["logs", "--json", "-n", "5", "--event", "violation", *rotated["files"]]) == 0
    want = [
        x
        for x, r in zip(rotated["lines"], rotated["recs"], strict=True)
        if r["event"] == "violation"
    ]
    assert _json(capsys) == want[-5:]
    assert main(["logs", "--json", "-n", "0", *rotated["files"]]) == 0
    assert _json(capsys) == []


def test_verify_finds_an_edited_and_a_removed_line(rotated, capsys) -> None:
    gz, one, live = rotated["files"]
    assert main(["logs", "--verify", live, gz, one]) == 0
    out = capsys.readouterr().out
    assert f"{live}:1: continues {one} (rotation link intact)" in out
    assert f"{one}:1: continues {gz} (rotation link intact)" in out
    lines = Path(one).read_text().splitlines(keepends=True)
    lines[41] = lines[41].replace("sRobot", "sRobon", 1)
    Path(one).write_text("".join(lines))
    text = Path(live).read_text().splitlines(keepends=True)
    del text[30]
    Path(live).write_text("".join(text))
    assert main(["logs", "--verify", gz, one, live]) == 1
    out = capsys.readouterr().out
    assert f"{one}:42: hash chain broken: line was edited" in out
    assert (
        f"{live}:31: hash chain broken: line was inserted, or a line before it was removed" in out
    )
    assert f"{gz}: 100 records, chain intact" in out


# ---------------------------------------------------------------- --follow


class _Follow:
    """``logs --follow`` as a subprocess; its stdout lines arrive on a queue."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "supervisor", "logs", *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def take(self, n: int, timeout: float = 10) -> list[str]:
        deadline = time.monotonic() + timeout
        out = []
        while len(out) < n:
            try:
                out.append(self.lines.get(timeout=max(0.01, deadline - time.monotonic())))
            except queue.Empty:
                raise AssertionError(f"got {out}, wanted {n} lines") from None
        return out

    def quiet(self, seconds: float = 0.6) -> bool:
        try:
            self.lines.get(timeout=seconds)
        except queue.Empty:
            return True
        return False

    def stop(self, sig: int) -> tuple[int, str]:
        self.proc.send_signal(sig)
        _, err = self.proc.communicate(timeout=10)
        return self.proc.returncode, err


@pytest.mark.slow
def test_follow_across_rotation(tmp_path: Path) -> None:
    live = tmp_path / "v.jsonl"
    log = ViolationLog(live, "sRobot", "ab" * 32, echo=False)
    try:
        for i in range(15):
            log.violation("A", text="t", formula="f", tick=i, inputs={})
            log.mitigation("A", action="stop", kind="publish", ok=True, latency_ms=1.0)
        f = _Follow("--follow", "--json", "--event", "violation", str(live))
        try:
            before = [json.loads(x)["tick"] for x in f.take(10)]
            assert before == list(range(5, 15))  # the last 10 selected, as tail -f
            assert f.quiet()
            log.violation("A", text="t", formula="f", tick=100, inputs={})
            log.mitigation("A", action="stop", kind="publish", ok=True, latency_ms=1.0)
            log.violation("B", text="t", formula="f", tick=101, inputs={})
            assert [json.loads(x)["tick"] for x in f.take(2)] == [100, 101]
            # logrotate's create mode: rename; records still go to the old file
            # until the daemon reopens the path
            live.rename(tmp_path / "v.jsonl.1")
            log.violation("A", text="t", formula="f", tick=102, inputs={})
            time.sleep(0.5)  # the follower sees the rename before the new file exists
            assert log.reopen()
            log.violation("A", text="t", formula="f", tick=103, inputs={})
            got = [json.loads(x) for x in f.take(2)]
            assert [r["tick"] for r in got] == [102, 103]
            assert got[1] == json.loads(live.read_text().splitlines()[1])  # as stored
            # and once more, the follower now on the second file
            live.rename(tmp_path / "v.jsonl.2")
            assert log.reopen()
            for tick in (104, 105):
                log.violation("C", text="t", formula="f", tick=tick, inputs={})
            assert [json.loads(x)["tick"] for x in f.take(2)] == [104, 105]
            assert f.quiet()
            code, err = f.stop(signal.SIGTERM)
            assert code == 0, err
            assert "Traceback" not in err
        finally:
            if f.proc.poll() is None:
                f.proc.kill()
    finally:
        log.close()


@pytest.mark.slow
def test_follow_table_and_ctrl_c(tmp_path: Path) -> None:
    live = tmp_path / "v.jsonl"
    with ViolationLog(live, "sRobot", "ab" * 32, echo=False) as log:
        log.supervisor("start")
        f = _Follow("-f", "--failed", "-n", "0", str(live))
        try:
            assert f.take(1)[0].split() == ["TIME", "EVENT", "REQUIREMENT", "DETAILS"]
            log.mitigation("A", action="stop", kind="publish", ok=True, latency_ms=1.0)
            log.mitigation("A", action="off", kind="ssh", ok=False, error="e", latency_ms=1.0)
            row = f.take(1)[0]
            assert "ssh:off FAILED (e)" in row
            assert f.quiet()
            code, err = f.stop(signal.SIGINT)
            assert code == 130, err
            assert "Traceback" not in err
        finally:
            if f.proc.poll() is None:
                f.proc.kill()


def test_follow_and_summary_exclusive(rotated, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        main(["logs", "--follow", "--summary", *rotated["files"]])
    assert e.value.code == 2
    assert "not allowed with" in capsys.readouterr().err
    assert os.path.exists(rotated["files"][0])
