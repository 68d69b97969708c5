"""``log`` mitigations: the record is the action (no effect on the robot)."""

from __future__ import annotations

import threading
from collections.abc import Callable

from mitigations.actions.base import Outcome
from mitigations.settings import LogSettings


class LogAction:
    kind = "log"
    inline = False  # the engine's record of it is all it does; made off the loop like any other

    def __init__(self, name: str, settings: LogSettings) -> None:
        self.name = name
        self.message = settings.message

    def run(self, cancel: threading.Event, on_attempt: Callable[[Outcome], None]) -> Outcome:
        out = Outcome(ok=True, detail={"message": self.message} if self.message else {})
        on_attempt(out)
        return out
