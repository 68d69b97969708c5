"""Test doubles for code that writes the violation log, shipped with the package
(as ``structlog.testing`` is) so that users' tests need not write their own.

:class:`MemoryLog` has the writing interface the daemon's core uses
(``violation``, ``mitigation``, ``reset``, ``supervisor``, ``prediction``,
``prediction_expired``, as
:class:`mitigations.violationlog.writer.ViolationLog` has them) and keeps each
call as one record in memory: no file, no hash chain, no fsync.  The fields are
kept as given, not rendered: the writer's own format is tested against the file
(docs/reference/log.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class MemoryLog:
    """A violation log in a list.  Each record is ``{"event": ..., <the fields>}``,
    ``requirement`` or ``what`` first, in the order written; ``on_record`` (when
    given) sees each one as it is added.  Every write succeeds (returns True)."""

    def __init__(self, on_record: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.records: list[dict[str, Any]] = []
        self._on_record = on_record

    def _add(self, event: str, fields: dict[str, Any]) -> bool:
        record = {"event": event, **fields}
        self.records.append(record)
        if self._on_record is not None:
            self._on_record(record)
        return True

    def violation(self, requirement: str, **fields: Any) -> bool:
        return self._add("violation", {"requirement": requirement, **fields})

    def mitigation(self, requirement: str, **fields: Any) -> bool:
        return self._add("mitigation", {"requirement": requirement, **fields})

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        return self._add("reset", {"requirement": requirement, "reason": reason, **extra})

    def supervisor(self, what: str, **fields: Any) -> bool:
        return self._add("supervisor", {"what": what, **fields})

    def prediction(self, requirement: str, **fields: Any) -> bool:
        return self._add("prediction", {"requirement": requirement, **fields})

    def prediction_expired(self, requirement: str, **fields: Any) -> bool:
        return self._add("prediction_expired", {"requirement": requirement, **fields})

    def of(self, event: str) -> list[dict[str, Any]]:
        """The records of one event kind (``violation``, ``supervisor``, ...)."""
        return [r for r in self.records if r["event"] == event]
