"""``safety-supervisor status``: the running daemon's state through its control
socket, exit 3 when no supervisor answers (docs/reference/commands.md, "status").

Quick tier: no daemon (exit 3, one line), a socket that answers nonsense (exit 1,
one line).  ROS tier: a real ``safety-supervisor run`` of the sRobot example,
asked before and after a violation, in words and as JSON.
"""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[3]


def status(*args: object) -> subprocess.CompletedProcess[str]:
    """The installed command's exit path, as systemctl's callers see it."""
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "status", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def test_no_supervisor_exits_3_in_one_line(tmp_path: Path) -> None:
    r = status("--socket", tmp_path / "none.sock")
    assert r.returncode == 3, r
    assert r.stdout.count("\n") == 1 and "no supervisor is running here" in r.stdout, r
    assert r.stderr == "", r


@pytest.fixture
def liar(tmp_path: Path) -> Iterator[Path]:
    """A socket whose program answers ok with a status of the wrong shape."""
    path = tmp_path / "liar.sock"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(str(path))
    srv.listen(1)

    def serve() -> None:
        conn, _ = srv.accept()
        with conn:
            conn.recv(4096)
            answer = {"ok": True, "message": "running", "status": {"pid": "\x1b[2Jx"}}
            conn.sendall(json.dumps(answer).encode() + b"\n")

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    yield path
    t.join(10)
    srv.close()


def test_an_answer_not_understood_is_one_line_exit_1(liar: Path) -> None:
    r = status("--socket", liar)
    assert r.returncode == 1, r
    assert r.stderr.count("\n") == 1 and "status answer is not understood" in r.stderr, r
    assert "\x1b" not in r.stdout + r.stderr


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[Any, Path, Path]]:
    from rosutil import Daemon, variant

    sock = tmp_path / "c.sock"
    config = variant(
        tmp_path, ("logging:", f"control:\n  socket: {sock}\nlogging:"), record_only=True
    )
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=60)
        yield d, sock, config
    finally:
        d.close()


@pytest.mark.ros
def test_status_of_a_running_daemon(daemon: tuple[Any, Path, Path]) -> None:
    from rosutil import Robot, ros_node

    d, sock, config = daemon
    r = status("--socket", sock, "--json")
    assert r.returncode == 0, r.stdout + r.stderr + d.explain()
    doc = json.loads(r.stdout)
    assert doc["config_sha256"] == hashlib.sha256(config.read_bytes()).hexdigest()
    assert doc["pid"] == d.proc.pid and doc["uptime_s"] > 0 and doc["recording"] is False
    ids = [r["id"] for r in doc["requirements"]]
    assert "state_req103" in ids and len(ids) == 13, ids
    assert all(r["last_violation"] is None for r in doc["requirements"]), doc
    with ros_node() as node:
        robot = Robot(node)
        found = robot.violate(
            d, lambda x: x.get("event") == "violation", "a violation of the sRobot"
        )
    doc = json.loads(status("--socket", sock, "--json").stdout)
    row = next(r for r in doc["requirements"] if r["id"] == found["requirement"])
    assert row["violations"] >= 1 and row["last_violation"] is not None, row
    assert doc["violations"] >= 1 and doc["ticks"] > 0, doc
    words = status("--socket", sock)
    assert words.returncode == 0, words
    text = words.stdout
    assert "Active: active (running)" in text and doc["config_sha256"] in text, text
    line = next(x for x in text.splitlines() if x.startswith(found["requirement"] + " "))
    assert row["last_violation"] in line and f"tick {row['last_tick']}" in line, line
    assert d.proc.poll() is None, d.explain()
