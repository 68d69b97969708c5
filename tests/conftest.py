"""Shared pytest fixtures."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
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

# A skip that CI needs run is a failure in CI: with SAFETY_SUPERVISOR_REQUIRE_<KIND>=1
# (.ci/run sets them), a skip whose reason names that kind fails the test instead.
# The skip reasons say what is missing in these words; `-rs` lists the skips.
REQUIRED_KINDS: dict[str, re.Pattern[str]] = {
    "STRACE": re.compile(r"\bstrace\b"),
    "ROOT": re.compile(r"\bneeds root\b"),
    "ROS": re.compile(r"\brclpy\b"),
    "COPILOT": re.compile(r"\bCopilot\b"),
    # sshd, ssh-keygen, systemd-analyze, logrotate: the Debian packages .ci/run installs
    "TOOLS": re.compile(r"\binstall Debian's\b"),
    # the fleet extra's Ray (fleet replay --engine ray)
    "RAY": re.compile(r"\bray is not installed\b"),
}


def required_kind(reason: str) -> str | None:
    """The kind whose SAFETY_SUPERVISOR_REQUIRE_<KIND>=1 forbids a skip for this reason."""
    for kind, pattern in REQUIRED_KINDS.items():
        if pattern.search(reason) and os.environ.get(f"SAFETY_SUPERVISOR_REQUIRE_{kind}") == "1":
            return kind
    return None


def _fail_required_skip(report: pytest.TestReport | pytest.CollectReport) -> None:
    if not report.skipped or hasattr(report, "wasxfail"):
        return
    longrepr = report.longrepr
    reason = str(longrepr[2] if isinstance(longrepr, tuple) else longrepr)
    reason = reason.removeprefix("Skipped: ")
    kind = required_kind(reason)
    if kind is not None:
        report.outcome = "failed"
        report.longrepr = f"SAFETY_SUPERVISOR_REQUIRE_{kind}=1 but the test skipped: {reason}"


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    report = yield
    _fail_required_skip(report)
    return report


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Any:
    report = yield
    _fail_required_skip(report)
    return report


@pytest.fixture(autouse=True)
def _no_daemon_outlives_its_test() -> Iterator[None]:
    """A daemon a failed test left running would hold its domain's control socket,
    and the worker's later daemon tests would all fail to start (rosutil._OPEN)."""
    yield
    rosutil = sys.modules.get("rosutil")
    if rosutil is not None:
        rosutil.close_leftovers()


@pytest.fixture
def short_tmp() -> Iterator[Path]:
    """A directory with a short path, for Unix sockets: sun_path holds 108 bytes, and
    pytest's tmp_path under xdist (``.../popen-gw1/<test name>/``) can exceed it."""
    d = Path(tempfile.mkdtemp(prefix="ss-"))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


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
    """The CLI's main in this process (tests/support/inproc.py), without
    SAFETY_SUPERVISOR_DEBUG, as for users."""
    from inproc import cli_main

    monkeypatch.delenv("SAFETY_SUPERVISOR_DEBUG", raising=False)
    return cli_main


@pytest.fixture
def sshd(tmp_path: Path) -> Iterator[Sshd]:
    """A real OpenSSH sshd on 127.0.0.1 (see tests/support/sshd.py), stopped after the test."""
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
    """An rclpy node in this process on the test run's DDS domain (tests/support/rosutil.py)."""
    from rosutil import ros_node

    with ros_node() as node:
        yield node


def _done(req: Any) -> dict[str, Any]:
    return {"ok": True, "message": f"{req.command} done"}


@pytest.fixture
def control_server() -> Iterator[Callable[..., Any]]:
    """Opens control sockets (supervisor.daemon.control) served as the daemon's
    receive loop serves them: a thread woken by the server takes the requests and
    answers a refused one as refused, any other with ``answer(request)`` after
    ``delay`` seconds (a reload that validates and compiles).  The socket's folder
    has ``mode`` (pytest's own tmp_path is its user's alone); all closed after the test."""
    from supervisor.config.model import ControlConfig
    from supervisor.daemon.control import open_control

    opened: list[tuple[Any, threading.Event, threading.Thread, Path]] = []

    def serve(
        answer: Callable[[Any], dict[str, Any]] = _done,
        *,
        delay: float = 0.0,
        mode: int = 0o700,
        group: str | None = None,
        file: str = "cfg.yaml",
    ) -> Any:
        d = Path(tempfile.mkdtemp(prefix="ctl-"))
        d.chmod(mode)
        srv = open_control(ControlConfig(socket=str(d / "c.sock"), group=group, file=file))
        woken, stop = threading.Event(), threading.Event()
        pending: list[tuple[float, Any]] = []

        def loop() -> None:
            while not stop.is_set():
                woken.wait(0.05)  # woken by a request, or the next answer's time
                woken.clear()
                for req in srv.take():
                    if req.refused:
                        req.answer({"ok": False, "refused": req.refused, "message": req.detail})
                    else:
                        pending.append((time.monotonic() + delay, req))
                for due, req in [p for p in pending if p[0] <= time.monotonic()]:
                    pending.remove((due, req))
                    req.answer(answer(req))

        thread = threading.Thread(target=loop, daemon=True)
        thread.start()
        srv.start(woken.set)
        opened.append((srv, stop, thread, d))
        return srv

    try:
        yield serve
    finally:
        for srv, stop, thread, d in opened:
            srv.close()
            stop.set()
            thread.join(5)
            shutil.rmtree(d, ignore_errors=True)
