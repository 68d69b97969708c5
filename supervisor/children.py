"""The one way this package starts a child process (the daemon's recording writer,
and through :mod:`supervisor.tools.children` the tools' and the tests' children).

Every child:

* gets :func:`child_env`: this process's environment without the systemd variables
  meant for this process (:func:`ros_env` adds one ROS domain, localhost only);
* runs in its own process group, so Ctrl-C reaches only the parent, which stops
  the children in order, and killing the group also takes what the child started.
  Under systemd the child stays in the service's cgroup, so stopping the unit
  still reaches it (``KillMode=mixed``: after the daemon has exited);
* gets ``parent_death_signal`` (default SIGTERM) when the parent dies, even by
  SIGKILL (``PR_SET_PDEATHSIG``).  A trampoline sets it, ``python -m
  supervisor.children PID -- ARGV``, then execs ARGV, which keeps the pid (signals
  and /proc readings reach the real child).  Popen's ``preexec_fn`` would save a
  process but is unsafe once threads run, and the daemon, the tests (rclpy) and
  the bench (stdout readers) have threads by then;
* runs ``sys.executable -m ...`` on the installed package: no PYTHONPATH to a
  source tree, so it works installed from a wheel.

The parent-death signal fires when the *thread* that started the child ends:
start such children from a thread that outlives them (the main thread).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

PR_SET_PDEATHSIG = 1
# Meant for this process (a systemd service, a shell with ROS set up), not its children;
# ROS_LOCALHOST_ONLY is deprecated and ROS_AUTOMATIC_DISCOVERY_RANGE says the same.
NOT_INHERITED = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "ROS_LOCALHOST_ONLY")

# What Popen takes for a standard stream: PIPE, DEVNULL, a file or None (inherit).
Stream = int | IO[Any] | None


def child_env() -> dict[str, str]:
    """This process's environment without what is meant for this process only."""
    return {k: v for k, v in os.environ.items() if k not in NOT_INHERITED}


def ros_vars(domain_id: int) -> dict[str, str]:
    """The variables that put a ROS process on ``domain_id``, this machine only."""
    return {"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def ros_env(domain_id: int, *, log_dir: Path | None = None) -> dict[str, str]:
    """The environment of a child on ``domain_id``; ``log_dir``: ROS_LOG_DIR (not ~/.ros)."""
    env = child_env()
    env.update(ros_vars(domain_id))
    if log_dir is not None:
        env["ROS_LOG_DIR"] = str(log_dir)
    return env


def start(
    argv: Sequence[str],
    *,
    env: Mapping[str, str],
    cwd: Path | None = None,
    stdin: Stream = subprocess.DEVNULL,
    stdout: Stream = subprocess.DEVNULL,
    stderr: Stream = None,
    parent_death_signal: int | None = signal.SIGTERM,
) -> subprocess.Popen[bytes]:
    """``argv`` as a child (see the module docstring); ``parent_death_signal=None``:
    no trampoline, for a child that notices its parent's death itself (EOF)."""
    if parent_death_signal is not None:
        trampoline = [sys.executable, "-m", __name__, str(os.getpid()), str(parent_death_signal)]
        argv = [*trampoline, "--", *argv]
    return subprocess.Popen(
        list(argv),
        cwd=cwd,
        env=dict(env),
        stdin=stdin,
        stdout=stdout,
        stderr=stderr,
        start_new_session=True,
    )


def run(
    argv: Sequence[str],
    *,
    env: Mapping[str, str],
    timeout: float | None,
    capture: bool = True,
    parent_death_signal: int | None = signal.SIGTERM,
) -> subprocess.CompletedProcess[str]:
    """``argv`` to its end as a :func:`start`ed child, as ``subprocess.run`` would:
    its output as text (``capture``), or on this process's streams with its stdin
    (``capture=False``, for an operator's command).  On ``timeout`` the child's
    process group is killed, what it started too, and ``subprocess.TimeoutExpired``
    raised.  ``parent_death_signal=None`` where the trampoline's own start would
    distort a timing."""
    pipe = subprocess.PIPE if capture else None
    proc = start(
        argv,
        env=env,
        stdin=subprocess.DEVNULL if capture else None,
        stdout=pipe,
        stderr=pipe,
        parent_death_signal=parent_death_signal,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    text = [b.decode(errors="replace") if b is not None else "" for b in (out, err)]
    return subprocess.CompletedProcess(list(argv), proc.returncode, text[0], text[1])


def _trampoline(args: list[str]) -> int:
    """``PID SIGNAL -- ARGV``: get SIGNAL when PID dies, then become ARGV."""
    if len(args) < 4 or args[2] != "--":
        print("usage: python -m supervisor.children PARENT_PID SIGNAL -- ARGV...", file=sys.stderr)
        return 2
    parent, signum, argv = int(args[0]), int(args[1]), args[3:]
    # Best effort (Linux only); the parent kills the process group anyway.
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum)
    if os.getppid() != parent:  # the parent died before prctl took effect
        return 1
    try:
        os.execvp(argv[0], argv)
    except OSError as e:
        print(f"cannot run {argv[0]}: {e.strerror or e}", file=sys.stderr)
    return 127


if __name__ == "__main__":
    raise SystemExit(_trampoline(sys.argv[1:]))
