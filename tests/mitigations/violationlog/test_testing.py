"""The shipped in-memory violation log (mitigations.violationlog.testing): the
writer's interface, each call one record, in order."""

from __future__ import annotations

import inspect
from typing import Any

from mitigations.violationlog.testing import MemoryLog
from mitigations.violationlog.writer import ViolationLog

WRITES = ("violation", "mitigation", "reset", "supervisor")


def test_it_is_called_as_the_writer_is() -> None:
    # the same positional and keyword-only names as the real writer's methods: a call
    # that works on one works on the other
    for name in WRITES:
        real = inspect.signature(getattr(ViolationLog, name)).parameters
        double = inspect.signature(getattr(MemoryLog, name)).parameters
        required = [
            p.name
            for p in real.values()
            if p.default is inspect.Parameter.empty
            and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)
            and p.name != "self"
        ]
        for p in required:
            assert p in double or any(d.kind is d.VAR_KEYWORD for d in double.values()), (name, p)
        positional = [p for p in real.values() if p.kind is p.POSITIONAL_OR_KEYWORD]
        assert [p.name for p in positional] == [
            p.name for p in double.values() if p.kind is p.POSITIONAL_OR_KEYWORD
        ], name


def test_each_write_is_one_record_in_order() -> None:
    seen: list[dict[str, Any]] = []
    log = MemoryLog(seen.append)
    assert log.violation("r1", tick=3, inputs={"x": 1}) is True
    assert log.mitigation("r1", action="stop", ok=True, latency_ms=0.5) is True
    assert log.reset("*", reason="operator reset", tick=9) is True
    assert log.supervisor("input_stale", input="x") is True
    assert log.records == [
        {"event": "violation", "requirement": "r1", "tick": 3, "inputs": {"x": 1}},
        {
            "event": "mitigation",
            "requirement": "r1",
            "action": "stop",
            "ok": True,
            "latency_ms": 0.5,
        },
        {"event": "reset", "requirement": "*", "reason": "operator reset", "tick": 9},
        {"event": "supervisor", "what": "input_stale", "input": "x"},
    ]
    assert seen == log.records
    assert log.of("reset") == [log.records[2]]
