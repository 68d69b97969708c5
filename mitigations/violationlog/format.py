"""The violation log's on-disk format: record layout, hash chain, one-line rendering.

Format (written by :mod:`mitigations.violationlog.writer`, read by :mod:`mitigations.violationlog.reader`): JSON lines, ASCII, one object per
line, ``\\n``-terminated.  Every record starts with ``ts``, ``event``,
``component``, ``config_sha256``, ``prev_sha256``, ``seq`` and ends with ``line_sha256``.

``seq`` numbers the records one writer makes (1, 2, ...; across rotated files; a new
writer starts at 1).  A gap is accounted for by the ``supervisor`` record
``what=records_lost`` that follows it, naming the missing numbers (docs/reference/log.md).

Hash chain, per file:

* ``prev_sha256`` is the SHA-256 (hex) of the previous line's bytes including
  its newline; the first line of a file carries the hash of the empty string.
  Each file therefore verifies on its own (logrotate may compress or delete
  older files without breaking the newer ones).
* ``line_sha256`` is the SHA-256 of the line itself (including the newline)
  with this field's value replaced by 64 zeros.  It lets ``--verify`` name the
  line that was edited, rather than the line after it.
* Across rotation the files are linked, not chained: after ``reopen()`` the
  writer's first record in the (new) file is a ``supervisor`` record
  ``what="log_reopened"`` whose ``previous_last_sha256`` is the hash of the
  last line written to the old file.  ``--verify old new`` reports the link.
* A line left incomplete by a crash or a full disk is terminated by the writer
  when it next writes, and the next record chains over it, so such a line in
  the middle of a file is a warning, not a break.  An incomplete *final* line
  cannot be told from a truncated file and fails verification.

What the chain cannot show: a file whose last whole lines were removed (unless
a later file's link names them), or a file rewritten from scratch by someone
who recomputes the hashes; it has no key.

Non-finite floats, which JSON lacks, are written as the strings ``"nan"``,
``"inf"`` and ``"-inf"``.

Since anyone can write a log that verifies, a record is checked against one schema
where a line is read (:func:`parse_record`, used by the reader): its size and
nesting, and each event's fields with their types and ranges.  What the readers do
with a record that fails: docs/reference/faults.md, "Trust".

This package uses the standard library only (the writer adds structlog), so the CLI stays quick to start.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Any

from monitors.untrusted import Untrusted, load_json

HEADER = ("ts", "event", "component", "config_sha256", "prev_sha256", "seq")
EMPTY_SHA256 = hashlib.sha256(b"").hexdigest()
ZERO_SHA256 = "0" * 64
EVENTS = ("violation", "mitigation", "reset", "supervisor", "prediction", "prediction_expired")
# logging.durability (docs/reference/log.md): when a durable record is fsynced relative
# to the actions of the same turn of the daemon's loop.  after_publish: written
# (page cache) before the actions, fsynced after the inline ones are out;
# before_action: fsynced before any action.
DURABILITIES = ("after_publish", "before_action")
DURABILITY = "after_publish"
RETRY_BUFFER = 1000  # records kept in memory while the log cannot be written (default)

_LINE_HASH_RE = re.compile(rb',"line_sha256":"([0-9a-f]{64})"\}\n\Z')
_PREV_RE = re.compile(rb'"prev_sha256":"([0-9a-f]{64})"')


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def seal_line(body: bytes) -> bytes:
    """Append ``line_sha256`` to a rendered JSON object ``{...}`` (no newline)."""
    assert body.endswith(b"}")
    placeholder = body[:-1] + b',"line_sha256":"' + ZERO_SHA256.encode() + b'"}\n'
    digest = sha256_hex(placeholder).encode()
    return placeholder[: -len(ZERO_SHA256) - 3] + digest + b'"}\n'


def line_seal_ok(line: bytes) -> bool | None:
    """True/False when the line carries a ``line_sha256``; None when it has none."""
    m = _LINE_HASH_RE.search(line)
    if m is None:
        return None
    zeroed = line[: m.start(1)] + ZERO_SHA256.encode() + line[m.end(1) :]
    return sha256_hex(zeroed) == m.group(1).decode()


def json_safe(value: Any) -> Any:
    """JSON has no NaN/Infinity: write them as the strings "nan", "inf", "-inf"."""
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [json_safe(v) for v in value]
    return value


def _fmt_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def details(rec: dict[str, Any]) -> str:
    """The event-specific part of a record, as ``key=value`` words."""
    ev = rec.get("event")
    if ev == "violation":
        parts = [f"tick={rec.get('tick')}"]
        parts += [f"{k}={_fmt_value(v)}" for k, v in (rec.get("inputs") or {}).items()]
        if rec.get("stale"):
            parts.append("stale=" + ",".join(map(str, rec["stale"])))
        return " ".join(parts)
    if ev == "mitigation":
        res = "ok" if rec.get("ok") else f"FAILED ({rec.get('error')})"
        return (
            f"{rec.get('kind')}:{rec.get('action')} {res} "
            f"latency_ms={rec.get('latency_ms')} attempt={rec.get('attempt')}"
        )
    if ev == "reset":
        return f"reason={rec.get('reason')}"
    if ev == "prediction":
        return (
            f"tick={rec.get('tick')} ttv_ms={_fmt_value(rec.get('ttv_ms'))} "
            f"[{_fmt_value(rec.get('ttv_lo_ms'))}, {_fmt_value(rec.get('ttv_hi_ms'))}] "
            f"margin={_fmt_value(rec.get('margin'))} slope={_fmt_value(rec.get('slope'))} "
            f"confidence={_fmt_value(rec.get('confidence'))}"
        )
    if ev == "prediction_expired":
        return (
            f"predicted_tick={rec.get('predicted_tick')} "
            f"horizon_ms={_fmt_value(rec.get('horizon_ms'))}"
        )
    skip = {*HEADER, "line_sha256", "what"}
    extra = [f"{k}={_fmt_value(v)}" for k, v in rec.items() if k not in skip and k[:1] != "_"]
    return " ".join([str(rec.get("what"))] + extra)


def describe(rec: dict[str, Any]) -> str:
    """One human-readable line for a record (stderr/journald), e.g.
    ``VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2``."""
    label = str(rec.get("event", "?")).upper()
    req = rec.get("requirement")
    return f"{label} {req} {details(rec)}" if req else f"{label} {details(rec)}"


# ---------------------------------------------------------------- the record schema

# One line: a violation with ``logging.recent`` at its maximum (10,000 ticks) of a few
# dozen inputs.  Nesting: the writer's records nest 4 levels (record, recent, row).
MAX_LINE = 16 * 1024 * 1024
MAX_DEPTH = 16
MAX_ID = 256  # a requirement, action, kind, input or ``what``
MAX_RECENT = 10_000  # rows of ``recent`` (the config's logging.recent maximum)
MAX_TICK = 2**63 - 1  # the monitor's tick is an int64
# A robot without a real-time clock boots in 1970; nothing is logged after 2200.
TS_RANGE = (datetime(1970, 1, 1, tzinfo=UTC), datetime(2200, 1, 1, tzinfo=UTC))
_NON_FINITE = ("nan", "inf", "-inf")


class BadRecord(Untrusted):
    """A line that is not a record of this format; ``str`` is one line."""


def parse_time(text: Any, key: str = "ts") -> datetime:
    """A record's ISO 8601 time (UTC when it names no zone), within ``TS_RANGE``."""
    if not isinstance(text, str) or len(text) > 64:
        raise BadRecord(f"{key} is not an ISO 8601 time")
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError:
        raise BadRecord(f"{key} is not an ISO 8601 time") from None
    t = t if t.tzinfo is not None else t.replace(tzinfo=UTC)
    if not TS_RANGE[0] <= t < TS_RANGE[1]:
        raise BadRecord(f"{key} is not between the years 1970 and 2199")
    return t


