"""The command mitigation with real processes: no mocks."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import pytest

from mitigations.actions.base import Outcome
from mitigations.actions.command import CommandAction
from mitigations.settings import CommandSettings, SettingsError, parse_settings


def command_action(params: dict) -> CommandAction:
    """A CommandAction from ``command:`` settings as the config loader makes them."""
    settings = parse_settings("command", params)
    assert isinstance(settings, CommandSettings)
    return CommandAction("cmd", settings)


def run(params: dict, cancel: threading.Event | None = None) -> tuple[Outcome, list[Outcome]]:
    seen: list[Outcome] = []
    out = command_action(params).run(cancel or threading.Event(), seen.append)
    return out, seen


def test_ok_and_output_tail(tmp_path: Path) -> None:
    marker = tmp_path / "touched"
    out, seen = run({"argv": ["touch", str(marker)]})
    assert out.ok and out.error is None
    assert out.detail["exit_status"] == 0
    assert marker.exists()
    assert seen == [out] and out.attempt == 1


def test_exit_status_with_stderr_tail() -> None:
    script = "import sys; print('x' * 2000, file=sys.stderr); print('boom', file=sys.stderr); sys.exit(3)"
    out, seen = run({"argv": [sys.executable, "-c", script]})
    assert not out.ok
    assert out.detail["exit_status"] == 3
    assert out.detail["stderr"].endswith("boom\n") and len(out.detail["stderr"]) == 500
    assert out.error.startswith(f"command {sys.executable}: exit status 3: ")
    assert out.error.endswith("boom") and "\n" not in out.error
    assert len(seen) == 1


def test_not_found_is_not_retried() -> None:
    out, seen = run({"argv": ["no-such-program-anywhere", "x"], "retries": 3})
    assert not out.ok
    assert out.error == "command no-such-program-anywhere: executable not found"
    assert len(seen) == 1


def test_not_executable(tmp_path: Path) -> None:
    script = tmp_path / "script"
    script.write_text("#!/bin/sh\nexit 0\n")
    os.chmod(script, 0o644)
    out, _ = run({"argv": [str(script)]})
    assert not out.ok and "permission denied" in out.error


def test_timeout_kills_the_process_group(tmp_path: Path) -> None:
    # The child starts a grandchild; both must be gone after the timeout.
    pidfile = tmp_path / "pid"
    argv = ["sh", "-c", f"sleep 30 & echo $! > {pidfile}; wait"]
    t0 = time.monotonic()
    out, _ = run({"argv": argv, "timeout_s": 0.5})
    elapsed = time.monotonic() - t0
    assert not out.ok
    assert out.error == "command sh: timed out after 0.5 s (process killed)"
    assert 0.5 <= elapsed < 3
    grandchild = int(pidfile.read_text())
    for _ in range(100):  # the kill is asynchronous; a zombie is reaped by init
        if not Path(f"/proc/{grandchild}").exists() or "Z" in _state(grandchild):
            break
        time.sleep(0.01)
    else:
        pytest.fail(f"grandchild {grandchild} survived the timeout")


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "Z"


def test_no_shell_interpretation() -> None:
    out, _ = run({"argv": ["echo", "$HOME;", "*", "`id`"]})
    assert out.ok
    assert out.detail["stdout"] == "$HOME; * `id`\n"


def test_minimal_environment_plus_env() -> None:
    os.environ["SAFETY_SUPERVISOR_TEST_LEAK"] = "leaked"
    try:
        out, _ = run({"argv": ["env"], "env": {"ROBOT": "srobot"}})
    finally:
        del os.environ["SAFETY_SUPERVISOR_TEST_LEAK"]
    lines = set(out.detail["stdout"].splitlines())
    assert "ROBOT=srobot" in lines
    assert not any(line.startswith("SAFETY_SUPERVISOR_TEST_LEAK=") for line in lines)
    assert any(line.startswith("PATH=") for line in lines)


def test_retries_with_backoff_then_success(tmp_path: Path) -> None:
    # Fails twice, then succeeds: a counter file outlives each attempt.
    counter = tmp_path / "n"
    script = (
        "import pathlib, sys\n"
        f"p = pathlib.Path({str(counter)!r})\n"
        "n = int(p.read_text()) + 1 if p.exists() else 1\n"
        "p.write_text(str(n))\n"
        "sys.exit(0 if n >= 3 else 1)\n"
    )
    t0 = time.monotonic()
    out, seen = run({"argv": [sys.executable, "-c", script], "retries": 5, "backoff_s": 0.1})
    elapsed = time.monotonic() - t0
    assert out.ok and out.attempt == 3
    assert [(o.attempt, o.ok) for o in seen] == [(1, False), (2, False), (3, True)]
    assert elapsed >= 0.1 + 0.2


def test_cancel_stops_a_running_command_promptly() -> None:
    cancel = threading.Event()
    timer = threading.Timer(0.2, cancel.set)
    timer.start()
    t0 = time.monotonic()
    out, seen = run({"argv": ["sleep", "30"], "timeout_s": 20, "retries": 3}, cancel)
    elapsed = time.monotonic() - t0
    timer.join()
    assert not out.ok and "cancelled" in out.error
    assert len(seen) == 1
    assert elapsed < 0.2 + 0.5


def test_a_failing_on_attempt_does_not_stop_the_action(tmp_path: Path) -> None:
    marker = tmp_path / "touched"

    def broken(_: Outcome) -> None:
        raise OSError("log disk full")

    out = command_action({"argv": ["touch", str(marker)]}).run(threading.Event(), broken)
    assert out.ok and marker.exists()
    assert out.detail["on_attempt_errors"] == ["OSError: log disk full"]


@pytest.mark.parametrize(
    "bad",
    [
        {"argv": "echo hi"},
        {"argv": []},
        {"argv": ["echo", 1]},
        {"argv": ["true"], "timeout_s": 0},
        {"argv": ["true"], "retries": 0},
        {"argv": ["true"], "env": ["A=1"]},
    ],
)
def test_bad_settings_are_rejected(bad: dict) -> None:
    with pytest.raises(SettingsError):
        parse_settings("command", bad)
