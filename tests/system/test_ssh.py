"""The ssh mitigation against a real OpenSSH sshd on 127.0.0.1 (tests/support/sshd.py): no mocks."""

from __future__ import annotations

import os
import shlex
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest
from sshd import Sshd, free_port, keygen, known_hosts_line

from mitigations.actions.base import Outcome, backoff_delay
from mitigations.actions.ssh import SshAction, preflight
from mitigations.settings import SettingsError, SshSettings, parse_settings


class Recorder:
    """on_attempt callback: every outcome with the time it arrived."""

    def __init__(self) -> None:
        self.outcomes: list[Outcome] = []
        self.times: list[float] = []

    def __call__(self, out: Outcome) -> None:
        self.outcomes.append(out)
        self.times.append(time.monotonic())


def settings(params: dict) -> SshSettings:
    """``ssh:`` settings as the config loader makes them (validated)."""
    s = parse_settings("ssh", params)
    assert isinstance(s, SshSettings)
    return s


def ssh_action(name: str, params: dict) -> SshAction:
    return SshAction(name, settings(params))


def run(action: SshAction, cancel: threading.Event | None = None) -> tuple[Outcome, Recorder]:
    rec = Recorder()
    out = action.run(cancel or threading.Event(), rec)
    return out, rec


@pytest.mark.sshd
def test_command_runs_on_the_server_and_reports_exit_status(sshd: Sshd, tmp_path: Path) -> None:
    marker = tmp_path / "touched"
    params = sshd.params(f"touch {shlex.quote(str(marker))}")
    assert preflight(settings(params)) == []
    action = ssh_action("power_off", params)
    t0 = time.monotonic()
    out, rec = run(action)
    elapsed = time.monotonic() - t0
    assert out.ok, out.error
    assert out.error is None
    assert out.attempt == 1
    assert out.detail["exit_status"] == 0
    assert marker.exists()
    assert rec.outcomes == [out]
    assert (action.name, action.kind) == ("power_off", "ssh")
    print(f"ssh round trip (connect, auth, command, exit status): {elapsed * 1000:.0f} ms")


@pytest.mark.sshd
def test_nonzero_exit_status_fails_with_status_and_stderr_not_retried(sshd: Sshd) -> None:
    action = ssh_action("p", sshd.params("echo 'disk on fire' >&2; exit 3", retries=3))
    out, rec = run(action)
    assert not out.ok
    assert out.detail["exit_status"] == 3
    assert "disk on fire" in out.detail["stderr"]
    assert "command exited with status 3: disk on fire" in out.error
    assert out.error.startswith(f"ssh {sshd.user}@127.0.0.1:{sshd.port}: ")
    assert "\n" not in out.error
    # The command ran; running it again is not this action's call.
    assert [o.attempt for o in rec.outcomes] == [1]


@pytest.mark.sshd
def test_wrong_host_key_is_refused_and_not_retried(sshd: Sshd, tmp_path: Path) -> None:
    impostor = keygen(tmp_path / "other_host_key")
    known = tmp_path / "known_hosts_wrong"
    known.write_text(known_hosts_line("127.0.0.1", sshd.port, impostor))
    marker = tmp_path / "must_not_exist"
    action = ssh_action(
        "p", sshd.params(f"touch {marker}", known_hosts=str(known), retries=3, backoff_s=0.01)
    )
    out, rec = run(action)
    assert not out.ok
    assert "host key" in out.error and "does not match" in out.error
    assert "refused" in out.error and "not retried" in out.error
    assert f"[127.0.0.1]:{sshd.port}" in out.error
    assert len(rec.outcomes) == 1 and out.attempt == 1
    assert not marker.exists()
    # The file is untouched: a wrong key is never replaced or added.
    assert known.read_text() == known_hosts_line("127.0.0.1", sshd.port, impostor)


@pytest.mark.sshd
def test_empty_known_hosts_is_refused(sshd: Sshd, tmp_path: Path) -> None:
    known = tmp_path / "known_hosts_empty"
    known.write_text("")
    marker = tmp_path / "must_not_exist"
    params = sshd.params(f"touch {marker}", known_hosts=str(known), retries=3)
    assert any("has no key for" in p for p in preflight(settings(params)))
    action = ssh_action("p", params)
    out, rec = run(action)
    assert not out.ok
    assert f"host key for [127.0.0.1]:{sshd.port} not in {known} (refused" in out.error
    assert len(rec.outcomes) == 1
    assert not marker.exists()
    assert known.read_text() == ""  # never auto-added


