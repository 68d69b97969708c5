"""Shared pytest fixtures."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
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
