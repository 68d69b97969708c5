"""The halt path's entry to the log (ViolationLog.violation_row, docs/reference/log.md#the-halt-path)
against the policies' way (violation_from) where writing goes wrong: a failed fsync, a
short write then an error, and where echo and tee run.  Each case the same on both."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

import mitigations.violationlog.writer as w
from mitigations.violationlog.writer import Row, ViolationLog


def _one(log: ViolationLog, way: str) -> bool:
    tpl = log.violation_template("R1", text="t", formula="f")
    r = Row.of({"tick": 7, "x": 1})
    if way == "row":
        ok = log.violation_row(tpl, row=r, recent=[r], stale=[], policy_state="{}")
        assert ok is not None
        return ok
    return log.violation_from(tpl, tick=7, inputs={"x": 1}, recent=[r], stale=[], policy_state={})


@pytest.mark.parametrize("way", ["from", "row"])
def test_a_failed_fsync_is_not_a_record_not_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], way: str
) -> None:
    """A record in the file whose fsync failed is said so, not reported as not
    written nor counted as a failed write."""
    log = ViolationLog(tmp_path / "v.log", "c", "00", echo=False, durability="before_action")

    def eio(fd: int) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(w.os, "fsync", eio)
    assert _one(log, way) is False  # both: written, not fsynced
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert "written but not fsynced" in err
    assert "NOT written" not in err, err
    assert log.failed_writes == 0
    log.close()
    assert (tmp_path / "v.log").read_bytes().count(b"\n") == 1


@pytest.mark.parametrize("way", ["from", "row"])
def test_a_write_error_is_reported_and_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], way: str
) -> None:
    """A short write then an error: the torn fragment stays in the file as a line of
    its own, and the error that left it is reported and counted, even when the retry
    writes the record."""
    log = ViolationLog(tmp_path / "v.log", "c", "00", echo=False, retry_interval_s=3600)
    real, n = w.os.write, [0]

    def flaky(fd: int, data: bytes) -> int:
        n[0] += 1
        if n[0] == 1:
            return real(fd, data[:20])  # a short write
        if n[0] == 2:
            raise OSError(5, "Input/output error")
        return real(fd, data)

    monkeypatch.setattr(w.os, "write", flaky)
    _one(log, way)
    log.retry()
    monkeypatch.undo()
    err = capsys.readouterr().err
    log.close()
    lines = (tmp_path / "v.log").read_bytes().splitlines()
    assert len(lines) == 2 and not lines[0].endswith(b"}")  # the torn fragment, then the record
    assert "cannot write: Input/output error" in err, err  # the fragment is explained
    assert log.failed_writes == 1


@pytest.mark.parametrize("way", ["from", "row"])
def test_echo_and_tee_are_not_done_under_the_lock(tmp_path: Path, way: str) -> None:
    """Echo and tee never run holding the lock every worker's mitigation record
    waits for, on either way."""
    held: list[tuple[str, bool]] = []

    class Echo(io.StringIO):
        def write(self, s: str) -> int:
            held.append(("echo", log._lock._is_owned()))  # type: ignore[attr-defined]
            return super().write(s)

    log = ViolationLog(tmp_path / "v.log", "c", "00", echo=Echo())
    log.tee = lambda _text: held.append(("tee", log._lock._is_owned()))  # type: ignore[attr-defined]
    log.supervisor("start")  # no flush() after it: the chain's last hash is not made yet
    held.clear()
    _one(log, way)
    log.close()
    assert held and not any(h for _, h in held), held