@pytest.mark.sshd
def test_host_key_under_another_port_does_not_vouch(sshd: Sshd, tmp_path: Path) -> None:
    # The right key, filed under plain 127.0.0.1 (port 22): OpenSSH and we look up [host]:port.
    known = tmp_path / "known_hosts_port22"
    known.write_text(known_hosts_line("127.0.0.1", 22, Path(f"{sshd.host_key}.pub").read_text()))
    out, _ = run(ssh_action("p", sshd.params("true", known_hosts=str(known))))
    assert not out.ok and "not in" in out.error


@pytest.mark.sshd
def test_sshd_not_running_is_retried_with_growing_backoff(tmp_path: Path, sshd: Sshd) -> None:
    port = free_port()  # nothing listens here
    backoff = 0.1
    action = ssh_action(
        "p", {**sshd.params("true"), "port": port, "retries": 4, "backoff_s": backoff}
    )
    t0 = time.monotonic()
    out, rec = run(action)
    elapsed = time.monotonic() - t0
    assert not out.ok
    assert [o.attempt for o in rec.outcomes] == [1, 2, 3, 4]
    for o in rec.outcomes:
        assert not o.ok
        assert o.error == f"ssh {sshd.user}@127.0.0.1:{port}: connection refused"
    waits = [backoff_delay(backoff, n) for n in (1, 2, 3)]
    assert waits == [0.1, 0.2, 0.4]
    assert elapsed >= sum(waits)
    gaps = [b - a for a, b in zip(rec.times, rec.times[1:], strict=False)]
    for gap, wait in zip(gaps, waits, strict=True):
        assert gap >= wait


def test_backoff_is_capped() -> None:
    assert [backoff_delay(0.5, n) for n in range(1, 7)] == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0]


@pytest.mark.sshd
def test_cancel_stops_the_retry_loop(sshd: Sshd) -> None:
    # 10 attempts at 1, 2, 4, 5, 5, ... s apart would take over half a minute.
    action = ssh_action(
        "p", {**sshd.params("true"), "port": free_port(), "retries": 10, "backoff_s": 1.0}
    )
    cancel = threading.Event()
    timer = threading.Timer(0.3, cancel.set)
    timer.start()
    t0 = time.monotonic()
    out, rec = run(action, cancel)
    elapsed = time.monotonic() - t0
    timer.join()
    assert not out.ok
    assert "retries cancelled by shutdown" in out.error
    assert len(rec.outcomes) == 1
    assert elapsed < 0.3 + 0.5


@pytest.mark.sshd
def test_cancelled_before_start_still_reports(sshd: Sshd, tmp_path: Path) -> None:
    marker = tmp_path / "must_not_exist"
    cancel = threading.Event()
    cancel.set()
    out, rec = run(ssh_action("p", sshd.params(f"touch {marker}")), cancel)
    assert not out.ok and "cancelled" in out.error
    assert rec.outcomes == [out]
    assert not marker.exists()


@pytest.mark.sshd
def test_silent_server_times_out_in_handshake_and_is_retried(sshd: Sshd) -> None:
    # Accepts TCP connections and never says a word: the banner timeout must fire.
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        action = ssh_action(
            "p",
            {
                **sshd.params("true"),
                "port": port,
                "connect_timeout_s": 0.5,
                "retries": 2,
                "backoff_s": 0.05,
            },
        )
        t0 = time.monotonic()
        out, rec = run(action)
        elapsed = time.monotonic() - t0
    assert len(rec.outcomes) == 2
    assert "timed out after 0.5 s in the SSH handshake" in out.error
    assert 2 * 0.5 + 0.05 <= elapsed < 5


@pytest.mark.sshd
def test_unknown_user_key_fails_authentication(sshd: Sshd, tmp_path: Path) -> None:
    stranger = tmp_path / "stranger_key"
    keygen(stranger)
    marker = tmp_path / "must_not_exist"
    params = sshd.params(f"touch {marker}", key=str(stranger), retries=3)
    assert (
        preflight(settings(params)) == []
    )  # a fine key; only the server can say it is not authorized
    action = ssh_action("p", params)
    out, rec = run(action)
    assert not out.ok
    assert f"authentication failed (key {stranger}" in out.error
    assert len(rec.outcomes) == 1
    assert not marker.exists()


