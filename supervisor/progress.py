"""Progress for a person at a terminal, and only there, so that CI and logs stay
as they were: ``check``'s one line per stage (parse, formalize, unroll, each
analysis, compile) with its elapsed time (`Progress`), and the line that
``replay``, ``report`` and ``fleet`` redraw in place as they read (`Line`)
(docs/reference/commands.md)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO


def on_terminal(stream: TextIO) -> bool:
    """Whether ``stream`` is a terminal; a closed or odd stream is not."""
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class Line:
    """One line on ``stream`` (stderr), redrawn in place with ``\\r`` when it is a
    terminal and ``on`` is not False; silent otherwise. `end` closes it, so that
    whatever is printed next starts on a line of its own."""

    def __init__(self, label: str, stream: TextIO | None = None, *, on: bool | None = None) -> None:
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.on = on_terminal(self.stream) if on is None else on
        self.drawn = False

    def show(self, text: str) -> None:
        if self.on:
            # the trailing blanks wipe what a longer earlier text left
            self.stream.write(f"\r{self.label}: {text}  ")
            self.stream.flush()
            self.drawn = True

    def messages(self, done: int, total: int | None) -> None:
        """The readers' callback: messages read so far, of ``total`` when known."""
        pct = f" of {total:,} ({100 * done / total:.0f} %)" if total else ""
        self.show(f"{done:,} messages{pct}")

    def end(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


class Progress:
    """Stage lines on ``stream`` when it is a terminal; silent otherwise."""

    def __init__(self, stream: TextIO | None = None, *, on: bool | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.on = on_terminal(self.stream) if on is None else on
        self._t0 = 0.0

    def start(self, name: str) -> None:
        """The stage begins: its name now, so a long one shows what is running."""
        self._t0 = time.perf_counter()
        if self.on:
            self.stream.write(f"safety-supervisor: {name} ... ")
            self.stream.flush()

    def done(self, seconds: float | None = None) -> None:
        """The stage ended after ``seconds`` (default: since ``start``)."""
        if seconds is None:
            seconds = time.perf_counter() - self._t0
        if self.on:
            self.stream.write(f"{seconds:.2f} s\n")
            self.stream.flush()

    def step(self, name: str, seconds: float | None) -> None:
        """The analyses' callback: ``seconds`` None when ``name`` starts."""
        if seconds is None:
            self.start(name)
        else:
            self.done(seconds)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        self.start(name)
        try:
            yield
        finally:
            self.done()
