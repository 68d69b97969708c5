"""Operator resets are authenticated, authorised and rate-limited.

Quick tier: the ``control:`` and ``ros.reset_service`` keys (one-line errors
with FILE:LINE, ``check`` warns about the ROS service), the control socket
itself (bound with the right mode, a leftover replaced, a live one refused,
bad requests answered), the rate limit and the refusal summary.

ROS tier (the daemon as a subprocess over real DDS): a reset through the
socket is accepted and recorded with the caller's uid and pid; a caller the
socket's permissions exclude is refused (as another uid, so only as root); the
ROS Trigger service is absent by default and present when enabled; a burst of
200 requests writes a handful of records.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from ctlclient import ask

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.config.model import ControlConfig
from supervisor.daemon.control import Caller, ControlServer, Refusals, ResetGate, open_control
from supervisor.names import RESET_SERVICE
from supervisor.tools.reset import request

ROOT = Path(__file__).resolve().parents[3]
NOBODY = 65534


def srobot_with(tmp: Path, tail: str) -> Path:
    from supervisor import data

    text = data.example("srobot.yaml").read_text()
    path = tmp / "srobot.yaml"
    path.write_text(text.rstrip("\n") + "\n" + tail)
    return path


def as_nobody(fn: Callable[[], str]) -> str:
    """``fn()`` in a forked child running as uid/gid 65534 (needs root)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            os.close(r)
            os.setgroups([])
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            out = fn()
        except BaseException as e:  # noqa: BLE001 - reported to the parent
            out = f"{type(e).__name__}: {e}"
        os.write(w, out.encode())
        os._exit(0)
    os.close(w)
    chunks = []
    while chunk := os.read(r, 65536):
        chunks.append(chunk)
    os.close(r)
    os.waitpid(pid, 0)
    return b"".join(chunks).decode()


# ------------------------------------------------------------------ config


@pytest.mark.parametrize(
    ("tail", "line", "words"),
    [
        ("control:\n  socket: /" + "x" * 120 + "\n", 2, "at most 107"),
        ("control:\n  group: 'no group'\n", 2, "not a group name"),
        ("control:\n  max_resets: 0\n", 2, "whole number >= 1"),
        ("control:\n  interval_ms: -5\n", 2, "must be positive"),
        ("control:\n  sockets: /tmp/x\n", 2, "did you mean 'socket'"),
        ("ros:\n  reset_service: yes please\n", 2, "true or false"),
    ],
)
def test_bad_control_keys_are_one_line_errors(
    tmp_path: Path, tail: str, line: int, words: str
) -> None:
    path = srobot_with(tmp_path, tail)
    first = len(path.read_text().splitlines()) - tail.count("\n") + 1
    with pytest.raises(UserError) as e:
        load_config(path)
    assert f"{path}:{first + line - 1}:" in str(e.value) and words in str(e.value), str(e.value)


def test_control_defaults_and_relative_socket(tmp_path: Path) -> None:
    cfg = load_config(srobot_with(tmp_path, ""))
    assert cfg.ros.reset_service is False
    assert (cfg.control.socket, cfg.control.max_resets, cfg.control.interval_ms) == (
        None,
        1,
        1000.0,
    )
    cfg = load_config(srobot_with(tmp_path, "control:\n  socket: c.sock\n  max_resets: 3\n"))
    assert cfg.control.socket == str(tmp_path / "c.sock") and cfg.control.max_resets == 3


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_check_warns_when_the_ros_reset_service_is_enabled(tmp_path: Path) -> None:
    def check(tail: str) -> str:
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", "check", str(srobot_with(tmp_path, tail))],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
        assert r.returncode == 0, r.stdout + r.stderr
        return r.stdout + r.stderr

    assert RESET_SERVICE not in check("")
    out = check("ros:\n  reset_service: true\n")
    warning = next(x for x in out.splitlines() if RESET_SERVICE in x)
    assert "ros.reset_service" in warning and "SROS2" in warning, warning


# ------------------------------------------------------------------ the socket, no ROS


@pytest.fixture
def server(control_server: Callable[..., ControlServer]) -> ControlServer:
    """A control socket whose loop answers every request as accepted, in a folder
    any user may traverse (tests/conftest.py's control_server)."""
    return control_server(
        lambda req: {"ok": True, "message": f"{req.command} by {req.caller.uid}"}, mode=0o755
    )


def test_socket_mode_and_answers(server: ControlServer) -> None:
    st = os.stat(server.path)
    assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o600
    assert ask(server.path) == {"ok": True, "message": f"reset by {os.getuid()}"}
    bad = ask(server.path, b"not json\n")
    assert bad["refused"] == "bad_request" and "not JSON" in bad["message"]
    bad = ask(server.path, b'{"command": "halt"}\n')
    assert bad["refused"] == "bad_request" and "'halt'" in bad["message"]
    bad = ask(server.path, b"x" * 5000 + b"\n")
    assert bad["refused"] == "bad_request"
    # The CLI's client side: the same answer.
    assert request(server.path, {"command": "reset"}, 5)["ok"] is True


