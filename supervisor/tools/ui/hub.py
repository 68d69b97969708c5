"""What the page shows, kept in one place, and its fan-out to the browsers.

The ROS side (:mod:`.node`) calls ``on_status``, ``on_violation`` and
``on_diagnostics`` from its executor thread; each HTTP ``/events`` stream
subscribes a queue.  No rclpy here, so it is tested without DDS.

Sources (docs/reference/ros-interfaces.md, "What the UI reads"):

- the status document (``/safety_supervisor/status``) is the picture: requirements,
  inputs, health, and the records made since the previous document (``events``);
- a violation record (``/safety_supervisor/violations``) goes to the feed at once,
  not half a status period later; the same violation in the next document's
  ``events`` is then not shown twice;
- ``/diagnostics`` stands in for the requirements and inputs while no status
  document has arrived (a daemon without the status topic).

Any node of the domain can publish on those topics: a document or record enters
through ``receive_status`` / ``receive_violation``, which check it once
(:mod:`.schema`); a bad one is not shown but counted and said ("invalid status
from <publisher>"), and a second publisher of the status topic is shown as a
warning (docs/reference/ros-interfaces.md, "What the status topic can be trusted
for").
"""

from __future__ import annotations

import json
import math
import queue
import struct
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from datetime import UTC, datetime
from decimal import ROUND_HALF_UP, Context
from typing import Any

from monitors.untrusted import Untrusted, printable
from supervisor.tools.ui.schema import parse_status, parse_violation
from supervisor.tools.ui.streams import Streams

FEED_LENGTH = 200  # entries a newly opened page gets
# A flood of bad documents is said once in a while, counted every time: at most one
# stderr line per WARN_EVERY_S, one update of the pages per SAY_EVERY_S.
WARN_EVERY_S = 10.0
SAY_EVERY_S = 0.5


def utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _diag_state(level: int, message: str) -> str:
    """A requirement's state in the words of the status document, from its
    /diagnostics status (docs/reference/ros-interfaces.md, "/diagnostics")."""
    if level == 0:
        return "holding"
    return "latched" if "latched" in message else "violated"


