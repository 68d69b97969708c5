"""The violation log's writing interface with every record dropped.

The daemon's core writes six kinds of record (``violation``, ``mitigation``,
``reset``, ``supervisor``, ``prediction``, ``prediction_expired``; docs/reference/log.md).
A sink that keeps only some of them (``fleet replay``'s violations table, ``report``'s
windows) subclasses :class:`DiscardingLog` and overrides those, so that a new kind of
record is added here once rather than to every such sink.
"""

from __future__ import annotations

from typing import Any


class DiscardingLog:
    """Accepts every record (returns True, as a written one) and keeps none."""

    def violation(self, requirement: str, **fields: Any) -> bool:
        return True

    def mitigation(self, requirement: str, **fields: Any) -> bool:
        return True

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        return True

    def supervisor(self, what: str, **fields: Any) -> bool:
        return True

    def prediction(self, requirement: str, **fields: Any) -> bool:
        return True

    def prediction_expired(self, requirement: str, **fields: Any) -> bool:
        return True
