"""The bench's processes: a temp dir, one ROS environment, and every child started
(:mod:`supervisor.tools.children`), all killed when the session ends.

The helpers (``python -m supervisor.tools.bench.procs ROLE``) talk to the bench in
JSON lines on stdout (``{"event": ...}``); the daemon through its notify socket
and its violation log.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from mitigations.violationlog.reader import records_since
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.children import Child, NotifySocket, daemon_argv, ros_env

# tests/support/rosutil.py draws ROS_DOMAIN_ID from 1..200; 215..232 is disjoint from it
# and, unlike 102..214, clear of Linux's ephemeral port range.
DOMAIN_IDS = (215, 232)


def cpu_seconds(pid: int) -> float:
    """utime + stime of every thread of ``pid`` (DDS threads included)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return float("nan")
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_at_exit(pid: int, timeout: float) -> float:
    """``cpu_seconds`` of ``pid`` once it has exited and before it is reaped
    (WNOWAIT leaves it a zombie, whose /proc stat still holds its times); nan when
    it did not exit within ``timeout`` or was reaped already."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            done = os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return float("nan")
        if done is not None:
            return cpu_seconds(pid)
        time.sleep(0.01)  # polling for the exit; waitid has no timeout
    return float("nan")


class Helper(Child):
    """A child whose JSON lines are events: ``{"event": KIND, ...}``; ``error`` ends the bench."""

    def check(self) -> None:
        """Raise BenchError if the child reported an error or died."""
        for _t, ev in self.objects():
            if ev.get("event") == "error":
                raise BenchError(f"{self.name}: {ev.get('error')}")
        if not self.alive():
            why = self.last_stderr()
            raise BenchError(
                f"{self.name} exited ({self.returncode})" + (f": {why}" if why else "")
            )

    def events(self, kind: str) -> list[dict[str, Any]]:
        return [ev for _t, ev in self.objects() if ev.get("event") == kind]

    def latest(self, kind: str) -> tuple[float, dict[str, Any]] | None:
        for t, ev in reversed(self.objects()):
            if ev.get("event") == kind:
                return t, ev
        return None

    def wait_event(
        self, kind: str, timeout: float, others: tuple[Helper, ...] = ()
    ) -> dict[str, Any]:
        """The first event ``kind``; BenchError if this child (or one of
        ``others``) fails first or ``timeout`` passes."""
        deadline = time.monotonic() + timeout
        while True:
            seen = self.objects()
            for _t, ev in seen:
                if ev.get("event") == kind:
                    return ev
            self.wait_output(len(seen), 0.1)
            for c in (self, *others):
                c.check()
            if time.monotonic() > deadline:
                raise BenchError(f"{self.name}: no '{kind}' within {timeout:g} s")


class Daemon(Helper):
    """``safety-supervisor run CONFIG`` with its log, build dir and a bound
    NOTIFY_SOCKET in ``workdir``; ``extra``: more arguments of ``run`` (``--record DIR``)."""

    def __init__(
        self,
        config: Path,
        workdir: Path,
        env: dict[str, str],
        watchdog_usec: int | None = None,
        extra: Sequence[str] = (),
    ) -> None:
        workdir.mkdir(parents=True, exist_ok=True)
        self.log = workdir / "violations.jsonl"
        self.notify = NotifySocket(workdir / "notify.sock")
        self.pings: list[float] = []  # monotonic times of WATCHDOG=1, once watched
        self._watching = threading.Event()
        self._watcher: threading.Thread | None = None
        wd = {"WATCHDOG_USEC": str(watchdog_usec)} if watchdog_usec else {}
        super().__init__(
            "daemon",
            daemon_argv(config, self.log, workdir / "build", *extra),
            env={**env, **self.notify.env(), **wd},
            cwd=workdir,
            stderr=workdir / "daemon.stderr",
        )

    def wait_ready(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BenchError(f"daemon: not ready within {timeout:g} s: {self.last_stderr()}")
            self.check()
            data = self.notify.recv(min(left, 0.2))
            if data is not None and "READY=1" in data.splitlines():
                return

    def watch_pings(self) -> None:
        """After READY=1: time every WATCHDOG=1 on a thread of its own, as systemd would."""
        self._watching.set()

        def run() -> None:
            while self._watching.is_set():
                data = self.notify.recv(0.05)
                if data is not None and "WATCHDOG=1" in data.splitlines():
                    self.pings.append(time.monotonic())

        self._watcher = threading.Thread(target=run, name="pings", daemon=True)
        self._watcher.start()

    def longest_ping_gap(self, start: float, end: float) -> float | None:
        """Seconds: the longest time without a ping between ``start`` and ``end``."""
        self._watching.clear()
        if self._watcher is not None:
            self._watcher.join()
            self._watcher = None
        marks = [start, *(t for t in self.pings if start < t < end), end]
        return max(b - a for a, b in zip(marks, marks[1:], strict=False)) if self.pings else None

    def stop_cleanly(self, timeout: float = 10.0) -> float:
        """SIGTERM and wait: the daemon writes its ``stop`` record. Returns its CPU
        seconds at exit (shutdown included: the recorder's last writes), read from
        /proc while it is a zombie, before it is reaped."""
        self.terminate()
        cpu = _cpu_at_exit(self.pid, timeout)
        if not self.wait(timeout):
            raise BenchError(f"daemon did not stop within {timeout:g} s")
        if self.returncode != 0:
            raise BenchError(f"daemon exited ({self.returncode}): {self.last_stderr()}")
        return cpu

    def records(self) -> list[dict[str, Any]]:
        return records_since(self.log, 0, raw=True)[0]  # with _line: each record as stored

    def stop_record(self) -> dict[str, Any]:
        for r in reversed(self.records()):
            if r.get("event") == "supervisor" and r.get("what") == "stop":
                return r
        raise BenchError(f"daemon wrote no stop record in {self.log}")

    def kill(self) -> None:
        self._watching.clear()
        if self._watcher is not None:
            self._watcher.join()
        super().kill()
        self.notify.close()


def claim_domain() -> tuple[int, socket.socket]:
    """A ROS_DOMAIN_ID of DOMAIN_IDS that no other bench on this host holds, and the
    claim on it: an abstract Unix socket bound to a name per domain, which the kernel
    frees when its holder exits however it exits. Two benches in one domain see each
    other's publishers on the same topics, and their counts mix."""
    ids = list(range(DOMAIN_IDS[0], DOMAIN_IDS[1] + 1))
    random.shuffle(ids)
    for d in ids:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            s.bind(f"\0safety-supervisor-bench-domain-{d}")
        except OSError:
            s.close()
            continue
        return d, s
    raise BenchError(
        f"every ROS_DOMAIN_ID of {DOMAIN_IDS[0]}..{DOMAIN_IDS[1]} is held by another bench "
        "on this host; wait for one to finish or give --domain-id"
    )


class Session:
    """The temp dir, the ROS environment and every process started (for cleanup)."""

    def __init__(self, domain_id: int | None) -> None:
        self._claim: socket.socket | None = None
        if domain_id is None:
            domain_id, self._claim = claim_domain()
        self.domain_id = domain_id
        self.tmp = Path(tempfile.mkdtemp(prefix="safety-supervisor-bench-"))
        (self.tmp / "ros-log").mkdir()
        self.env = ros_env(self.domain_id, log_dir=self.tmp / "ros-log")
        self.children: list[Child] = []

    def child(self, label: str, role: str, *args: str, workdir: Path) -> Helper:
        """``python -m supervisor.tools.bench.procs ROLE ARGS``."""
        workdir.mkdir(parents=True, exist_ok=True)
        c = Helper(
            label,
            [sys.executable, "-m", "supervisor.tools.bench.procs", role, *args],
            env=self.env,
            cwd=workdir,
            stderr=workdir / f"{role}.stderr",
            stdin=True,
            json_stdout=True,
        )
        self.children.append(c)
        return c

    def daemon(
        self,
        config: Path,
        workdir: Path,
        watchdog_usec: int | None = None,
        extra: Sequence[str] = (),
    ) -> Daemon:
        d = Daemon(config, workdir, self.env, watchdog_usec, extra)
        self.children.append(d)
        return d

    def close(self) -> None:
        for c in self.children:
            c.kill()
        self.children = []
        shutil.rmtree(self.tmp, ignore_errors=True)
        if self._claim is not None:
            self._claim.close()
            self._claim = None


@contextlib.contextmanager
def session(domain_id: int | None) -> Iterator[Session]:
    s = Session(domain_id)
    try:
        yield s
    finally:
        s.close()
