"""The one check of what the UI reads from ROS: the status document and the
violation records.

Any node of the DDS domain can publish on the daemon's topics
(docs/reference/ros-interfaces.md, "What the status topic can be trusted for"), so
a document is bounded (size, nesting: :mod:`monitors.untrusted`) and every field the
page uses is type- and range-checked here, once, where it enters.  What passes is a
new document holding only the known fields, with the types the page relies on;
anything else is :class:`Untrusted` with one line naming the field
(``requirements[0].violations: ...``).  Unknown fields are dropped, not refused, so a
newer daemon still shows.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from typing import Any

from monitors.untrusted import Untrusted, load_json

SCHEMA = 1
# A document of 1,000 requirements with their last actions and 500 events is under
# 2 MB; 8 MB leaves room and still bounds a forged one.
MAX_STATUS_BYTES = 8 * 1024 * 1024
MAX_VIOLATION_BYTES = 1024 * 1024
MAX_DEPTH = 16  # the daemon's documents nest 5 deep; an event's detail a little more
MAX_ITEMS = 10_000  # requirements, inputs
MAX_EVENTS = 500  # the daemon's EVENTS_KEPT (supervisor/daemon/status.py)
MAX_ACTIONS = 50
MAX_TEXT = 16 * 1024  # one string (a requirement's text or formula)
MAX_NAME = 256  # an id, a name, a topic, a time
STATES = ("latched", "escalated", "debouncing", "violated", "cooldown", "holding")
NONFINITE = ("nan", "inf", "-inf")  # how the daemon writes them (json_safe)
# A margin is in its inputs' units (docs/reference/margins.md): past 1e12 of any unit
# it is no reading of a robot but a forged or broken value the page would draw.
MAX_MARGIN = 1e12

Check = Callable[[Any, str], Any]


def _default(check: Check, default: Any) -> Check:
    """What an absent field becomes (a document of an older daemon lacks some)."""
    check.default = default  # type: ignore[attr-defined]
    return check


def _fail(where: str, what: str, value: Any) -> Untrusted:
    shown = type(value).__name__ if not isinstance(value, str) else f"a string of {len(value)}"
    return Untrusted(f"{where}: must be {what}, not {shown}")


def text(limit: int = MAX_TEXT, *, optional: bool = True, empty: bool = True) -> Check:
    def check(v: Any, where: str) -> Any:
        if v is None and optional:
            return None
        if not isinstance(v, str) or len(v) > limit or (not empty and not v):
            what = f"{'a non-empty ' if not empty else 'a '}string of at most {limit} characters"
            raise _fail(where, what + (" or null" if optional else ""), v)
        return v

    return _default(check, None)


def integer(*, optional: bool = False, minimum: int = 0) -> Check:
    def check(v: Any, where: str) -> Any:
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum or v >= 2**63:
            raise _fail(where, f"a whole number >= {minimum}", v)
        return v

    return _default(check, None if optional else 0)


def number(*, optional: bool = False, minimum: float | None = 0.0) -> Check:
    def check(v: Any, where: str) -> Any:
        if v is None and optional:
            return None
        if (
            isinstance(v, bool)
            or not isinstance(v, int | float)
            or not math.isfinite(v)
            or (minimum is not None and v < minimum)
        ):
            low = "" if minimum is None else f" >= {minimum:g}"
            raise _fail(where, f"a finite number{low}" + (" or null" if optional else ""), v)
        return v

    return _default(check, None if optional else 0.0)


def boolean(*, optional: bool = False) -> Check:
    def check(v: Any, where: str) -> Any:
        if v is None and optional:
            return None
        if not isinstance(v, bool):
            raise _fail(where, "true or false" + (" or null" if optional else ""), v)
        return v

    return _default(check, None if optional else False)


def one_of(*allowed: str) -> Check:
    def check(v: Any, where: str) -> Any:
        if v not in allowed or not isinstance(v, str):
            raise _fail(where, "one of " + ", ".join(allowed), v)
        return v

    return check


def value(v: Any, where: str) -> Any:
    """An input's value: bool, int64, double, the daemon's spelling of a non-finite
    double, or null before the first message."""
    if v is None or isinstance(v, bool) or v in NONFINITE:
        return v
    if isinstance(v, int) and -(2**63) <= v < 2**63:
        return v
    if isinstance(v, float) and math.isfinite(v):
        return v
    raise _fail(where, 'a bool, a number, "nan", "inf", "-inf" or null', v)


def within(limit: float) -> Check:
    """A finite number from -limit to limit, or null."""

    def check(v: Any, where: str) -> Any:
        if v is None:
            return None
        if (
            isinstance(v, bool)
            or not isinstance(v, int | float)
            or not math.isfinite(v)
            or abs(v) > limit
        ):
            raise _fail(where, f"a finite number within +-{limit:g} or null", v)
        return float(v)

    return _default(check, None)


def margin_value(v: Any, where: str) -> Any:
    """A margin: finite and within MAX_MARGIN, or the daemon's spelling of a boolean
    atom's infinite one ("inf", "-inf"); never NaN."""
    if isinstance(v, str) and v in ("inf", "-inf"):
        return v
    if (
        v is None
        or isinstance(v, bool)
        or not isinstance(v, int | float)
        or not math.isfinite(v)
        or abs(v) > MAX_MARGIN
    ):
        raise _fail(where, f'a finite number within +-{MAX_MARGIN:g}, "inf" or "-inf"', v)
    return float(v)


