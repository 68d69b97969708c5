"""Runs mitigation actions off the monitoring loop and writes their records.

One worker thread per configured action: a slow or retrying action (an SSH
shutdown with backoff) never delays another (the halt publish), and none of
them ever delays the next monitor step.  Every attempt of every action is a
``mitigation`` record with the latency from the violation's detection to the
attempt's end.  An action that raises is caught here: the worker survives and
the failure is a record, not a traceback.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from mitigations.actions.base import Action, Outcome

if TYPE_CHECKING:  # an annotation only: replay imports this module and writes no log
    from mitigations.violationlog.writer import ViolationLog


@dataclass(frozen=True)
class Request:
    """Run ``actions`` for ``requirement`` (an id, or ``on_stale``)."""

    requirement: str
    actions: tuple[str, ...]
    detected_ns: int  # time.monotonic_ns() when the violation was detected
    stage: str = "violation"  # violation | escalation | repeat | confirm_failed | stale


# (request, action name, final outcome): called on the worker thread.
DoneCallback = Callable[[Request, str, Outcome], None]


class Engine:
    def __init__(
        self,
        actions: Mapping[str, Action],
        log: ViolationLog,
        on_done: DoneCallback | None = None,
    ) -> None:
        self.actions = dict(actions)
        self.log = log
        self.on_done = on_done
        self.cancel = threading.Event()
        self._queues: dict[str, queue.SimpleQueue[Request | None]] = {}
        self._threads: list[threading.Thread] = []
        for name, action in self.actions.items():
            if action.inline:
                continue  # run by submit() in the caller's thread: no worker needed
            q: queue.SimpleQueue[Request | None] = queue.SimpleQueue()
            self._queues[name] = q
            t = threading.Thread(target=self._work, args=(name, q), name=f"mitigation-{name}")
            t.daemon = True
            t.start()
            self._threads.append(t)

    def submit(self, request: Request) -> None:
        """Queue the request's actions; returns at once."""
        for name in request.actions:
            action = self.actions.get(name)
            if action is None:  # config validation makes this unreachable; never drop silently
                self.log.mitigation(
                    request.requirement,
                    action=name,
                    kind="undefined",
                    ok=False,
                    error=f"no mitigation named '{name}'",
                    latency_ms=0.0,
                    stage=request.stage,
                )
            elif action.inline:
                # A publish takes microseconds: done here, right after the violation
                # record is written (and fsynced, under before_action), instead of
                # paying a thread handoff before the halt.
                self._run(name, request)
            else:
                self._queues[name].put(request)

    def close(self, timeout: float = 1.0) -> list[str]:
        """Cancel retries, let running attempts end; names of workers still busy."""
        self.cancel.set()
        for q in self._queues.values():
            q.put(None)
        deadline = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))
        return [t.name for t in self._threads if t.is_alive()]

    def _work(self, name: str, q: queue.SimpleQueue[Request | None]) -> None:
        while True:
            request = q.get()
            if request is None or self.cancel.is_set():
                return
            self._run(name, request)

    def _run(self, name: str, request: Request) -> None:
        action = self.actions[name]

        def record(out: Outcome, request: Request = request) -> None:
            latency_ms = (time.monotonic_ns() - request.detected_ns) / 1e6
            self.log.mitigation(
                request.requirement,
                action=name,
                kind=action.kind,
                ok=out.ok,
                error=out.error,
                attempt=out.attempt,
                latency_ms=round(latency_ms, 3),
                stage=request.stage,
                **({"detail": out.detail} if out.detail else {}),
            )

        try:
            final = action.run(self.cancel, record)
        except Exception as e:  # noqa: BLE001 - a crashing action must not kill its worker
            final = Outcome(ok=False, error=f"{type(e).__name__}: {e}")
            record(final)
        if self.on_done is not None:
            try:
                self.on_done(request, name, final)
            except Exception as e:  # noqa: BLE001 - keep the worker alive, say why
                self.log.supervisor(
                    "internal_error", where=f"mitigation-{name} callback", error=repr(e)
                )
