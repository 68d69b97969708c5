"""The tools' (``demo``, ``bench``) and the tests' children: :class:`Child` (stderr to
a file, JSON lines read from stdout, stopping in order), the daemon's command line and
a NOTIFY_SOCKET to read.

Starting a process is :func:`supervisor.children.start` (environment, own process
group, SIGTERM when the parent dies): the daemon starts its recording writer the same
way, and the daemon may not import the tools.
"""

from __future__ import annotations

import contextlib
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

from supervisor.children import NOT_INHERITED, ros_env, ros_vars, start

__all__ = ["NOT_INHERITED", "Child", "NotifySocket", "daemon_argv", "ros_env", "ros_vars"]

REAP_TIMEOUT_S = 5.0


def daemon_argv(config: Path, log: Path, build_dir: Path, *extra: str) -> list[str]:
    """``safety-supervisor run`` of this interpreter's installed package."""
    run = [sys.executable, "-m", "supervisor", "run", str(config)]
    return [*run, "--log", str(log), "--build-dir", str(build_dir), *extra]


class Child:
    """A child process (:func:`supervisor.children.start`); stderr goes to a file.

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
        with stderr.open("w") as err:
            self.proc = start(
                argv,
                env=env,
                cwd=cwd,
                stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                stdout=subprocess.PIPE if json_stdout else subprocess.DEVNULL,
                stderr=err,
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