class Hub:
    """The latest picture and the browsers' queues; every method is thread-safe."""

    def __init__(
        self,
        reset_state: Callable[[dict[str, Any] | None], dict[str, Any]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._lock = threading.Lock()
        self._reset_state = reset_state  # whether resets can reach the daemon, and why not
        self._clock = clock
        self.status: dict[str, Any] | None = None
        self._precisions: dict[str, str | None] = {}
        # the daemon that started last of those seen: (its start, its document).  Only
        # a later start is a restart, so a second publisher of the topic (forged
        # documents, ros-interfaces.md) cannot fill the feed with restart lines.
        self._daemon: tuple[datetime, dict[str, Any]] | None = None
        self._status_at: float | None = None
        self._diagnostics: dict[str, Any] = {"requirements": {}, "inputs": {}, "at": None}
        self._feed: deque[dict[str, Any]] = deque(maxlen=FEED_LENGTH)
        # violations shown from the topic, not yet seen in a status document's events:
        # by (requirement, tick)
        self._pending: Counter[tuple[str, Any]] = Counter()
        self._streams = Streams()
        # documents and records refused by the schema check: how many, the last one
        self.invalid: dict[str, Any] = {"count": 0, "publisher": "", "why": "", "at": None}
        self._invalid_said = self._invalid_warned = -math.inf
        self._invalid_unwarned = 0
        self.publishers: list[str] = []  # of the status topic, from the ROS graph
        self.label = ""  # whose status this is, for stderr (a fleet's robot)

    # ------------------------------------------------------------ untrusted inputs

    def receive_status(self, data: bytes | str, publisher: Callable[[], str]) -> bool:
        """A status document as it came off the topic: shown if it passes the
        schema, else counted and said; ``publisher()`` names who sent it."""
        return self._receive(data, publisher, parse_status, self.on_status, "status")

    def receive_violation(self, data: bytes | str, publisher: Callable[[], str]) -> bool:
        return self._receive(
            data, publisher, parse_violation, self.on_violation, "violation record"
        )

    def _receive(
        self,
        data: bytes | str,
        publisher: Callable[[], str],
        parse: Callable[[bytes | str], dict[str, Any]],
        use: Callable[[dict[str, Any]], None],
        what: str,
    ) -> bool:
        try:
            doc = parse(data)
        except Untrusted as e:
            self.on_invalid(publisher(), f"{what}: {e}")
            return False
        use(doc)
        return True

    def on_invalid(self, publisher: str, why: str) -> None:
        """A document or record that failed the schema check: counted, said."""
        now = self._clock()
        publisher, why = printable(publisher)[:300], printable(why)[:300]
        with self._lock:
            count = self.invalid["count"] + 1
            self.invalid = {"count": count, "publisher": publisher, "why": why, "at": utc_now()}
            self._invalid_unwarned += 1
            warn = now - self._invalid_warned >= WARN_EVERY_S
            if warn:
                self._invalid_warned, n, self._invalid_unwarned = now, self._invalid_unwarned, 0
            say = now - self._invalid_said >= SAY_EVERY_S
            if say:
                self._invalid_said = now
            invalid = dict(self.invalid)
        if warn:
            more = f" ({n} since the last warning, {count} in all)" if count > 1 else ""
            print(f"safety-supervisor ui: WARNING: {self.label}invalid {why.partition(':')[0]} "
                  f"from {publisher}, not shown: {why.partition(': ')[2]}{more}",
                  file=sys.stderr, flush=True)  # fmt: skip
        if say:
            self._broadcast({"type": "invalid", "invalid": invalid})

    def on_publishers(self, names: list[str]) -> None:
        """The nodes publishing the status topic (the ROS graph); said when it changes."""
        names = [printable(n)[:300] for n in names[:100]]
        with self._lock:
            if names == self.publishers:
                return
            self.publishers = names
        if len(names) > 1:
            print(f"safety-supervisor ui: WARNING: {self.label}{len(names)} publishers of the "
                  f"status topic: {', '.join(names)}", file=sys.stderr, flush=True)  # fmt: skip
        self._broadcast({"type": "publishers", "publishers": names})

    # ------------------------------------------------------------ inputs

    def on_status(self, doc: dict[str, Any]) -> None:
        entries = []
        with self._lock:
            started = _started(doc)
            if started is not None and (self._daemon is None or started > self._daemon[0]):
                if self._daemon is not None:
                    # the feed goes on across daemons: say where the previous one's ends
                    entries.append(_restart_entry(self._daemon[1], doc))
                self._daemon = (started, doc)
            self.status = doc
            # each input's precision, for the violation records' values (value_text)
            self._precisions = {i["name"]: i.get("precision") for i in doc.get("inputs") or []}
            self._status_at = self._clock()
            for ev in doc.get("events") or []:
                if not isinstance(ev, dict):
                    continue
                key = (str(ev.get("requirement") or ""), ev.get("tick"))
                if ev.get("event") == "violation" and self._pending[key] > 0:
                    self._pending[key] -= 1  # already in the feed from the topic
                    continue
                entries.append(self._entry(ev))
            self._feed.extend(entries)
        self._broadcast(
            {"type": "status", "status": doc, "reset": self._reset_state(doc), "feed": entries}
        )

    def on_violation(self, record: dict[str, Any]) -> None:
        rid = str(record.get("requirement") or "")
        entry = {
            "event": "violation",
            "ts": record.get("ts") or utc_now(),
            "requirement": rid,
            "what": "violated",
            "detail": _inputs_text(record.get("inputs"), self._precisions),
            "tick": record.get("tick"),
            "text": record.get("text"),
            "formula": record.get("formula"),
        }
        with self._lock:
            self._pending[(rid, record.get("tick"))] += 1
            self._feed.append(entry)
        self._broadcast({"type": "violation", "record": record, "feed": [entry]})

    def on_diagnostics(self, statuses: list[tuple[str, int, str, dict[str, str]]]) -> None:
        """``(name, level, message, values)`` per status of one DiagnosticArray."""
        reqs: dict[str, Any] = {}
        inputs: dict[str, Any] = {}
        for name, level, message, values in statuses:
            _node, _, what = name.partition(": ")
            kind, _, key = what.partition(" ")
            if kind == "requirement" and key:
                reqs[key] = {
                    "id": key,
                    "state": _diag_state(level, message),
                    "message": message,
                    "violations": _int(values.get("violations")),
                }
            elif kind == "input" and key:
                age = values.get("age_ms", "never")
                inputs[key] = {
                    "name": key,
                    "topic": values.get("topic", ""),
                    "age_s": None if age == "never" else _float(age, 1e-3),
                    "stale": level != 0 and "stale" in message,
                    "messages": _int(values.get("messages")),
                    "lost": _int(values.get("lost")),
                    "message": message,
                }
        if not reqs and not inputs:
            return  # another node's diagnostics
        with self._lock:
            self._diagnostics = {"requirements": reqs, "inputs": inputs, "at": utc_now()}
            diag = self._diagnostics
        self._broadcast({"type": "diagnostics", "diagnostics": diag})

    def note(self, entry: dict[str, Any]) -> None:
        """An entry of the UI's own (a reset asked for from the page) for the feed."""
        entry = {"ts": utc_now(), **entry}
        with self._lock:
            self._feed.append(entry)
        self._broadcast({"type": "feed", "feed": [entry]})

    # ------------------------------------------------------------ outputs

    def snapshot(self) -> dict[str, Any]:
        """Everything a page that just connected needs."""
        with self._lock:
            age = None if self._status_at is None else self._clock() - self._status_at
            out = {
                "type": "snapshot",
                "status": self.status,
                "status_age_s": age,
                "diagnostics": self._diagnostics,
                "feed": list(self._feed),
                "invalid": dict(self.invalid),
                "publishers": list(self.publishers),
            }
            status = self.status
        out["reset"] = self._reset_state(status)
        return out

    def subscribe(self) -> queue.Queue[str | None]:
        """A queue of SSE ``data`` lines, the snapshot first (streams.py)."""
        return self._streams.subscribe(self.snapshot)

    def unsubscribe(self, q: queue.Queue[str | None]) -> None:
        self._streams.unsubscribe(q)

    def close(self) -> None:
        self._streams.close()

    def _broadcast(self, message: dict[str, Any]) -> None:
        self._streams.broadcast(message)

    @staticmethod
    def _entry(ev: dict[str, Any]) -> dict[str, Any]:
        """A feed entry from a status document's shortened record
        (docs/reference/ros-interfaces.md, "Status")."""
        event = str(ev.get("event") or "supervisor")
        what = str(ev.get("what") or "")
        detail = ev.get("detail") or ev.get("error") or ""
        if event == "mitigation":
            ok = "ok" if ev.get("ok") else "failed"
            what = f"{ev.get('action', '')} ({ev.get('stage', '')}) {ok}"
        elif event == "reset":
            what = str(ev.get("reason") or "reset")
        elif event == "violation":
            what = "violated"
        if ev.get("input"):
            what = f"{what} {ev['input']}".strip()
        return {
            "event": event,
            "ts": ev.get("ts") or utc_now(),
            "requirement": ev.get("requirement") or "",
            "what": what,
            "detail": detail if isinstance(detail, str) else json.dumps(detail),
            "tick": ev.get("tick"),
        }


def _started(doc: dict[str, Any]) -> datetime | None:
    """When the daemon of a status document started (its ``started``), if readable."""
    try:
        t = datetime.fromisoformat(str(doc.get("started")))
    except ValueError:
        return None
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def _restart_entry(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """The feed's mark between two daemons' entries (docs/reference/commands.md, ui)."""
    return {
        "event": "restart",
        "ts": after.get("started") or utc_now(),
        "requirement": "",
        "what": f"supervisor started: pid {after.get('pid')}",
        "detail": f"the entries below are the previous supervisor's "
        f"(pid {before.get('pid')}, started {before.get('started')})",
        "tick": None,
    }


def value_text(value: Any, precision: str | None = None) -> str:
    """An input's value as a page shows it: at its type's precision (a float32
    field's shortest text that reads back as the same float32: 0.8, not
    0.800000011920929), a double as Python writes it, an integer as one."""
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, float) and precision == "float32" and _f32(value) == value:
        for digits in range(1, 10):  # 9 significant digits always read back
            # rounded as the page's toExponential rounds: ties away from zero
            short = float(Context(prec=digits, rounding=ROUND_HALF_UP).create_decimal(value))
            if _f32(short) == value:
                return repr(short)
    if isinstance(value, float):
        return repr(value)
    return str(value)  # an integer, or the daemon's "nan", "inf", "-inf"


def _f32(x: float) -> float:
    """``x`` rounded to the nearest float32, as a float."""
    try:
        return float(struct.unpack("f", struct.pack("f", x))[0])
    except OverflowError:
        return math.nan  # beyond float32: no float32 field gave it


def _inputs_text(inputs: Any, precisions: dict[str, str | None]) -> str:
    if not isinstance(inputs, dict):
        return ""
    return ", ".join(f"{k}={value_text(v, precisions.get(k))}" for k, v in inputs.items())


def _int(text: str | None) -> int | None:
    try:
        return int(str(text))
    except ValueError:
        return None


def _float(text: str, scale: float = 1.0) -> float | None:
    """A finite number (JSON, and so the page, has no NaN or infinity), else None."""
    try:
        value = float(text) * scale
    except ValueError:
        return None
    return value if math.isfinite(value) else None