def test_live_socket_refused_leftover_replaced(server: ControlServer, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="in use by another running supervisor"):
        open_control(ControlConfig(socket=server.path, file="cfg.yaml", socket_line=7))
    leftover = tmp_path / "old.sock"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(leftover))
    s.close()  # a socket file nobody listens on: a supervisor that was killed
    srv = open_control(ControlConfig(socket=str(leftover), file="cfg.yaml"))
    srv.close()
    assert not leftover.exists()  # close() removes its own socket
    plain = tmp_path / "plain"
    plain.write_text("not a socket")
    with pytest.raises(UserError) as e:
        open_control(ControlConfig(socket=str(plain), file="cfg.yaml", line=3, socket_line=4))
    assert str(e.value).startswith("cfg.yaml:4:") and "not a socket" in str(e.value)
    assert plain.read_text() == "not a socket"  # never removed


def test_unknown_group_is_an_error_at_its_line(tmp_path: Path) -> None:
    cfg = ControlConfig(
        socket=str(tmp_path / "c.sock"), group="no-such-group-xyz", file="cfg.yaml", group_line=9
    )
    with pytest.raises(UserError) as e:
        open_control(cfg)
    assert str(e.value).startswith("cfg.yaml:9: control.group 'no-such-group-xyz' does not exist")