def optional(check: Check) -> Check:
    """``check``, or null."""

    def inner(v: Any, where: str) -> Any:
        return None if v is None else check(v, where)

    return _default(inner, None)


def any_text(v: Any, where: str) -> Any:
    """A free-form detail: a string as is, anything else as its JSON text."""
    if v is None or isinstance(v, str):
        return text()(v, where)
    return text()(json.dumps(v), where)


def scalar(v: Any, where: str) -> Any:
    """An event field the daemon copies from a record: a scalar, shown as text."""
    if v is None or isinstance(v, bool | int):
        return v
    if isinstance(v, float):
        return number(minimum=None)(v, where)
    return text()(v, where)


def listof(item: Check, limit: int) -> Check:
    def check(v: Any, where: str) -> Any:
        if not isinstance(v, list) or len(v) > limit:
            raise _fail(where, f"a list of at most {limit}", v)
        return [item(x, f"{where}[{i}]") for i, x in enumerate(v)]

    return _default(check, [])


def record(fields: dict[str, Check], required: tuple[str, ...] = ()) -> Check:
    """An object: the known ``fields`` checked (absent ones as their default), others
    dropped."""

    def check(v: Any, where: str) -> Any:
        if not isinstance(v, dict):
            raise _fail(where or "the document", "an object", v)
        out = {}
        for k, f in fields.items():
            if k in v:
                out[k] = f(v[k], _join(where, k))
            elif k in required:
                raise Untrusted(f"{_join(where, k)}: missing")
            else:
                out[k] = copy.deepcopy(getattr(f, "default", None))
        return out

    return _default(check, {k: getattr(f, "default", None) for k, f in fields.items()})


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _schema(v: Any, where: str) -> Any:
    if v != SCHEMA or isinstance(v, bool):
        raise _fail(where, f"{SCHEMA} (the schema this UI reads)", v)
    return v


