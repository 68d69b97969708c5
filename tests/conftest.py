"""Shared pytest fixtures."""

from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from sshd import Sshd, sshd_available, start_sshd

# A test suite started in the background by a shell without job control inherits
# SIGINT ignored, and so would every command it starts: the tests that press Ctrl-C
# (demo, logs -f, ui) would wait for nothing.  Handled here, SIGINT is back to its
# default in every child (exec keeps ignored signals, resets handled ones).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def user_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One ``$XDG_CACHE_HOME`` for the whole run, in and out of this process: replay
    keeps its monitors and parser tables there (supervisor/cache.py, ``open_user``),
    so a spec compiles once per run, and never in or from the user's own
    ~/.cache.  Tests of that cache set their own."""
    home = tmp_path_factory.mktemp("xdg-cache")
    home.chmod(0o700)
    with pytest.MonkeyPatch.context() as mp:
        if "PIP_CACHE_DIR" not in os.environ:  # pip's wheels stay where they were
            base = os.environ.get("XDG_CACHE_HOME", "")
            mp.setenv(
                "PIP_CACHE_DIR",
                str(Path(base if os.path.isabs(base) else Path.home() / ".cache") / "pip"),
            )
        mp.setenv("XDG_CACHE_HOME", str(home))
        yield home


@pytest.fixture
def cli_main(monkeypatch: pytest.MonkeyPatch) -> Callable[..., subprocess.CompletedProcess[str]]:
    """The CLI's main in this process (tests/inproc.py), without
    SAFETY_SUPERVISOR_DEBUG, as for users."""
    from inproc import cli_main

    monkeypatch.delenv("SAFETY_SUPERVISOR_DEBUG", raising=False)
    return cli_main


@pytest.fixture
def sshd(tmp_path: Path) -> Iterator[Sshd]:
    """A real OpenSSH sshd on 127.0.0.1 (see tests/sshd.py), stopped after the test."""
    if not sshd_available():
        reason = "/usr/sbin/sshd or ssh-keygen missing (install Debian's openssh-server)"
        if os.environ.get("CI"):
            # .ci/run installs openssh-server, so in CI this is a broken setup, not a skip.
            pytest.fail(reason)
        pytest.skip(reason)
    server = start_sshd(tmp_path / "sshd")
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def robot_node() -> Iterator[Any]:
    """An rclpy node in this process on the test run's DDS domain (tests/rosutil.py)."""
    from rosutil import ros_node

    with ros_node() as node:
        yield node
