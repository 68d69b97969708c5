"""Stopping ``fleet replay``'s processes whole: a Ctrl-C that comes while the local
pool's workers and its fork server are being stopped waits for the stop to end, then
interrupts as usual (docs/reference/commands.md, "fleet replay")."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """SIGINT held off in the block and raised once it ends: a second Ctrl-C during a
    stop (a ``waitpid``, a pool's shutdown) would otherwise cut it short, leaving
    workers running and the standard library's fork server half stopped."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread gets Python's signal handlers
        return
    came: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        came.append(signum)

    previous = signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)
    if came:
        signal.raise_signal(signal.SIGINT)  # now, to the handler it would have reached