@pytest.mark.sshd
def test_command_timeout(sshd: Sshd) -> None:
    action = ssh_action("p", sshd.params("sleep 30", command_timeout_s=1, retries=3))
    t0 = time.monotonic()
    out, rec = run(action)
    elapsed = time.monotonic() - t0
    assert not out.ok
    assert "command timed out after 1 s" in out.error
    assert len(rec.outcomes) == 1  # the command may be running: not started twice
    assert 1.0 <= elapsed < 5.0


@pytest.mark.sshd
def test_chatty_command_output_is_drained_and_tail_kept(sshd: Sshd) -> None:
    # 4 MB is more than paramiko's 2 MB receive window: unread, the command would stall.
    cmd = "head -c 4000000 /dev/zero | tr '\\0' x; echo; echo the-end >&2; exit 0"
    out, _ = run(ssh_action("p", sshd.params(cmd, command_timeout_s=10)))
    assert out.ok, out.error
    assert out.detail["stderr"] == "the-end\n"
    assert len(out.detail["stdout"]) == 500


@pytest.mark.sshd
def test_forced_command_in_authorized_keys(sshd: Sshd, tmp_path: Path) -> None:
    """The documented robot-side setup: whatever the client asks, the forced command runs."""
    forced, asked = tmp_path / "forced", tmp_path / "asked"
    pub = Path(f"{sshd.user_key}.pub").read_text().strip()
    sshd.authorized_keys.write_text(f'restrict,command="touch {forced}" {pub}\n')
    out, _ = run(ssh_action("p", sshd.params(f"touch {asked}")))
    assert out.ok, out.error
    assert forced.exists() and not asked.exists()


def test_check_reports_file_problems_without_connecting(tmp_path: Path) -> None:
    key = tmp_path / "id"
    keygen(key)
    known = tmp_path / "known_hosts"
    known.write_text(known_hosts_line("robot", 2222, Path(f"{key}.pub").read_text()))
    base = {"host": "robot", "port": 2222, "user": "u", "command": "true"}
    assert preflight(settings({**base, "key": str(key), "known_hosts": str(known)})) == []

    def problems(**changes: object) -> str:
        params = {**base, "key": str(key), "known_hosts": str(known), **changes}
        found = preflight(settings(params))
        assert len(found) == 1, found
        return found[0]

    assert "No such file" in problems(key=str(tmp_path / "missing"))
    assert "not a usable private key" in problems(key=str(known))
    assert "not a usable private key" in problems(key=f"{key}.pub")
    assert "No such file" in problems(known_hosts=str(tmp_path / "nope"))
    assert "has no key for robot (" in problems(port=22)  # filed under [robot]:2222 only
    loose = tmp_path / "loose"
    loose.write_bytes(key.read_bytes())
    os.chmod(loose, 0o644)
    assert "chmod 600" in problems(key=str(loose))
    locked = tmp_path / "locked"
    keygen(locked)
    subprocess.run(
        ["ssh-keygen", "-q", "-p", "-P", "", "-N", "secret", "-f", str(locked)], check=True
    )
    assert "passphrase" in problems(key=str(locked))


@pytest.mark.sshd
def test_run_never_raises_on_a_broken_key(sshd: Sshd, tmp_path: Path) -> None:
    out, rec = run(ssh_action("p", sshd.params("true", key=str(tmp_path / "missing"))))
    assert not out.ok and "cannot read key" in out.error
    assert len(rec.outcomes) == 1


@pytest.mark.parametrize(
    "bad", [{"port": 0}, {"port": "22"}, {"retries": 0}, {"connect_timeout_s": -1}]
)
def test_bad_settings_are_rejected(bad: dict) -> None:
    params = {"host": "h", "user": "u", "key": "k", "known_hosts": "kh", "command": "true"}
    with pytest.raises(SettingsError) as e:
        parse_settings("ssh", {**params, **bad})
    assert e.value.setting == next(iter(bad))
