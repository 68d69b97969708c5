"""Operator resets and the control socket's requests, served in the receive loop.

The socket's thread (supervisor/daemon/control.py) hands requests over; this
module answers them between two steps: a reset through the core, at most
``control.max_resets`` per ``control.interval_ms``, refused calls counted and
reported once per interval; a reload request goes to the reloader
(supervisor/daemon/reload.py).  It also watches the socket thread: one that
failed is started again a few times, then stays down, and the watchdog stops
(docs/reference/ros-interfaces.md, "Control socket").
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from mitigations.violationlog.writer import ViolationLog
from supervisor.daemon.control import ControlRequest, ControlServer, Refusals, ResetGate
from supervisor.daemon.core import Core

CONTROL_RESTARTS = 3  # a control thread that fails again after this many stays down


class Resets:
    """The operator's side of the loop: ``control`` (None: no socket) and resets."""

    def __init__(
        self,
        core: Core,
        log: ViolationLog,
        control: ControlServer | None,
        reload: Callable[[ControlRequest], None],
        status: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        self.core = core
        self.log = log
        self.control = control
        self._reload = reload  # a reload asked for on the socket
        self._status = status  # the answer to a status request (read-only)
        self._gate = ResetGate()
        self._refusals = Refusals()
        cfg = core.session.config.control
        self._seen = (cfg.socket, cfg.group)
        self._down = False  # its thread failed more than CONTROL_RESTARTS times

    def serving(self) -> bool:
        """The control socket's thread serves (no socket: nothing to serve).  The
        watchdog pings only while it does: an operator who cannot reset is a
        failure systemd must see (docs/reference/ros-interfaces.md, "Control socket")."""
        return self.control is None or self.control.alive()

    def _health(self) -> None:
        """A control thread that ended is recorded and started again, at most
        ``CONTROL_RESTARTS`` times; after that it stays down, the status and
        STATUS= say so and the watchdog stops."""
        control = self.control
        # A thread that runs but is late (the process was stopped, the machine is
        # swamped) is not restarted: the watchdog waits for it (serving).
        if control is None or control.running() or self._down:
            return
        error = control.health()["error"] or "it ended"
        if control.restarts < CONTROL_RESTARTS and control.revive():
            self.log.supervisor("control_failed", socket=control.path, error=error, restarted=True)
            return
        self._down = True
        self.log.supervisor("control_failed", socket=control.path, error=error, restarted=False)

    def work(self, now: int) -> None:
        """Answer the control socket's requests; report refused calls once per interval."""
        cfg = self.core.session.config.control
        self._health()
        if self.control is not None:
            for req in self.control.take():
                if req.refused is not None:
                    self._refusals.add(req.refused, _who(req.caller.record()))
                    req.answer({"ok": False, "refused": req.refused, "message": req.detail})
                    continue
                if req.command == "reload":
                    self._reload(req)
                    continue
                if req.command == "status":
                    state = self._status() if self._status is not None else {}
                    req.answer({"ok": True, "message": "running", "status": state})
                    continue
                ok, message, refused = self.operator_reset(
                    via=req.via or "control_socket",
                    caller=req.caller.record(),
                    now=now,
                    requirement=req.requirement,
                    client=req.client,
                )
                reply: dict[str, Any] = {"ok": ok, "message": message}
                if refused is not None:
                    reply["refused"] = refused
                req.answer(reply)
            seen = (cfg.socket, cfg.group)
            if seen != self._seen:  # a reload changed control.socket or group
                self._seen = seen
                why = "control.socket and control.group take effect at the next start"
                self.log.supervisor("control_unchanged", socket=self.control.path, why=why)
        summary = self._refusals.due(now, int(cfg.interval_ms * 1e6))
        if summary is not None:
            # Each warning is a record, which the log echoes on stderr or sends to the
            # journal (docs/reference/log.md): never printed a second time here.
            self.log.supervisor("reset_refused", **summary)

    def operator_reset(
        self,
        *,
        via: str,
        caller: dict[str, Any] | None,
        now: int | None = None,
        requirement: str | None = None,
        client: str | None = None,
    ) -> tuple[bool, str, str | None]:
        """Reset every requirement's monitor (or ``requirement``'s); lift latches of
        requirements that hold.  Returns (accepted, message for the caller, why refused).

        At most ``control.max_resets`` per ``control.interval_ms``: a refused call
        touches nothing and is counted, not logged on its own (:class:`Refusals`)."""
        now = time.monotonic_ns() if now is None else now
        who = _who(caller) if caller is not None else via
        cfg = self.core.session.config.control
        known = [r.id for r in self.core.session.requirements]
        if requirement is not None and requirement not in known:
            self._refusals.add("bad_request", who)
            return (
                False,
                f"no requirement '{requirement}' (known: {', '.join(known)})",
                "bad_request",
            )
        if not self._gate.admit(now, cfg.max_resets, int(cfg.interval_ms * 1e6)):
            self._refusals.add("rate", who)
            return (
                False,
                f"not reset: rate limited to {cfg.max_resets} per {cfg.interval_ms:g} ms "
                "(control.max_resets, control.interval_ms); try again",
                "rate",
            )
        extra: dict[str, Any] = {"via": via}
        if caller is not None:
            extra["caller"] = caller
        if client is not None:
            extra["client"] = client
        refused = self.core.operator_reset(now, requirement, **extra)
        if refused:
            self._refusals.add("still_violated", who)
            return False, "not reset: " + ", ".join(refused), "still_violated"
        return True, f"{requirement or 'all requirements'} reset", None


def _who(caller: dict[str, Any]) -> str:
    """A caller as the refusal summary names it."""
    return str(caller.get("user", f"uid {caller.get('uid')}"))
