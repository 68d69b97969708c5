"""supervisor.daemon.notify against real Unix datagram sockets (path and abstract)."""

from __future__ import annotations

import os
import socket
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from supervisor.daemon.notify import Notifier, watchdog_interval


def _bind(address: str) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(address)
    s.settimeout(5)
    return s


@pytest.fixture(params=["path", "abstract"])
def server(request, tmp_path: Path, monkeypatch) -> Iterator[socket.socket]:
    if request.param == "path":
        env = str(tmp_path / "notify.sock")
        sock = _bind(env)
    else:
        name = f"safety-supervisor-test-{uuid.uuid4().hex}"
        sock = _bind("\0" + name)
        env = "@" + name
    monkeypatch.setenv("NOTIFY_SOCKET", env)
    yield sock
    sock.close()


def _recv(sock: socket.socket) -> str:
    return sock.recv(4096).decode("utf-8")


def test_messages_arrive(server: socket.socket) -> None:
    n = Notifier()
    assert n.enabled
    assert n.ready()
    assert _recv(server) == "READY=1"
    assert n.status("monitoring 9 requirements")
    assert _recv(server) == "STATUS=monitoring 9 requirements"
    assert n.watchdog()
    assert _recv(server) == "WATCHDOG=1"
    before = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    assert n.reloading(status="reloading config")
    after = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    lines = _recv(server).split("\n")
    assert lines[0] == "RELOADING=1"
    assert lines[1].startswith("MONOTONIC_USEC=")
    assert before <= int(lines[1].split("=", 1)[1]) <= after
    assert lines[2] == "STATUS=reloading config"
    assert n.stopping()
    assert _recv(server) == "STOPPING=1"
    assert n.failures == 0


def test_ready_with_status_is_one_datagram_and_status_is_utf8_one_line(server) -> None:
    n = Notifier()
    n.ready(status="Überwachung\naktiv")
    assert _recv(server) == "READY=1\nSTATUS=Überwachung aktiv"


def test_no_notify_socket_sends_nothing(tmp_path: Path, monkeypatch) -> None:
    sock = _bind(str(tmp_path / "notify.sock"))
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = Notifier()
    assert not n.enabled
    assert n.ready() is False
    assert n.watchdog() is False
    assert n.stopping() is False
    sock.setblocking(False)
    with pytest.raises(BlockingIOError):
        sock.recv(4096)
    sock.close()


def test_unreachable_socket_never_raises_and_recovers(tmp_path: Path, monkeypatch, capfd) -> None:
    path = tmp_path / "notify.sock"
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    n = Notifier()
    assert n.ready() is False  # nobody listening yet
    assert n.watchdog() is False
    assert n.failures == 2
    err = capfd.readouterr().err
    assert err.count("systemd notify:") == 1  # reported once, not per ping
    sock = _bind(str(path))  # systemd's socket comes (back)
    assert n.watchdog() is True
    assert _recv(sock) == "WATCHDOG=1"
    sock.close()
    path.unlink()
    assert n.watchdog() is False  # connected socket gone: error, no exception
    sock = _bind(str(path))
    assert n.watchdog() is True  # reconnected
    assert _recv(sock) == "WATCHDOG=1"
    sock.close()


def test_unset_environment(server, monkeypatch) -> None:
    n = Notifier(unset_environment=True)
    assert "NOTIFY_SOCKET" not in os.environ
    assert n.ready()
    assert _recv(server) == "READY=1"


@pytest.mark.parametrize(
    ("usec", "pid", "expected"),
    [
        ("2000000", None, 1.0),
        ("30000000", "self", 15.0),
        ("2000000", "1", None),  # meant for another process
        (None, None, None),
        ("0", None, None),
        ("soon", None, None),
    ],
)
def test_watchdog_interval(monkeypatch, usec: str | None, pid: str | None, expected) -> None:
    for var, value in (("WATCHDOG_USEC", usec), ("WATCHDOG_PID", pid)):
        if value is None:
            monkeypatch.delenv(var, raising=False)
        else:
            monkeypatch.setenv(var, str(os.getpid()) if value == "self" else value)
    assert watchdog_interval() == expected
