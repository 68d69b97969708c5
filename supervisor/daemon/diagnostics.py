"""``/diagnostics`` (diagnostic_msgs/DiagnosticArray, REP 107): one status per
requirement and one per input, so rqt_runtime_monitor and robot dashboards
show what the supervisor sees without reading its log."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


def _status(
    level: bytes, name: str, message: str, hardware_id: str, values: Mapping[str, Any]
) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )


def requirement_status(
    node: str, component: str, rid: str, state: Mapping[str, Any], violated_now: bool
) -> DiagnosticStatus:
    latched = bool(state.get("latched"))
    if latched:
        level, message = ERROR, "violated; mitigation latched until operator reset"
    elif violated_now:
        level, message = ERROR, "violated"
    else:
        level, message = OK, "holds"
    return _status(level, f"{node}: requirement {rid}", message, component, state)


def input_status(
    node: str, component: str, name: str, topic: str, stats: Mapping[str, Any], now_ns: int
) -> DiagnosticStatus:
    last = stats.get("last_ns")
    values = {
        "topic": topic,
        "messages": stats.get("messages", 0),
        "rejected": stats.get("rejected", 0),
        "age_ms": "never" if last is None else f"{(now_ns - last) / 1e6:.0f}",
        "publishers": stats.get("publishers", "?"),
        # Skipped publication sequence numbers; per publisher stream as told
        # apart by continuity (docs/reference/ros-interfaces.md).
        "lost": stats.get("lost", 0),
        "lost_by_publisher": " ".join(
            f"{p['lost']}/{p['received'] + p['lost']}" for p in stats.get("by_publisher", ())
        ),
        "own_messages": stats.get("own", 0),
    }
    if last is None:
        level, message = ERROR, "no message received yet"
    elif stats.get("stale"):
        level, message = ERROR, "stale"
    elif stats.get("lost_recent"):
        level, message = WARN, f"lost {stats['lost_recent']} messages since the last report"
    elif stats.get("problem"):
        level, message = WARN, str(stats["problem"])
    else:
        level, message = OK, "receiving"
    return _status(level, f"{node}: input {name}", message, component, values)


def diagnostic_array(stamp: Any, statuses: Sequence[DiagnosticStatus]) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg
