"""Reload (SIGHUP, or ``reload`` on the control socket) and log reopen (SIGUSR1).

The new config is checked and compiled on a helper thread while the old monitor
keeps running; the swap (the node's) happens between two loop iterations.
Requests coalesce and none is lost: one that comes while a reload runs waits for
it, then the file is read once more (docs/reference/faults.md, "Log rotation and
reload signals").
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from mitigations.violationlog.writer import ViolationLog
from supervisor.daemon.control import ControlRequest
from supervisor.daemon.core import Core
from supervisor.daemon.notify import Notifier
from supervisor.daemon.session import Session

# How long STATUS= keeps saying a reload was done (a refusal stays until one is).
RELOADED_SHOWN_NS = 60_000_000_000


class Reloader:
    """Serves reload and reopen requests from the loop's :meth:`step`.

    ``prepare`` makes a session for the control socket's reload (run's, as for
    SIGHUP; None: not available), ``poke`` wakes the loop from the helper thread,
    ``swap(session, how)`` puts a prepared session in force, ``status_line()``
    is the daemon's STATUS= line."""

    def __init__(
        self,
        core: Core,
        log: ViolationLog,
        notifier: Notifier,
        *,
        prepare: Callable[[], Session] | None,
        poke: Callable[[], None],
        swap: Callable[[Session, dict[str, Any]], None],
        status_line: Callable[[], str],
    ) -> None:
        self.core = core
        self.log = log
        self.notifier = notifier
        self._prepare = prepare
        self._poke = poke
        self._swap = swap
        self._status_line = status_line
        self._request: Callable[[], Session] | None = None
        self._thread: threading.Thread | None = None
        self._result: Session | Exception | None = None
        # The requests the next reload answers, and those the running one does.
        self._waiting: list[ControlRequest] = []
        self._answering: list[ControlRequest] = []
        self._started = 0  # monotonic ns of the running reload's RELOADING=1
        # The last reload's outcome, and until when STATUS= leads with it (None:
        # until the next reload): `systemctl status` still shows a refused config
        # long after the periodic status line would have replaced it.
        self._outcome: tuple[str, int | None] | None = None
        self._reopen_requests = 0  # SIGUSR1s received; counted, so none is lost
        self._reopens_done = 0

    def request(self, prepare: Callable[[], Session]) -> None:
        """Reload with ``prepare()`` (run on a helper thread); safe from a signal handler."""
        self._request = prepare

    def request_reopen(self) -> None:
        """Reopen the violation log (logrotate); safe from a signal handler."""
        self._reopen_requests += 1

    def asked(self, req: ControlRequest) -> None:
        """A reload asked for on the control socket: answered when the new config
        is in force or refused (:meth:`step`), as ``systemctl reload`` needs.  A
        reload already running read the config before this request: the request
        waits for the next one, which reads the file anew."""
        if self._prepare is None:
            req.answer(
                {"ok": False, "refused": "bad_request", "message": "reload is not available"}
            )
            return
        self._waiting.append(req)
        self.request(self._prepare)

    def step(self) -> None:
        """Reopen if asked; start a requested reload; finish one whose thread ended."""
        # Reopen first: a reload never delays the switch to the new log file.
        requested = self._reopen_requests
        if requested != self._reopens_done:
            self._reopens_done = requested  # a signal after this line is served next turn
            self.log.reopen()  # logrotate's create mode: a fresh file after rename
        if self._request is not None and self._thread is None:
            # A SIGHUP during a reload stays in _request until this one ends:
            # the newest config is then read once more (requests coalesce, none is lost).
            prepare, self._request = self._request, None
            # An old logrotate snippet sends SIGHUP: follow a rotated path all the same.
            self.log.reopen(only_if_moved=True)
            self._answering, self._waiting = self._waiting, []
            self._started = time.monotonic_ns()
            self.notifier.reloading(status="reloading configuration")

            def work() -> None:
                try:
                    self._result = prepare()
                except Exception as e:  # noqa: BLE001 - reported by the loop
                    self._result = e
                self._poke()

            self._thread = threading.Thread(target=work, name="reload", daemon=True)
            self._thread.start()
        if self._thread is not None and not self._thread.is_alive():
            self._thread = None
            result, self._result = self._result, None
            requests, self._answering = self._answering, []
            how = self._how(requests)
            if isinstance(result, Session):
                self._swap(result, how)
                sha = result.config.sha256
                n = len(result.requirements)
                self._outcome = (
                    f"reloaded: monitoring {n} requirements",
                    time.monotonic_ns() + RELOADED_SHOWN_NS,
                )
                reply: dict[str, Any] = {
                    "ok": True,
                    "message": f"reloaded: monitoring {n} requirements, config sha256 {sha}",
                    "config_sha256": sha,
                }
            else:
                why = " ".join(str(result).splitlines())  # one line, wherever it came from
                self.log.supervisor("reload", ok=False, why=why, **how)
                self._outcome = (f"reload rejected: {why}", None)
                self.notifier.ready(status=f"reload rejected: {why} | {self._status_line()}")
                reply = {
                    "ok": False,
                    "refused": "config",
                    "message": f"reload rejected, still running the previous config: {why}",
                    "config_sha256": self.core.session.config.sha256,
                }
            # After the record and READY=1: whoever waits sees the outcome everywhere.
            for req in requests:
                req.answer(reply)

    def headline(self, now_ns: int) -> str | None:
        """What STATUS= leads with now: the last reload's outcome, while it is news."""
        if self._outcome is None:
            return None
        text, until = self._outcome
        if until is not None and now_ns >= until:
            self._outcome = None
            return None
        return text

    def _how(self, requests: list[ControlRequest]) -> dict[str, Any]:
        """The reload record's ``via`` (``signal`` or ``control_socket``), the
        callers who asked on the socket, and how long the reload took."""
        took = round((time.monotonic_ns() - self._started) / 1e6, 3)
        if not requests:
            return {"via": "signal", "duration_ms": took}
        callers = [r.caller.record() for r in requests]
        return {"via": "control_socket", "callers": callers, "duration_ms": took}


def keep_policies(old: Session, new: Session) -> list[str]:
    """A requirement whose text, formula, policy and actions did not change keeps its
    policy object (latch, episode, incident) across a reload, so a reload neither
    releases a latch nor reports a violation again; the ids of those kept."""

    def key(s: Session, i: int) -> tuple[Any, ...]:
        p = s.policies[i]
        return (s.formulas[i], p.config, p.on_violation, p.repeatable)

    before = {r.id: i for i, r in enumerate(old.requirements)}
    kept = []
    for i, req in enumerate(new.requirements):
        j = before.get(req.id)
        if j is not None and key(old, j) == key(new, i):
            new.policies[i] = old.policies[j]
            kept.append(req.id)
    return kept