def _type(v: Any) -> str:
    return "null" if v is None else type(v).__name__


def _ident(key: str, v: Any) -> None:
    if not isinstance(v, str) or not 0 < len(v) <= MAX_ID:
        raise BadRecord(f"{key} must be a string of 1 to {MAX_ID} characters, not {_type(v)}")


def _string(key: str, v: Any) -> None:
    if not isinstance(v, str):
        raise BadRecord(f"{key} must be a string, not {_type(v)}")


def _opt_string(key: str, v: Any) -> None:
    if v is not None:
        _string(key, v)


def _tick(key: str, v: Any) -> None:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= MAX_TICK:
        raise BadRecord(f"{key} must be a whole number from 0 to 2^63-1")


def _count(key: str, v: Any) -> None:
    _tick(key, v)


def _bool(key: str, v: Any) -> None:
    if not isinstance(v, bool):
        raise BadRecord(f"{key} must be true or false, not {_type(v)}")


def _number(key: str, v: Any) -> None:
    """A number (an integer within int64), null, or JSON's stand-in for a non-finite one."""
    ok = v is None or v in _NON_FINITE or isinstance(v, float)
    # an int64 (the monitor's integers); JSON's are unbounded
    ok = ok or (isinstance(v, int) and not isinstance(v, bool) and -(2**63) <= v < 2**63)
    if not ok:
        raise BadRecord(f"{key} must be a number, not {_type(v)}")


