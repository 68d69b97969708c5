"""Stopping a command's processes whole: SIGTERM (systemd, a CI job's time limit,
``timeout``) stops a long command as Ctrl-C does, and a signal that comes while its
workers are being stopped waits for the stop to end, then interrupts as usual
(docs/reference/commands.md, "Exit codes and errors")."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

# the signals that stop a command: held off while its children are being stopped
_STOPS = (signal.SIGINT, signal.SIGTERM)


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt in the block, as Ctrl-C does: the command's
    ``finally`` blocks stop what it started and it says what it did, rather than dying
    at once with its workers left to their parent's death."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread gets Python's signal handlers
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """SIGINT and SIGTERM held off in the block and raised once it ends: a second
    Ctrl-C during a stop (a ``waitpid``, a pool's shutdown) would otherwise cut it
    short, leaving workers running and the standard library's fork server half
    stopped."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        came.append(signum)

    previous = {s: signal.signal(s, hold) for s in _STOPS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    for s in dict.fromkeys(came):
        signal.raise_signal(s)  # now, to the handler it would have reached
