"""``safety-supervisor reload`` returns when the new config is in force, and the
daemon speaks systemd's notify-reload protocol (docs/reference/commands.md,
``reload``; docs/reference/ros-interfaces.md, "Signals").

ROS tier: a real ``safety-supervisor run`` with a NOTIFY_SOCKET bound by the
test, reloaded by the real ``reload`` command and by SIGHUP, with a good and a
broken config.  Quick tier: the control socket's side (a reload's answer may
take longer than a reset's; the request's schema) and the command's arguments.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from ctlclient import ask

from supervisor.daemon import control
from supervisor.daemon.control import Caller, ControlServer

ROOT = Path(__file__).resolve().parents[3]


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------ quick tier


def test_a_reload_naming_a_requirement_is_a_bad_request() -> None:
    req = ControlServer._parse(b'{"command": "reload", "requirement": "r1"}', Caller(1, 0, 0))
    assert req.refused == "bad_request" and "reset" in req.detail, req
    assert ControlServer._parse(b'{"command": "reload"}', Caller(1, 0, 0)).refused is None


@pytest.fixture
def slow_loop(
    monkeypatch: pytest.MonkeyPatch, control_server: Callable[..., ControlServer]
) -> tuple[ControlServer, float]:
    """A control server whose loop answers a reload only after a reset's answer
    deadline has passed, as a reload that validates and compiles for seconds."""
    monkeypatch.setattr(control, "ANSWER_TIMEOUT_S", 0.3)
    delay = 0.9
    return control_server(delay=delay), delay


def test_a_reload_is_answered_after_a_resets_deadline(
    slow_loop: tuple[ControlServer, float],
) -> None:
    srv, delay = slow_loop
    # A reset past its deadline: the socket thread says busy (unchanged).
    assert ask(srv.path, b'{"command": "reset"}\n')["refused"] == "busy"
    t0 = time.monotonic()
    answer = ask(srv.path, b'{"command": "reload"}\n')
    assert answer == {"ok": True, "message": "reload done"}, answer
    assert time.monotonic() - t0 >= delay * 0.9


CLIENT = """
import socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
s.settimeout(10)
s.connect(sys.argv[1])
s.sendall(sys.argv[2].encode() + b"\\n")
data = b""
while not data.endswith(b"\\n"):
    chunk = s.recv(65536)
    if not chunk:
        break
    data += chunk