def _scalar(key: str, v: Any) -> None:
    """An input's value: a Boolean, a number, null (no value yet) or "nan"/"inf"/"-inf"."""
    if isinstance(v, str) and v not in _NON_FINITE:
        raise BadRecord(f"{key} must be a Boolean or a number, not a string")
    if not isinstance(v, bool):
        _number(key, v)


def _inputs(key: str, v: Any) -> None:
    if not isinstance(v, dict):
        raise BadRecord(f"{key} must be a mapping of input names to values, not {_type(v)}")
    for name, x in v.items():
        if not 0 < len(name) <= MAX_ID:
            raise BadRecord(f"{key} has a name of more than {MAX_ID} characters")
        _scalar(f"{key}.{name[:40]!r}", x)


def _recent(key: str, v: Any) -> None:
    if not isinstance(v, list) or len(v) > MAX_RECENT:
        raise BadRecord(f"{key} must be a list of at most {MAX_RECENT} ticks")
    for i, row in enumerate(v):
        if not isinstance(row, dict):
            raise BadRecord(f"{key}[{i}] must be a mapping, not {_type(row)}")
        _tick(f"{key}[{i}].tick", row.get("tick"))
        _inputs(f"{key}[{i}]", {k: x for k, x in row.items() if k != "tick"})


def _strings(key: str, v: Any) -> None:
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise BadRecord(f"{key} must be a list of strings")


def _flat(key: str, v: Any) -> None:
    if not isinstance(v, dict) or any(isinstance(x, dict | list) for x in v.values()):
        raise BadRecord(f"{key} must be a mapping of names to single values")


def _mapping(key: str, v: Any) -> None:
    if not isinstance(v, dict):
        raise BadRecord(f"{key} must be a mapping, not {_type(v)}")


def _sha256(key: str, v: Any) -> None:
    # the writer's is hex; the chain checks the hashes themselves, here only the shape
    if not isinstance(v, str) or len(v) > 64:
        raise BadRecord(f"{key} must be a SHA-256 (a string of at most 64 characters)")


MAX_IMPORTS = 1000  # a config's imported files a record may name


def _digests(key: str, v: Any) -> None:
    ok = (
        isinstance(v, dict)
        and len(v) <= MAX_IMPORTS
        and all(isinstance(k, str) and len(k) <= 4096 for k in v)
        and all(isinstance(d, str) and len(d) <= 64 for d in v.values())
    )
    if not ok:
        raise BadRecord(f"{key} must map at most {MAX_IMPORTS} file names to SHA-256s")


def _ranges(key: str, v: Any) -> None:
    ok = isinstance(v, list) and all(
        isinstance(r, list)
        and len(r) == 2
        and all(isinstance(x, int) and not isinstance(x, bool) for x in r)
        for r in v
    )
    if not ok:
        raise BadRecord(f"{key} must be a list of [first, last] seq numbers")


def _any(key: str, v: Any) -> None:
    pass


Check = Callable[[str, Any], None]
# Each event's fields: name -> (check, required).  Fields not named are kept as they
# are (any JSON within the size and depth bounds): an older or newer writer's.  The
# chain's fields are the verifier's to require; a reader needs the time and event.
_COMMON: dict[str, tuple[Check, bool]] = {
    "event": (_any, True),  # checked first, below
    "component": (_ident, False),
    "config_sha256": (_sha256, False),
    "prev_sha256": (_string, False),
    "seq": (_count, False),
    "line_sha256": (_string, False),
    "dry_run": (_bool, False),
}
SCHEMA: dict[str, dict[str, tuple[Check, bool]]] = {
    "violation": {
        "requirement": (_ident, True),
        "tick": (_tick, True),
        "inputs": (_inputs, True),
        "text": (_string, False),
        "formula": (_string, False),
        "formula_inputs": (_string, False),
        "recent": (_recent, False),
        "stale": (_strings, False),
        "policy_state": (_flat, False),
        "predicted_ms": (_number, False),
    },
    # docs/reference/prediction.md, "Records"
    "prediction": {
        "requirement": (_ident, True),
        "tick": (_tick, True),
        "margin": (_number, True),
        "slope": (_number, True),
        "ttv_ms": (_number, True),
        "ttv_lo_ms": (_number, False),
        "ttv_hi_ms": (_number, False),
        "fitted": (_number, False),
        "slope_se": (_number, False),
        "confidence": (_number, False),
        "samples": (_count, False),
        "window_ms": (_number, False),
        "horizon_ms": (_number, False),
        "min_confidence": (_number, False),
        "actions": (_strings, False),
        "cooldown": (_ident, False),
        "inputs": (_inputs, False),
    },
    "prediction_expired": {
        "requirement": (_ident, True),
        "tick": (_tick, False),
        "predicted_tick": (_tick, False),
        "horizon_ms": (_number, False),
        "after_ms": (_number, False),
    },
    "mitigation": {
        "requirement": (_ident, True),
        "action": (_ident, True),
        "kind": (_ident, True),
        "ok": (_bool, True),
        "error": (_opt_string, False),
        "latency_ms": (_number, False),
        "attempt": (_count, False),
        "stage": (_ident, False),
        "detail": (_mapping, False),
    },
    "reset": {
        "requirement": (_ident, True),
        "reason": (_string, True),
        "tick": (_tick, False),
        "via": (_string, False),
        "caller": (_mapping, False),
    },
    "supervisor": {
        "what": (_ident, True),
        "input": (_ident, False),
        "config": (_string, False),
        "tick": (_tick, False),
        "previous_last_sha256": (_sha256, False),
        "imports": (_digests, False),  # start, reload, replay: the config's imports
    },
}
# A supervisor record's fields whose meaning depends on its ``what``.
_WHAT: dict[str, dict[str, tuple[Check, bool]]] = {
    "records_lost": {"lost": (_ranges, True)},  # record_closed's ``lost`` is a count
}


