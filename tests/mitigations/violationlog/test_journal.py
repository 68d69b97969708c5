"""Records to journald's native socket with structured fields (docs/reference/log.md),
received on a Unix datagram socket bound here and decoded by the protocol."""

from __future__ import annotations

import json
import os
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from mitigations.violationlog.journal import SOCKET_ENV, JournalSender, encode, priority
from mitigations.violationlog.writer import ViolationLog


def decode(data: bytes) -> dict[str, str]:
    """One native-protocol entry: ``NAME=value\\n`` or ``NAME\\n`` + u64 LE length + value."""
    fields: dict[str, str] = {}
    pos = 0
    while pos < len(data):
        nl = data.index(b"\n", pos)
        eq = data.find(b"=", pos, nl)
        if eq >= 0:
            fields[data[pos:eq].decode()] = data[eq + 1 : nl].decode()
            pos = nl + 1
            continue
        name = data[pos:nl].decode()
        (size,) = struct.unpack("<Q", data[nl + 1 : nl + 9])
        fields[name] = data[nl + 9 : nl + 9 + size].decode()
        assert data[nl + 9 + size : nl + 10 + size] == b"\n"
        pos = nl + 10 + size
    return fields


class Journal:
    """A stand-in for journald's socket: entries as datagrams or memfds (SCM_RIGHTS),
    read by a thread as journald reads them (the kernel queues only a few datagrams:
    net.unix.max_dgram_qlen, 10 by default; systemd raises it to 512)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.05)
        self.memfds = 0
        self._got: list[dict[str, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, fds, _flags, _addr = socket.recv_fds(self.sock, 1 << 20, 1)
            except TimeoutError:
                continue
            if fds:
                self.memfds += 1
                with os.fdopen(fds[0], "rb") as f:
                    f.seek(0)  # the sender's offset is shared: journald reads from 0 too
                    data = f.read()
            self._got.append(decode(data))

    def entries(self, quiet: float = 0.3) -> list[dict[str, str]]:
        """Everything received, once nothing more came for ``quiet`` seconds."""
        n = -1
        while n != len(self._got):
            n = len(self._got)
            time.sleep(quiet)
        return list(self._got)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


@pytest.fixture
def journal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Journal]:
    j = Journal(tmp_path / "journal.sock")
    monkeypatch.setenv(SOCKET_ENV, str(j.path))
    yield j
    j.close()


def _lines(path: Path) -> dict[int, str]:
    return {json.loads(x)["seq"]: x for x in path.read_text().splitlines()}


def test_encode_binary_safe_form() -> None:
    data = encode([("A", "one"), ("B", "two\nlines"), ("C", "")])
    assert data == b"A=one\nB\n" + struct.pack("<Q", 9) + b"two\nlines\nC=\n"
    assert decode(data) == {"A": "one", "B": "two\nlines", "C": ""}


def test_writer_sends_records_with_fields(journal: Journal, tmp_path: Path, capfd) -> None:
    path = tmp_path / "v.jsonl"
    with ViolationLog(path, "sRobot", "ab" * 32) as log:
        log.supervisor("start", pid=1)
        log.violation("state_req103", text="t", formula="f", tick=42, inputs={"classifier": 1})
        log.mitigation("state_req103", action="stop", kind="publish", ok=True, latency_ms=0.4)
        log.mitigation(
            "state_req103",
            action="power_off",
            kind="ssh",
            ok=False,
            error="exit status 1:\nPermission denied",
            latency_ms=12.0,
        )
        log.supervisor("internal_error", where="w", error="e")
    got = list(journal.entries())
    lines = _lines(path)
    assert len(got) == len(lines) == 5
    for e in got:
        # the JSON record is the line in the file, chain hashes and all
        assert e["SAFETY_SUPERVISOR_RECORD"] == lines[int(e["SEQ"])]
        assert e["SYSLOG_IDENTIFIER"] == "safety-supervisor"
        assert e["CONFIG_SHA256"] == "ab" * 32
        assert e["COMPONENT"] == "sRobot"
    start, viol, ok, failed, internal = got
    assert (start["EVENT"], start["WHAT"], start["PRIORITY"]) == ("supervisor", "start", "6")
    assert "REQUIREMENT" not in start
    assert viol["EVENT"] == "violation"
    assert viol["REQUIREMENT"] == "state_req103"
    assert viol["PRIORITY"] == "4"
    assert viol["MESSAGE"] == "VIOLATION state_req103 tick=42 classifier=1"
    assert ok["PRIORITY"] == "6"
    assert failed["PRIORITY"] == "3"
    # a value with a newline travels in the length-prefixed form, intact
    assert failed["MESSAGE"] == (
        "MITIGATION state_req103 ssh:power_off FAILED (exit status 1:\nPermission denied) "
        "latency_ms=12.0 attempt=1"
    )
    assert internal["PRIORITY"] == "3"
    # stderr is not the journal here (a file): the echo stays
    assert "VIOLATION state_req103 tick=42" in capfd.readouterr().err


def test_no_echo_on_stderr_when_it_is_the_journal(
    journal: Journal, tmp_path: Path, capfd, monkeypatch: pytest.MonkeyPatch
) -> None:
    st = os.fstat(2)
    monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")  # as systemd sets it
    with ViolationLog(tmp_path / "v.jsonl", "sRobot", "ab" * 32) as log:
        log.violation("R", text="t", formula="f", tick=1, inputs={})
    assert [e["EVENT"] for e in journal.entries()] == ["violation"]
    assert capfd.readouterr().err == ""


def test_large_record_goes_through_a_memfd(journal: Journal, tmp_path: Path) -> None:
    path = tmp_path / "v.jsonl"
    big = {f"x{i}": "y" * 100 for i in range(5000)}  # ~0.5 MB, over the datagram limit
    with ViolationLog(path, "sRobot", "ab" * 32, echo=True) as log:
        log.violation("R", text="t", formula="f", tick=1, inputs=big)
    (e,) = journal.entries()
    assert journal.memfds == 1
    assert e["SAFETY_SUPERVISOR_RECORD"] == path.read_text().rstrip("\n")


def test_missing_socket_reported_once_and_monitoring_goes_on(
    tmp_path: Path, capfd, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(SOCKET_ENV, str(tmp_path / "nowhere.sock"))
    path = tmp_path / "v.jsonl"
    with ViolationLog(path, "sRobot", "ab" * 32) as log:
        for tick in range(3):
            assert log.violation("R", text="t", formula="f", tick=tick, inputs={})
    err = capfd.readouterr().err
    assert err.count("cannot send records to the journal socket") == 1
    assert err.count("VIOLATION R") == 3  # the records still reach stderr
    assert len(path.read_text().splitlines()) == 3


def test_off_and_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SOCKET_ENV, "off")
    with ViolationLog(tmp_path / "a.jsonl", "c", "0" * 64) as log:
        assert log._journald is None
    monkeypatch.delenv(SOCKET_ENV)
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    with ViolationLog(tmp_path / "b.jsonl", "c", "0" * 64) as log:
        assert log._journald is None  # not started by systemd: stderr only
    st = os.fstat(2)
    monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
    with ViolationLog(tmp_path / "c.jsonl", "c", "0" * 64, echo=False) as log:
        assert log._journald is None  # a silent log (replay, tests) is not sent
    with ViolationLog(tmp_path / "d.jsonl", "c", "0" * 64) as log:
        assert log._journald is not None
        assert log._journald.path == "/run/systemd/journal/socket"


@pytest.mark.parametrize(
    ("rec", "prio"),
    [
        ({"event": "violation"}, 4),
        ({"event": "mitigation", "ok": True}, 6),
        ({"event": "mitigation", "ok": False, "kind": "confirm"}, 3),
        ({"event": "reset"}, 6),
        ({"event": "supervisor", "what": "ready"}, 6),
        ({"event": "supervisor", "what": "reload", "ok": False}, 3),
        ({"event": "supervisor", "what": "records_lost"}, 3),
        ({"event": "supervisor", "what": "control_failed"}, 3),
        ({"event": "supervisor", "what": "input_stale"}, 4),
    ],
)
def test_priority(rec: dict[str, Any], prio: int) -> None:
    assert priority(rec) == prio


def test_sender_counts_failures(tmp_path: Path) -> None:
    s = JournalSender(str(tmp_path / "none.sock"))
    assert not s.send([("MESSAGE", "x")])
    assert (s.sent, s.failed) == (0, 1)
    assert s.error
    s.close()


@pytest.mark.ros
def test_daemon_sends_violation_to_journal(tmp_path: Path, robot_node: Any) -> None:
    """The real daemon, its env pointing at the socket here: a violating message
    becomes an entry with EVENT=violation and the record as in the file."""
    pytest.importorskip("rclpy")
    from rosutil import Daemon, Robot

    j = Journal(tmp_path / "journal.sock")
    d = Daemon(tmp_path, env={SOCKET_ENV: str(j.path)})
    try:
        d.wait_notify("READY=1", timeout=30)
        rec = Robot(robot_node).violate(
            d, lambda r: r["event"] == "violation", "a violation record"
        )
        d.terminate()
        entries = list(j.entries())
        viol = [e for e in entries if e["EVENT"] == "violation"]
        assert viol, entries
        lines = _lines(d.log)
        first = viol[0]
        assert first["REQUIREMENT"] == rec["requirement"]
        assert first["PRIORITY"] == "4"
        assert first["MESSAGE"].startswith(f"VIOLATION {rec['requirement']} tick=")
        assert first["SAFETY_SUPERVISOR_RECORD"] == lines[int(first["SEQ"])]
        assert json.loads(first["SAFETY_SUPERVISOR_RECORD"])["event"] == "violation"
        assert any(e.get("WHAT") == "ready" for e in entries)
        seqs = [int(e["SEQ"]) for e in entries]
        assert len(seqs) == len(set(seqs))  # none twice
        # stderr is a file here, not the journal: the echo stays
        assert "VIOLATION " in d.stderr.read_text()
    finally:
        d.close()
        j.close()
