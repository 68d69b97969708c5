"""One reader per input variable: a message in, the variable's value out
(docs/reference/config.md, "Inputs from real robots").

Kinds of input, by what the value is:
- ``value``: a field (``field:``), maybe an element (``ranges[0]``) or one value
  made of an array (``reduce:``); also a field of a service call's request or
  response, or how many goals of an action are in some states;
- ``event``: true at the tick at which its message arrived (an estop button, a
  service call, an action goal entering a state);
- ``age``: the time from an input's message stamp to the tick, in ms;
- ``rate``: an input's messages per second over a window.
A reader returns ``SKIP`` when its message carries nothing for the variable (a
service event of the other direction, a status message where no goal changed).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import chain
from typing import Any, Protocol

from mitigations.rosmsg import COMPATIBLE, message_class
from monitors.errors import UserError
from supervisor.inputs.interfaces import GOAL_STATUS, SERVICE_CALLS
from supervisor.inputs.paths import (
    FieldPath,
    ReadError,
    element_type,
    nested_class,
    parse_path,
    path_type,
)
from supervisor.inputs.paths import reader as path_reader
from supervisor.inputs.reductions import reduce_values, reduction_type

C_TYPES = {"bool": "bool", "int64": "int64_t", "double": "double"}
STAMP_TYPE = "builtin_interfaces/Time"
DEFAULT_STAMP = "header.stamp"


class _Skip:
    def __repr__(self) -> str:
        return "SKIP"


SKIP: Any = _Skip()  # this message carries no value for the variable


class InputVariable(Protocol):
    """What a reader needs of a configured variable (supervisor.config.model.Variable)."""

    name: str
    type: str
    topic: str | None
    msg: str | None
    field: str
    event: bool
    reduce: str | None
    service: str | None
    srv: str | None
    call: str | None
    action: str | None
    statuses: tuple[str, ...]
    age_of: str | None
    rate_of: str | None
    stamp: str | None


def kind_of(v: InputVariable) -> str:
    if v.rate_of:
        return "rate"
    if v.age_of:
        return "age"
    return "event" if v.event else "value"


def sporadic(v: InputVariable) -> bool:
    """Silence is normal for it, so only its own ``stale_after_ms`` makes it stale:
    events, calls, goal states (published on change), ages and rates (which say
    silence themselves)."""
    return bool(v.event or v.service or v.action or v.age_of or v.rate_of)


def arrival_only(v: InputVariable) -> bool:
    """Its message's arrival alone is what it reads: a topic's event, a rate."""
    return bool(v.rate_of) or (v.event and not v.service and not v.action)


def plain_field(v: InputVariable) -> str | None:
    """The dotted field when the variable reads one primitive field as it is (what
    the CDR layout reader of supervisor/daemon/cdr.py reads without deserialising)."""
    if kind_of(v) != "value" or v.reduce or v.service or v.action:
        return None
    path = parse_path(v.field)
    return v.field if path.plain else None


# ------------------------------------------------------------ checking


@dataclass(frozen=True)
class Description:
    """What ``check`` says a variable reads (docs/reference/commands.md, "check")."""

    kind: str
    message: str  # the ROS type subscribed
    topic: str
    path: str  # what is read of each message, '' when only its arrival counts
    reduction: str  # '' if none
    c_type: str


def _leaf_check(klass: type, path: FieldPath, reduce: str | None, var_type: str, msg: str) -> None:
    pt = path_type(klass, path)
    array = element_type(pt.leaf)
    if reduce is not None:
        if not pt.many and array is None:
            raise UserError(
                f"field '{path}' of {msg} is {pt.leaf}, not an array: reduce needs one",
                hint="index an element (ranges[0]) or read the field without reduce",
            )
        reduction_type(reduce, array or pt.leaf, str(path), var_type)
        return
    if pt.many or array is not None:
        raise UserError(
            f"field '{path}' of {msg} is "
            + (f"a list of {pt.leaf}" if pt.many else pt.leaf)
            + ": one value is needed",
            hint="add reduce: (min, max, mean, sum, count, len, any, all) or index an element: "
            f"{path}[0]",
        )
    if pt.leaf not in COMPATIBLE[var_type]:
        raise UserError(
            f"field '{path}' of {msg} is {pt.leaf}, which cannot feed a {var_type} variable"
        )


def _service_part(v: InputVariable) -> type:
    """The class of the request or response a service variable reads."""
    assert v.msg is not None and v.call is not None
    event_class = message_class(v.msg)
    t = event_class.get_fields_and_field_types()[v.call]
    element = element_type(t)
    assert element is not None
    return nested_class(element)


def check_input(v: InputVariable) -> Description:
    """Validate what ``v`` reads against the installed message types; errors say
    which field is wrong."""
    kind = kind_of(v)
    assert v.msg is not None and v.topic is not None
    klass = message_class(v.msg)
    c_type = C_TYPES[v.type]
    if kind == "rate":
        return Description(kind, v.msg, v.topic, "", "", c_type)
    if kind == "age":
        stamp = parse_path(v.stamp or DEFAULT_STAMP)
        pt = path_type(klass, stamp)
        if pt.many or pt.leaf.replace("/msg/", "/") != STAMP_TYPE:
            raise UserError(
                f"'{stamp}' of {v.msg} is {pt.leaf}, not a time stamp ({STAMP_TYPE})",
                hint="name the stamp's field with stamp: (e.g. stamp: header.stamp)",
            )
        return Description(kind, v.msg, v.topic, str(stamp), "", c_type)
    if v.action:
        if v.type not in ("bool", "int64") or (v.event and v.type != "bool"):
            raise UserError(
                f"an action's goal states feed a bool (some goal is in them) or an int64 "
                f"(how many are), not a {v.type}"
            )
        what = "entered " if v.event else ("count " if v.type == "int64" else "any ")
        return Description(
            kind, v.msg, v.topic, "status_list[].status", what + "|".join(v.statuses), c_type
        )
    if v.service:
        if kind == "event":
            return Description(kind, v.msg, v.topic, f"{v.call}", "", c_type)
        part = _service_part(v)
        _leaf_check(part, parse_path(v.field), v.reduce, v.type, f"{v.srv} {v.call}")
        return Description(kind, v.msg, v.topic, f"{v.call}.{v.field}", v.reduce or "", c_type)
    if kind == "event":
        return Description(kind, v.msg, v.topic, "", "", c_type)
    _leaf_check(klass, parse_path(v.field), v.reduce, v.type, v.msg)
    return Description(kind, v.msg, v.topic, v.field, v.reduce or "", c_type)


def value_precision(v: InputVariable) -> str | None:
    """``'float32'`` when a double variable's value is a float32 field as it came (the
    field, an element, or the min or max of a float32 array), so a page shows it at
    that precision (0.8, not 0.800000011920929); ``None`` otherwise (the value is a
    double, an integer or a bool; docs/reference/ros-interfaces.md, "Status")."""
    if v.type != "double" or kind_of(v) != "value" or v.action or v.msg is None:
        return None
    if v.reduce not in (None, "min", "max"):
        return None  # a mean or a sum is computed in double
    try:
        klass = _service_part(v) if v.service else message_class(v.msg)
        pt = path_type(klass, parse_path(v.field))
    except (UserError, ReadError, LookupError, ValueError, TypeError):
        return None  # check says why; the page then shows the double
    leaf = (element_type(pt.leaf) or pt.leaf) if v.reduce else pt.leaf
    return "float32" if leaf == "float" else None  # rosidl's name of float32


# ------------------------------------------------------------ reading


def _stamp_ns(read: Callable[[Any], Any]) -> Callable[[Any], int]:
    def stamp(msg: Any) -> int:
        t = read(msg)
        return int(t.sec) * 1_000_000_000 + int(t.nanosec)

    return stamp


def _value_reader(path: FieldPath, reduce: str | None) -> Callable[[Any], Any]:
    read = path_reader(path)
    if reduce is None:
        return read
    many = path.many
    if many:  # a list of arrays (status[].values) is reduced as one array
        inner = read

        def flat(msg: Any) -> Any:
            items = inner(msg)
            first = items[0] if items else None
            if hasattr(first, "__len__") and not isinstance(first, str | bytes):
                return list(chain.from_iterable(items))
            return items

        read = flat
    last = path.segments[-1]
    if last.name == "ranges" and last.index is None and not many:
        # REP 117: a LaserScan's own range_min/range_max bound its readings.
        parent = path_reader(FieldPath(path.segments[:-1])) if len(path.segments) > 1 else None

        def ranges(msg: Any) -> Any:
            p = parent(msg) if parent is not None else msg
            bounds = None
            if hasattr(p, "range_min") and hasattr(p, "range_max"):
                bounds = (float(p.range_min), float(p.range_max))
            return reduce_values(p.ranges, reduce, bounds)

        return ranges

    def reduced(msg: Any) -> Any:
        return reduce_values(read(msg), reduce)

    return reduced


def _action_reader(v: InputVariable) -> Callable[[Any], Any]:
    codes = frozenset(GOAL_STATUS[n] for n in v.statuses)
    if not v.event:
        count = v.type == "int64"

        def state(msg: Any) -> Any:
            n = sum(1 for g in msg.status_list if int(g.status) in codes)
            return n if count else n > 0

        return state
    seen: dict[bytes, int] = {}

    def entered(msg: Any) -> Any:
        """A goal is in the states now and was not at the previous message."""
        now = {bytes(g.goal_info.goal_id.uuid): int(g.status) for g in msg.status_list}
        new = any(s in codes and seen.get(k) not in codes for k, s in now.items())
        seen.clear()
        seen.update(now)
        return True if new else SKIP

    return entered


def _service_reader(v: InputVariable) -> Callable[[Any], Any]:
    assert v.call is not None
    calls = SERVICE_CALLS[v.call]
    part_name = v.call
    if v.event:

        def called(msg: Any) -> Any:
            return True if int(msg.info.event_type) in calls else SKIP

        return called
    read = _value_reader(parse_path(v.field), v.reduce)

    def field(msg: Any) -> Any:
        if int(msg.info.event_type) not in calls:
            return SKIP
        items = getattr(msg, part_name)
        if not len(items):
            raise ReadError(
                f"the {part_name} has no contents: the service's introspection is set "
                "to metadata only (configure_introspection(..., CONTENTS))"
            )
        return read(items[0])

    return field


def make_reader(v: InputVariable) -> Callable[[Any], Any]:
    """The function the daemon and replay call on each message of ``v``'s topic
    (after check_input has accepted ``v``).  It may raise paths.ReadError."""
    kind = kind_of(v)
    if kind == "rate":
        return lambda msg: None  # the arrival is counted by the runtime
    if kind == "age":
        return _stamp_ns(path_reader(parse_path(v.stamp or DEFAULT_STAMP)))
    if v.action:
        return _action_reader(v)
    if v.service:
        return _service_reader(v)
    if kind == "event":
        return lambda msg: True
    return _value_reader(parse_path(v.field), v.reduce)
