"""The interface every mitigation action implements, and the retry loop they share.

An action runs on a worker thread of its own (never on the monitoring loop).
``run`` blocks until the action is done, reports every attempt (failed ones
included) through ``on_attempt`` so each becomes a ``mitigation`` record, returns
the final outcome, never raises, and returns promptly once ``cancel`` is set
(supervisor shutdown).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

# Upper bound of one wait between attempts, whatever backoff_s and the attempt number.
MAX_BACKOFF_S = 5.0


@dataclass(frozen=True)
class Outcome:
    ok: bool
    error: str | None = None  # one line, human readable, no traceback
    attempt: int = 1  # 1-based attempt number this outcome is for
    detail: dict[str, Any] = field(default_factory=dict)  # e.g. {"exit_status": 0, "stderr": "..."}


class Action(Protocol):
    name: str  # the mitigation's name in the config (e.g. power_off)
    kind: str  # publish | ssh | command | log
    # True only for what takes microseconds (a publish): the engine then runs it on
    # the monitoring loop, right after the violation record, with no thread handoff.
    inline: bool

    def run(self, cancel: threading.Event, on_attempt: Callable[[Outcome], None]) -> Outcome: ...


def one_line(text: object, limit: int = 500) -> str:
    """``text`` as one line (newlines folded, whitespace squeezed), at most ``limit`` chars
    kept from the end, where a failing program usually says what went wrong."""
    s = " ".join(str(text).split())
    return s if len(s) <= limit else "..." + s[-(limit - 3) :]


def backoff_delay(backoff_s: float, failed_attempt: int) -> float:
    """Wait after failed attempt ``failed_attempt`` (1-based): doubling, capped."""
    return min(backoff_s * 2 ** (failed_attempt - 1), MAX_BACKOFF_S)


# One attempt: (its outcome without the attempt number, whether retrying could help).
Attempt = Callable[[threading.Event], tuple[Outcome, bool]]


def run_with_retries(
    attempt: Attempt,
    *,
    attempts: int,
    backoff_s: float,
    cancel: threading.Event,
    on_attempt: Callable[[Outcome], None],
    where: str,
) -> Outcome:
    """Run ``attempt`` up to ``attempts`` times with doubling backoff between them.

    Stops at the first success, at a failure ``attempt`` calls not retryable, or
    when ``cancel`` is set (the wait between attempts is ``cancel.wait``, so
    shutdown is not held up by a backoff).  Any exception becomes a failed
    outcome; ``where`` prefixes such errors.
    """
    attempts = max(1, attempts)
    # A failing on_attempt (the log) must not stop a safety action; remember it instead.
    callback_errors: list[str] = []

    def report(out: Outcome) -> None:
        try:
            on_attempt(out)
        except Exception as e:  # noqa: BLE001 - see callback_errors
            callback_errors.append(f"{type(e).__name__}: {one_line(e)}")

    # Still one record when shutdown came first, so a skipped action is not silently missing.
    out = Outcome(False, f"{where}: cancelled (shutdown) before the first attempt")
    if cancel.is_set():
        report(out)
        attempts = 0
    for n in range(1, attempts + 1):
        try:
            out, retryable = attempt(cancel)
        except Exception as e:  # noqa: BLE001 - run() never raises, by contract
            out, retryable = Outcome(False, f"{where}: {type(e).__name__}: {one_line(e)}"), False
        out = replace(out, attempt=n)
        report(out)
        if out.ok or not retryable or n == attempts:
            break
        if cancel.wait(backoff_delay(backoff_s, n)):
            out = replace(out, error=f"{out.error} (retries cancelled by shutdown)")
            break
    if callback_errors:
        out = replace(out, detail={**out.detail, "on_attempt_errors": callback_errors})
    return out


class RetryingAction:
    """An action whose ``run`` is :func:`run_with_retries` over its own ``attempt``.

    Subclasses set ``retries`` (total attempts), ``backoff_s`` and ``where`` (the
    prefix of their error messages) and implement ``attempt``.
    """

    retries: int
    backoff_s: float
    where: str
    inline = False  # retries wait: never on the monitoring loop

    def run(self, cancel: threading.Event, on_attempt: Callable[[Outcome], None]) -> Outcome:
        return run_with_retries(
            self.attempt,
            attempts=self.retries,
            backoff_s=self.backoff_s,
            cancel=cancel,
            on_attempt=on_attempt,
            where=self.where,
        )

    def attempt(self, cancel: threading.Event) -> tuple[Outcome, bool]:
        """One try: its outcome and whether retrying could help."""
        raise NotImplementedError
