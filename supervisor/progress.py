"""``check``'s progress on stderr: one line per stage (parse, formalize, unroll,
each analysis, compile) with its elapsed time, written only when stderr is a
terminal, so that CI and logs stay as they were (docs/reference/commands.md,
"check")."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO


class Progress:
    """Stage lines on ``stream`` when it is a terminal; silent otherwise."""

    def __init__(self, stream: TextIO | None = None, *, on: bool | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        if on is None:
            try:
                on = self.stream.isatty()
            except (AttributeError, ValueError):  # a closed or odd stream: stay silent
                on = False
        self.on = on
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