sys.stdout.write(data.decode())
"""


@pytest.mark.skipif(os.geteuid() != 0, reason="runs a client as another user (needs root)")
def test_an_operator_may_reset_but_not_reload(
    control_server: Callable[..., ControlServer],
) -> None:
    """A member of the operators' group (here nobody in nogroup) is let in by the
    socket's mode and may reset; only the daemon's user and root may reload."""
    srv = control_server(mode=0o711, group="nogroup", file="c.yaml")

    def as_nobody(command: str) -> dict[str, Any]:
        r = subprocess.run(
            ["/usr/bin/python3", "-c", CLIENT, srv.path, json.dumps({"command": command})],
            capture_output=True,
            text=True,
            timeout=30,
            user=65534,
            group=65534,
            extra_groups=[],
        )
        assert r.returncode == 0, r.stderr
        doc = json.loads(r.stdout)
        assert isinstance(doc, dict), doc
        return doc

    assert as_nobody("reset") == {"ok": True, "message": "reset done"}
    refused = as_nobody("reload")
    assert refused["refused"] == "permission" and "reload" in refused["message"], refused
    assert ask(srv.path, b'{"command": "reload"}\n')["ok"] is True  # root may


@pytest.mark.parametrize("command", ["reload", "reset"])
@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "soon"])
def test_a_bad_timeout_is_a_usage_error(command: str, value: str) -> None:
    r = cli(command, "--socket", "/nonexistent/c.sock", "--timeout", value, timeout=60)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "--timeout" in r.stderr and "internal error" not in r.stderr, r.stderr


def test_reload_without_a_daemon_is_one_line() -> None:
    with tempfile.TemporaryDirectory() as d:
        r = cli("reload", "--socket", f"{d}/c.sock", timeout=60)
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert len(r.stderr.splitlines()) == 1 and "no supervisor is running" in r.stderr, r.stderr


# ------------------------------------------------------------------ a real daemon


def _srobot(tmp: Path, tail: str) -> Path:
    from supervisor import data

    path = tmp / "srobot.yaml"
    path.write_text(data.example("srobot.yaml").read_text().rstrip("\n") + "\n" + tail)
    return path


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[Any, Path, Path]]:
    from rosutil import Daemon

    sock = tmp_path / "c.sock"
    config = _srobot(tmp_path, f"control:\n  socket: {sock}\n")
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=60)
        yield d, sock, config
    finally:
        d.close()


def _arrived(d: Any) -> list[str]:
    """The datagrams already in the notify socket, without waiting for more."""
    out = []
    while (datagram := d.recv(0)) is not None:
        out.append(datagram)
    return out


def _notify_reload(datagrams: list[str]) -> None:
    """RELOADING=1 with MONOTONIC_USEC= (of this clock) in one datagram, then READY=1."""
    lines = [dg.splitlines() for dg in datagrams]
    reloading = next(i for i, ls in enumerate(lines) if "RELOADING=1" in ls)
    usec = next(int(x.split("=", 1)[1]) for x in lines[reloading] if x.startswith("MONOTONIC_"))
    now = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    assert 0 < now - usec < 120_000_000, (usec, now)
    assert any("READY=1" in ls for ls in lines[reloading + 1 :]), datagrams


def _reloads(d: Any) -> list[dict[str, Any]]:
    return [r for r in d.records() if r.get("what") == "reload"]


@pytest.mark.ros
def test_reload_returns_with_the_new_config_in_force(daemon: tuple[Any, Path, Path]) -> None:
    d, sock, config = daemon
    _arrived(d)
    first = sha256(config)
    config.write_text(config.read_text() + "# edited by the test\n")
    new = sha256(config)
    assert new != first

    t0 = time.monotonic()
    r = cli("reload", "--socket", str(sock))
    took = time.monotonic() - t0
    assert r.returncode == 0, (r.stdout, r.stderr, d.explain())
    assert new in r.stdout and r.stderr == "", (r.stdout, r.stderr)
    # In force when it returned: the record is written, systemd was told READY=1.
    (rec,) = _reloads(d)
    assert rec["ok"] is True and rec["config_sha256"] == new, rec
    assert rec["via"] == "control_socket", rec
    assert [c["uid"] for c in rec["callers"]] == [os.getuid()], rec
    assert rec["duration_ms"] > 0, rec
    _notify_reload(_arrived(d))
    print(f"\nsafety-supervisor reload (good config): {took:.2f} s")

    # A broken config: one line with the file and line, exit 1, the old one stays.
    config.write_text(config.read_text().replace("OpState=3)\n", "OpState=)\n", 1))
    r = cli("reload", "--socket", str(sock))
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert r.stdout == "" and len(r.stderr.splitlines()) == 1, r.stderr
    assert f"{config}:" in r.stderr and "still running the previous config" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    rejected = _reloads(d)[-1]
    assert rejected["ok"] is False and rejected["config_sha256"] == new, rejected
    assert rejected["via"] == "control_socket" and f"{config}:" in rejected["why"], rejected
    _notify_reload(_arrived(d))
    assert d.proc.poll() is None, d.explain()
    d.terminate()
    stop = d.records()[-1]
    assert stop["what"] == "stop" and stop["reloads"] == 1, stop


@pytest.mark.ros
def test_sighup_speaks_notify_reload_for_good_and_broken_configs(
    daemon: tuple[Any, Path, Path],
) -> None:
    d, _sock, config = daemon
    original = config.read_text()
    for text, ok in (
        (original + "# edited\n", True),
        (original.replace("OpState=3)\n", "OpState=)\n", 1), False),
    ):
        config.write_text(text)
        before = len(_reloads(d))
        start = len(d.notifications)
        d.proc.send_signal(signal.SIGHUP)
        d.wait_notify("RELOADING=1", timeout=10)
        d.wait_notify("READY=1", timeout=60)
        _notify_reload([n for _, n in d.notifications[start:]])
        # The record is written before READY=1.
        recs = _reloads(d)
        assert len(recs) == before + 1, d.explain()
        assert recs[-1]["ok"] is ok and recs[-1]["via"] == "signal", recs[-1]
    d.terminate()


@pytest.mark.ros
def test_a_reload_asked_during_a_reload_reads_the_newest_config(
    daemon: tuple[Any, Path, Path],
) -> None:
    d, sock, config = daemon
    original = config.read_text()
    config.write_text(original + "# first\n")
    d.proc.send_signal(signal.SIGHUP)
    d.wait_notify("RELOADING=1", timeout=10)
    config.write_text(original + "# second\n")
    newest = sha256(config)
    r = cli("reload", "--socket", str(sock))
    assert r.returncode == 0 and newest in r.stdout, (r.stdout, r.stderr, d.explain())
    assert _reloads(d)[-1]["config_sha256"] == newest
    d.terminate()


def _next_statuses(d: Any, n: int, timeout: float = 30) -> list[str]:
    """The STATUS= texts of the next ``n`` periodic status datagrams (no READY=1)."""
    out: list[str] = []
    deadline = time.monotonic() + timeout
    while len(out) < n:
        assert time.monotonic() < deadline, d.explain()
        dg = d.recv(0.5)
        if dg is None or "READY=1" in dg.splitlines():
            continue
        out += [x.removeprefix("STATUS=") for x in dg.splitlines() if x.startswith("STATUS=")]
    return out


@pytest.mark.ros
def test_the_status_line_keeps_saying_a_reload_was_refused(
    daemon: tuple[Any, Path, Path],
) -> None:
    # `systemctl status` a while after a refused reload must still show the refusal:
    # the periodic STATUS= (every second) leads with it until a reload succeeds.
    d, _sock, config = daemon
    original = config.read_text()
    config.write_text(original.replace("OpState=3)\n", "OpState=)\n", 1))
    d.proc.send_signal(signal.SIGHUP)
    d.wait_notify("READY=1", timeout=60)
    for text in _next_statuses(d, 2):
        assert text.startswith(f"reload rejected: {config}:"), text
        assert "ticks=" in text, text  # and the usual line after it
    config.write_text(original + "# fixed\n")
    d.proc.send_signal(signal.SIGHUP)
    d.wait_notify("READY=1", timeout=60)
    for text in _next_statuses(d, 2):
        assert text.startswith("reloaded: monitoring 13 requirements | ticks="), text
    d.terminate()