def check_record(rec: Any) -> datetime:
    """``rec`` (a parsed line) against the schema; its time.  :class:`BadRecord`
    names the first field that is wrong (never its value: it could be anything)."""
    if not isinstance(rec, dict):
        raise BadRecord(f"not a record (a JSON {_type(rec)}, not an object)")
    event = rec.get("event")
    if not isinstance(event, str) or event not in SCHEMA:
        raise BadRecord("event is missing or not one of " + ", ".join(EVENTS))
    t = parse_time(rec.get("ts"))
    if "recorded_ts" in rec:
        parse_time(rec["recorded_ts"], "recorded_ts")
    fields = _COMMON | SCHEMA[event]
    if event == "supervisor" and isinstance(rec.get("what"), str):
        fields |= _WHAT.get(rec["what"], {})
    for key, (check, required) in fields.items():
        if key in rec:
            check(key, rec[key])
        elif required:
            raise BadRecord(f"{key} is missing")
    return t


def parse_record(line: bytes) -> dict[str, Any]:
    """One line of a log as a checked record, with ``_ts`` (its time, parsed)."""
    try:
        rec = load_json(line, max_bytes=MAX_LINE, max_depth=MAX_DEPTH)
    except BadRecord:
        raise
    except Untrusted as e:
        raise BadRecord(str(e)) from None
    rec_ts = check_record(rec)
    rec["_ts"] = rec_ts
    return rec


# The records' encoder, and the rows it encodes ahead of the halt's path: here, not in
# the writer, so that the daemon's core and replay use them without structlog
# (docs/BENCHMARKS.md, "Fleet").
def unencodable(value: Any) -> Any:
    """The encoder's ``default``: anything JSON has no form for is refused."""
    raise TypeError(type(value).__name__)


# The chain of _processors(safe=False) in one call, for the records on the halt's
# path (docs/reference/log.md#durability; writer.py): the same dict in the same key order
# through the encoder JSONRenderer builds from the same settings, so the bytes are
# the chain's (tests/mitigations/violationlog/test_log_render.py compares them).
def _encoder() -> Callable[[Any], str]:
    """``json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=unencodable).encode``,
    with the C encoder that ``encode`` makes on every call (json/encoder.py) made
    once.  Without a check for circular containers: a record has none, and one
    would still fail (RecursionError), reported as a record not rendered."""
    make = getattr(json.encoder, "c_make_encoder", None)
    if make is None:  # a Python without _json: the encoder's own path
        return json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=unencodable).encode
    chunks = make(
        None, unencodable, json.encoder.encode_basestring_ascii, None, ":", ",", False, False, False
    )

    def encode(o: Any) -> str:
        return "".join(chunks(o, 0))

    return encode


ENCODE = _encoder()


def encode_fragment(value: Any) -> str:
    """``value`` as a record's field holds it (made once, off the halt's path:
    :meth:`ViolationLog.violation_row`'s ``policy_state``)."""
    return ENCODE(value)


class Row(dict[str, Any]):
    """One tick of a violation record's ``recent``, with its JSON as ``ENCODE``
    renders it inside the record, made (:meth:`of`) when the tick is stepped: the
    record on the halt's path then joins these instead of encoding every tick again
    (docs/reference/log.md#durability).  ``json`` is None (or unset) when the row
    has no plain JSON form (NaN, infinities, other types): the record goes the safe
    way.  A row is not changed once made (its ``json`` would no longer be its bytes)."""

    __slots__ = ("json",)
    json: str | None

    @classmethod
    def of(cls, row: Mapping[str, Any]) -> Row:
        r = cls(row)
        try:
            r.json = ENCODE(r)
        except (ValueError, TypeError):
            r.json = None
        return r
