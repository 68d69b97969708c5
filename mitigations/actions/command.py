"""The ``command`` mitigation: run a local program (no shell) and check its exit status.

Configuration::

    beep: {command: {argv: [/usr/local/bin/alarm, --loud], timeout_s: 10,
                     env: {ALARM_DEVICE: /dev/ttyUSB0}, retries: 1}}

* ``argv`` is executed directly, never through a shell: ``$HOME``, ``;``, ``*``
  reach the program literally.  A bare name is looked up in ``PATH``.
* The environment is minimal (``PATH``, ``LANG``) plus ``env``, not the
  daemon's own, so what the program sees does not depend on how the daemon was
  started.
* ``timeout_s`` (default 10): then the program and everything it started in its
  process group are killed.  Success means exit status 0.
* ``retries`` (default 1) is the total number of attempts, with a wait of
  ``backoff_s`` (default 0.5 s) after the first failure, doubling, at most 5 s.
  A program that cannot be started (not found, not executable) is not retried.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from typing import Any

from mitigations.actions.base import Outcome, RetryingAction, one_line
from mitigations.settings import CommandSettings

TAIL_CHARS = 500  # of stderr/stdout kept in an outcome's detail
BASE_ENV = {
    "PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
    "LANG": "C.UTF-8",
}


def _tail(data: bytes | None) -> str:
    return (data or b"").decode("utf-8", errors="replace")[-TAIL_CHARS:]


class CommandAction(RetryingAction):
    kind = "command"

    def __init__(self, name: str, settings: CommandSettings) -> None:
        self.name = name
        self.argv: list[str] = list(settings.argv)
        self.timeout_s = settings.timeout_s
        self.env: dict[str, str] = {**BASE_ENV, **settings.env}
        self.retries = settings.retries
        self.backoff_s = settings.backoff_s
        self.where = f"command {self.argv[0]}"

    def __repr__(self) -> str:
        return f"CommandAction({self.name!r}, {self.argv!r})"

    def attempt(self, cancel: threading.Event) -> tuple[Outcome, bool]:
        try:
            # Popen rather than subprocess.run: the wait must notice shutdown, and a
            # timeout must kill the whole process group, not only the direct child.
            proc = subprocess.Popen(
                self.argv,
                shell=False,
                env=self.env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                start_new_session=True,
            )
        except FileNotFoundError:
            return Outcome(False, f"{self.where}: executable not found"), False
        except PermissionError:
            return Outcome(False, f"{self.where}: permission denied (not executable?)"), False
        except OSError as e:
            return Outcome(False, f"{self.where}: cannot start: {e.strerror or e}"), False

        deadline = time.monotonic() + self.timeout_s
        stdout = stderr = b""
        why = ""
        while True:
            try:
                # Short slices so a shutdown is noticed within ~0.1 s; communicate()
                # may be called again after a timeout without losing output.
                stdout, stderr = proc.communicate(
                    timeout=max(0.0, min(0.1, deadline - time.monotonic()))
                )
                break
            except subprocess.TimeoutExpired:
                if time.monotonic() >= deadline:
                    why = f"timed out after {self.timeout_s:g} s (process killed)"
                elif cancel.is_set():
                    why = "cancelled (shutdown) while running (process killed)"
                else:
                    continue
            stdout, stderr = self._kill(proc)
            break

        detail: dict[str, Any] = {"stderr": _tail(stderr), "stdout": _tail(stdout)}
        if why:
            return Outcome(False, f"{self.where}: {why}", detail=detail), not cancel.is_set()
        status = proc.returncode
        detail = {"exit_status": status, **detail}
        if status == 0:
            return Outcome(True, detail=detail), False
        if status < 0:
            try:
                error = f"killed by signal {signal.Signals(-status).name}"
            except ValueError:  # a real-time signal has no name
                error = f"killed by signal {-status}"
        else:
            error = f"exit status {status}"
        tail = one_line(detail["stderr"], 200)
        return Outcome(
            False, f"{self.where}: {error}" + (f": {tail}" if tail else ""), detail=detail
        ), True

    @staticmethod
    def _kill(proc: subprocess.Popen[bytes]) -> tuple[bytes, bytes]:
        """Kill the program's process group; whatever it wrote so far."""
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        try:
            # Bounded: a grandchild that left the group could still hold the pipes open.
            return proc.communicate(timeout=1.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            return b"", b""
