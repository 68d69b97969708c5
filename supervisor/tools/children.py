"""The one way the tools (``demo``, ``bench``) and the tests start a child process.

Every child:

* gets :func:`ros_env`: this process's environment on one ROS domain with
  localhost-only discovery, without the systemd variables meant for this process;
* runs in its own process group, so Ctrl-C reaches only the parent, which stops
  the children in order, and killing the group also takes what the child started;
* gets SIGTERM when the parent dies, even by SIGKILL (``PR_SET_PDEATHSIG``).  A
  trampoline sets it, ``python -m supervisor.tools.children PID -- ARGV``, then
  execs ARGV, which keeps the pid (signals and /proc readings reach the real
  child).  Popen's ``preexec_fn`` would save a process but is unsafe once threads
  run, and the tests (rclpy) and the bench (stdout readers) have threads by then;
* runs ``sys.executable -m ...`` on the installed package: no PYTHONPATH to a
  source tree, so the tools work installed from a wheel.

The parent-death signal fires when the *thread* that started the child ends:
start children from a thread that outlives them (the main thread).
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

PR_SET_PDEATHSIG = 1
# Meant for this process (a systemd service, a shell with ROS set up), not its children;
# ROS_LOCALHOST_ONLY is deprecated and ROS_AUTOMATIC_DISCOVERY_RANGE says the same.
NOT_INHERITED = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "ROS_LOCALHOST_ONLY")
REAP_TIMEOUT_S = 5.0


def ros_vars(domain_id: int) -> dict[str, str]:
    """The variables that put a ROS process on ``domain_id``, this machine only."""
    return {"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def ros_env(domain_id: int, *, log_dir: Path | None = None) -> dict[str, str]:
    """The environment of a child on ``domain_id``; ``log_dir``: ROS_LOG_DIR (not ~/.ros)."""
    env = {k: v for k, v in os.environ.items() if k not in NOT_INHERITED}
    env.update(ros_vars(domain_id))
    if log_dir is not None:
        env["ROS_LOG_DIR"] = str(log_dir)
    return env


def daemon_argv(config: Path, log: Path, build_dir: Path, *extra: str) -> list[str]:
    """``safety-supervisor run`` of this interpreter's installed package."""
    run = [sys.executable, "-m", "supervisor", "run", str(config)]
    return [*run, "--log", str(log), "--build-dir", str(build_dir), *extra]


class Child:
    """A child process (see the module docstring); stderr goes to a file.

    ``stdin``: a pipe for :meth:`send`, else /dev/null.  ``json_stdout``: a thread
    collects the JSON objects the child prints one per line, else /dev/null.
    """

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        env: Mapping[str, str],
        cwd: Path,
        stderr: Path,
        stdin: bool = False,
        json_stdout: bool = False,
    ) -> None:
        self.name = name
        self.stderr_path = stderr
        self._objects: list[tuple[float, dict[str, Any]]] = []  # (monotonic time, object)
        self._taken = 0
        self._cond = threading.Condition()
        trampoline = [sys.executable, "-m", __name__, str(os.getpid()), "--"]
        with stderr.open("w") as err:
            self.proc = subprocess.Popen(
                [*trampoline, *argv],
                cwd=cwd,
                env=dict(env),
                stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                stdout=subprocess.PIPE if json_stdout else subprocess.DEVNULL,
                stderr=err,
                start_new_session=True,
            )
        self._reader: threading.Thread | None = None
        if json_stdout:
            self._reader = threading.Thread(target=self._read, name=f"{name}-stdout", daemon=True)
            self._reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def alive(self) -> bool:
        return self.proc.poll() is None

    # ---------------------------------------------------------- output

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                obj = json.loads(line)
            except ValueError:
                continue
            if isinstance(obj, dict):
                with self._cond:
                    self._objects.append((time.monotonic(), obj))
                    self._cond.notify_all()

    def objects(self) -> list[tuple[float, dict[str, Any]]]:
        """Every object printed so far, with the monotonic time it was read."""
        with self._cond:
            return list(self._objects)

    def take(self) -> list[dict[str, Any]]:
        """The objects printed since the last call."""
        with self._cond:
            new = self._objects[self._taken :]
            self._taken = len(self._objects)
        return [obj for _t, obj in new]

    def wait_output(self, seen: int, timeout: float) -> None:
        """Until more than ``seen`` objects were printed, or ``timeout`` seconds."""
        with self._cond:
            self._cond.wait_for(lambda: len(self._objects) > seen, timeout=timeout)

    def last_stderr(self, *, skip_warnings: bool = False) -> str:
        """The last line on stderr; ``skip_warnings``: the last that is not a warning
        (the FILE:LINE error, not a warning printed before it)."""
        try:
            lines = [ln.strip() for ln in self.stderr_path.read_text().splitlines() if ln.strip()]
        except OSError:
            return ""
        if skip_warnings:
            errors = [ln for ln in lines if "WARNING" not in ln]
            lines = errors or lines
        return lines[-1] if lines else ""

    def send(self, line: str) -> None:
        """A line on the child's stdin; nothing if it is gone (its exit is seen elsewhere)."""
        if self.proc.stdin is None:
            return
        with contextlib.suppress(OSError, ValueError):
            self.proc.stdin.write(line.encode() + b"\n")
            self.proc.stdin.flush()

    # ---------------------------------------------------------- stopping

    def signal(self, signum: int) -> None:
        if self.alive():
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signum)

    def terminate(self) -> None:
        """SIGTERM to the child, which stops what it started."""
        self.signal(signal.SIGTERM)

    def wait(self, timeout: float) -> bool:
        """Whether the child exited within ``timeout`` seconds."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return False
        return True

    def stop(self, timeout: float = 5.0) -> int | None:
        """SIGTERM, ``timeout`` seconds to exit, then :meth:`kill`; the exit status."""
        self.terminate()
        self.wait(timeout)
        self.kill()
        return self.proc.returncode

    def kill(self) -> None:
        """SIGKILL the whole group (anything the child left behind too), then reap."""
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.wait(REAP_TIMEOUT_S)
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        if self._reader is not None:
            self._reader.join(1.0)


class NotifySocket:
    """A daemon child's NOTIFY_SOCKET, bound here: what systemd would read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))

    def env(self) -> dict[str, str]:
        return {"NOTIFY_SOCKET": str(self.path)}

    def recv(self, timeout: float) -> str | None:
        """The next datagram, or None after ``timeout`` seconds (0: do not wait)."""
        self.sock.settimeout(timeout if timeout > 0 else 0.0)
        try:
            return self.sock.recv(4096).decode(errors="replace")
        except (TimeoutError, BlockingIOError):
            return None

    def close(self) -> None:
        self.sock.close()
        self.path.unlink(missing_ok=True)


def _trampoline(args: list[str]) -> int:
    """``PID -- ARGV``: die with PID, then become ARGV."""
    if len(args) < 3 or args[1] != "--":
        print("usage: python -m supervisor.tools.children PARENT_PID -- ARGV...", file=sys.stderr)
        return 2
    parent, argv = int(args[0]), args[2:]
    # Best effort (Linux only); the parent kills the process group anyway.
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != parent:  # the parent died before prctl took effect
        return 1
    try:
        os.execvp(argv[0], argv)
    except OSError as e:
        print(f"cannot run {argv[0]}: {e.strerror or e}", file=sys.stderr)
    return 127


if __name__ == "__main__":
    raise SystemExit(_trampoline(sys.argv[1:]))