NAME = text(MAX_NAME)
ACTION = record(
    {
        "action": NAME,
        "stage": NAME,
        "ok": boolean(optional=True),
        "ts": NAME,
        "latency_ms": number(optional=True),
        "dry_run": boolean(optional=True),
    }
)
PREDICTION = record(
    {
        "tick": integer(optional=True),
        "since_ms": number(optional=True),
        "ttv_ms": number(optional=True),
    }
)
MARGIN = record(
    {
        "value": margin_value,
        # margin units per second: the predictor's slope, or a difference
        "trend_per_s": within(MAX_MARGIN),
        "trend_from": optional(one_of("predictor", "difference")),
        "unit": NAME,
        "prediction": optional(PREDICTION),
    },
    required=("value",),
)
REQUIREMENT = record(
    {
        "id": text(MAX_NAME, optional=False, empty=False),
        "text": text(),
        "formula": text(),
        "state": one_of(*STATES),
        "violations": integer(),
        "last_violation": NAME,
        "last_tick": integer(optional=True),
        "stale_inputs": listof(text(MAX_NAME, optional=False), MAX_ITEMS),
        "actions": listof(ACTION, MAX_ACTIONS),
        "margin": optional(MARGIN),  # null: margins off (or no step yet)
    },
    required=("id", "state"),
)
INPUT = record(
    {
        "name": text(MAX_NAME, optional=False, empty=False),
        "topic": NAME,
        "type": NAME,
        # "float32": the value is a float32 field's, shown at that precision
        "precision": NAME,
        "value": value,
        "age_s": number(optional=True),
        "stale": boolean(),
        "messages": integer(),
        "lost": integer(),
    },
    required=("name",),
)
EVENT = record(
    {
        "event": NAME,
        "ts": NAME,
        "requirement": NAME,
        "what": scalar,
        "action": NAME,
        "ok": boolean(optional=True),
        "stage": NAME,
        "tick": integer(optional=True),
        "reason": scalar,
        "input": NAME,
        "detail": any_text,
        "error": any_text,
    }
)
STATUS = record(
    {
        "schema": _schema,
        "supervisor": text(MAX_NAME, optional=False, empty=False),
        "component": NAME,
        "config": text(4096),
        "config_sha256": NAME,
        "pid": integer(optional=True),
        "started": NAME,
        "now": NAME,
        "uptime_s": number(),
        "policy": NAME,
        "ticks": integer(),
        "tick_rate_hz": number(),
        "receive_rate_hz": number(),
        "received": integer(),
        "lost": integer(),
        "violations": integer(),
        "reloads": integer(),
        "recording": boolean(),
        "watchdog": record({"enabled": boolean(), "interval_s": number(optional=True)}),
        # shown only: resets go where the UI's own configuration says (command.py)
        "control_socket": text(4096),
        "requirements": listof(REQUIREMENT, MAX_ITEMS),
        "inputs": listof(INPUT, MAX_ITEMS),
        "events": listof(EVENT, MAX_EVENTS),
        "events_dropped": integer(),
        "status_period_s": number(optional=True),
    },
    required=("schema", "supervisor"),
)
VIOLATION = record(
    {
        "event": one_of("violation"),
        "ts": NAME,
        "requirement": text(MAX_NAME, optional=False, empty=False),
        "tick": integer(optional=True),
        "text": text(),
        "formula": text(),
        "inputs": lambda v, where: _inputs(v, where),
    },
    required=("requirement",),
)


def _inputs(v: Any, where: str) -> dict[str, Any]:
    if v is None:
        return {}
    if not isinstance(v, dict) or len(v) > MAX_ITEMS:
        raise _fail(where, f"an object of at most {MAX_ITEMS} input values", v)
    return {text(MAX_NAME)(k, where): value(x, f"{where}.{k}") for k, x in v.items()}


def parse_status(data: bytes | str) -> dict[str, Any]:
    """The status document of ``data``, checked; :class:`Untrusted` otherwise."""
    doc = load_json(data, max_bytes=MAX_STATUS_BYTES, max_depth=MAX_DEPTH)
    if not isinstance(doc, dict):
        raise Untrusted(f"not an object but {type(doc).__name__}")
    return STATUS(doc, "")


def parse_violation(data: bytes | str) -> dict[str, Any]:
    """A violation record of the violations topic, checked; :class:`Untrusted` otherwise."""
    doc = load_json(data, max_bytes=MAX_VIOLATION_BYTES, max_depth=MAX_DEPTH)
    if not isinstance(doc, dict):
        raise Untrusted(f"not an object but {type(doc).__name__}")
    return VIOLATION(doc, "")