def test_no_daemon_is_one_line(tmp_path: Path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", "reset", "--socket", str(tmp_path / "none.sock")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "no supervisor is running" in r.stderr, r.stderr


@pytest.mark.skipif(
    os.geteuid() != 0, reason="runs a client as another uid (os.setuid: needs root)"
)
def test_permission_refused_by_the_file_and_by_the_daemon(server: ControlServer) -> None:
    def cli() -> str:
        try:
            return json.dumps(request(server.path, {"command": "reset"}, 5))
        except UserError as e:
            return f"UserError: {e}"

    out = as_nobody(cli)  # mode 0600: the kernel refuses the connect
    assert out.startswith(f"UserError: {server.path}: permission denied: only user root"), out
    os.chmod(server.path, 0o666)  # the file lets everyone in: the daemon still refuses
    answer = json.loads(as_nobody(cli))
    assert answer["refused"] == "permission" and f"uid {NOBODY}" in answer["message"], answer


# ------------------------------------------------------------------ rate limit, summary


def test_reset_gate_admits_n_per_interval() -> None:
    gate, ms = ResetGate(), 1_000_000
    got = [gate.admit(t * ms, 2, 1000 * ms) for t in (0, 1, 2, 999, 1000, 1001, 1002)]
    assert got == [True, True, False, False, True, True, False]


def test_refusals_reported_once_per_interval() -> None:
    r, ms = Refusals(), 1_000_000
    for _ in range(500):
        r.add("rate", "alice")
    first = r.due(0, 1000 * ms)
    assert first == {"refused": {"rate": 500}, "callers": ["alice"], "interval_ms": 1000.0}
    r.add("permission", "uid 7")
    assert r.due(500 * ms, 1000 * ms) is None  # not again within the interval
    assert r.due(1000 * ms, 1000 * ms) == {
        "refused": {"permission": 1},
        "callers": ["uid 7"],
        "interval_ms": 1000.0,
    }
    assert r.due(5000 * ms, 1000 * ms) is None  # nothing refused: nothing to say


# ------------------------------------------------------------------ the daemon (ROS)


def _daemon(tmp_path: Path, tail: str) -> Any:
    from rosutil import Daemon

    d = Daemon(tmp_path, srobot_with(tmp_path, tail))
    d.wait_notify("READY=1", timeout=30)
    return d


def _operator_resets(d: Any) -> list[dict[str, Any]]:
    return [r for r in d.records() if r["event"] == "reset" and r["requirement"] == "*"]


@pytest.mark.ros
def test_socket_reset_recorded_with_the_caller(tmp_path: Path) -> None:
    sock = tmp_path / "c.sock"
    d = _daemon(tmp_path, f"control:\n  socket: {sock}\n")
    try:
        assert stat.S_IMODE(os.stat(sock).st_mode) == 0o600
        proc = subprocess.Popen(
            [sys.executable, "-m", "supervisor", "reset", "--socket", str(sock)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 and out.strip() == "all requirements reset", out + err
        (rec,) = _operator_resets(d)
        assert rec["via"] == "control_socket" and rec["refused"] == []
        assert rec["caller"]["uid"] == os.getuid() and rec["caller"]["pid"] == proc.pid
        d.terminate()
        assert not sock.exists()  # removed at exit: a later reset says "not running"
    finally:
        d.close()


@pytest.mark.ros
def test_burst_of_resets_writes_a_handful_of_records(tmp_path: Path) -> None:
    sock = tmp_path / "c.sock"
    d = _daemon(tmp_path, f"control:\n  socket: {sock}\n")
    try:
        answers = [ask(sock) for _ in range(200)]
        accepted = sum(a["ok"] for a in answers)
        rate = sum(a.get("refused") == "rate" for a in answers)
        assert accepted >= 1 and accepted + rate == 200, answers[:5]

        def summarised() -> int:
            return sum(
                r["refused"].get("rate", 0)
                for r in d.records()
                if r["event"] == "supervisor" and r["what"] == "reset_refused"
            )

        from rosutil import wait_until

        wait_until("every refusal in a summary", lambda: summarised() == rate, 10, d.explain)
        summaries = [r for r in d.records() if r.get("what") == "reset_refused"]
        # 1 per second: the burst lasts a few seconds at most.
        assert len(_operator_resets(d)) == accepted <= 5, accepted
        assert len(summaries) <= 5, summaries
        d.terminate()
    finally:
        d.close()


@pytest.mark.ros
def test_ros_reset_service_only_when_enabled(tmp_path: Path, robot_node: Any) -> None:
    from rosutil import wait_until

    def services(node: str) -> list[str]:
        try:
            found = robot_node.get_service_names_and_types_by_node(node, "/")
        except Exception:  # noqa: BLE001 - the node is not discovered yet
            return []
        return [n for n, _ in found]

    def services_once_discovered(node: str) -> list[str]:
        """The daemon's services, once its parameter services (rclpy's, always
        there) are discovered: any service of the node would be by then."""
        return wait_until(
            "the daemon's node and its services to be discovered",
            lambda: (s := services(node)) and f"/{node}/get_parameters" in s and s,
            20,
        )

    # A node name of its own for each daemon: a stopped daemon stays in the graph
    # until its DDS lease expires (docs/reference/faults.md, "Stop"), so an earlier
    # daemon's services must not be taken for this one's.
    for present in (False, True):
        node = f"ss_{'on' if present else 'off'}_{os.getpid()}"
        sub = tmp_path / node
        sub.mkdir()
        ros = f"ros:\n  node_name: {node}\n" + ("  reset_service: true\n" if present else "")
        d = _daemon(sub, ros + f"control:\n  socket: {sub / 'c.sock'}\n")
        try:
            found = services_once_discovered(node)
            if present:  # discovered with the node's other services, or soon after
                wait_until(RESET_SERVICE, lambda n=node: RESET_SERVICE in services(n), 10)
            else:
                assert RESET_SERVICE not in found, found
            d.terminate()
        finally:
            d.close()


# ------------------------------------------------------------------ the service


def test_unit_and_installer_give_operators_the_socket(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import grp

    from supervisor import data
    from supervisor.names import OPERATORS_GROUP
    from supervisor.tools import install

    unit = data.systemd_unit().read_text()
    lines = {x.partition("=")[0]: x.partition("=")[2] for x in unit.splitlines() if "=" in x}
    assert lines["RuntimeDirectory"] == "safety-supervisor"
    assert lines["SupplementaryGroups"] == OPERATORS_GROUP
    assert "PrivateUsers" not in lines  # it would make every operator uid 65534
    python = tmp_path / "bin" / "python3.11"  # outside a home (never run by a dry run)
    python.parent.mkdir()
    python.write_text("#!/bin/sh\nexit 1\n")
    python.chmod(0o755)
    rc = install.main(
        [
            "--dry-run",
            "--python",
            str(python),
            "--prefix",
            str(tmp_path / "opt"),
            "--unit-dir",
            str(tmp_path / "units"),
            "--logrotate-dir",
            str(tmp_path / "rot"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    try:
        grp.getgrnam(OPERATORS_GROUP)
        assert f"group {OPERATORS_GROUP} exists" in out, out
    except KeyError:
        assert f"$ groupadd --system {OPERATORS_GROUP}" in out, out
    assert f"usermod -aG {OPERATORS_GROUP} USER" in out, out


def test_a_request_may_name_one_requirement_and_who_relays_it() -> None:
    caller = Caller(pid=1, uid=0, gid=0)
    req = ControlServer._parse(
        b'{"command": "reset", "requirement": "r1", "via": "ui", "client": "10.0.0.5"}', caller
    )
    assert (req.refused, req.requirement, req.via, req.client) == (None, "r1", "ui", "10.0.0.5")
    bad = ControlServer._parse(b'{"command": "reset", "requirement": 3}', caller)
    assert bad.refused == "bad_request" and "requirement" in bad.detail
