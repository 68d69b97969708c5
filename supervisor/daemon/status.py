"""The status document of ``/safety_supervisor/status``: what an operator's page
shows (``ui``, docs/reference/ros-interfaces.md, "Status").

One JSON document every ``ros.status_ms``: each requirement's state (and, with
margins on, its latest margin and trend), each input's latest value and age, the
supervisor's health, and the records made since the previous document (so a page's
event feed misses none).  No rclpy here: the node
publishes what :class:`StatusBoard` builds.
"""

from __future__ import annotations

import json
import math
import os
import socket
import threading
from collections import deque
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from mitigations.policy import RequirementPolicy
from mitigations.violationlog.format import json_safe
from supervisor.daemon.core import Core
from supervisor.inputs.readers import value_precision

SCHEMA = 1
ACTIONS_KEPT = 5  # per requirement, the latest
EVENTS_KEPT = 500  # records between two documents; beyond, the oldest are counted
MS = 1_000_000
MAX_UNIT = 200  # a margin's unit text: the names of the inputs it reads, cut
# The UI refuses a margin or trend past this (supervisor/tools/ui/schema.py,
# MAX_MARGIN): a larger margin is written as the infinity of its sign, a trend as null.
MAX_MARGIN = 1e12


def requirement_state(pol: RequirementPolicy, now_ns: int) -> str:
    """One word for a requirement's policy state, the most pressing first."""
    c = pol.config
    if pol.latched:
        return "latched"
    if pol.escalated:
        return "escalated"
    if pol.run_steps > 0 and not pol.in_episode:
        return "debouncing"  # flagged, not yet for debounce_steps / debounce_ms
    if not pol.holds:
        return "violated"
    if pol.last_act_ns is not None and now_ns < pol.last_act_ns + int(c.cooldown_ms * MS):
        return "cooldown"
    return "holding"


def _iso(wall_ns: int) -> str:
    return datetime.fromtimestamp(wall_ns / 1e9, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


class StatusBoard:
    """Collects the records the log writes (``record``, from any thread) and builds
    the status document from the session (``document``, on the loop)."""

    def __init__(self, node_name: str, namespace: str = "/") -> None:
        self.supervisor = f"{socket.gethostname()}:{namespace.rstrip('/')}/{node_name}"
        self.started_wall = datetime.now(UTC).timestamp()
        self.started_mono = None  # set at the first document
        self._lock = threading.Lock()
        self._events: deque[dict[str, Any]] = deque(maxlen=EVENTS_KEPT)
        self._dropped = 0
        self._actions: dict[str, deque[dict[str, Any]]] = {}
        self._last_violation: dict[str, dict[str, Any]] = {}
        self._prev: tuple[int, int, int] | None = None  # (t, ticks, received)
        # each input's value_precision, looked up once per variable as configured
        self._precisions: dict[tuple[Any, ...], str | None] = {}
        # each requirement's margin in the previous document: the trend of one
        # without a predictor is the difference to it
        self._prev_margins: dict[str, tuple[int, float]] = {}

    def record(self, line: str) -> None:
        """A record as the log rendered it (ViolationLog.tee)."""
        try:
            r = json.loads(line)
        except ValueError:
            return
        event = r.get("event")
        brief = {
            k: r[k]
            for k in ("event", "ts", "requirement", "what", "action", "ok", "stage", "tick",
                      "reason", "input", "detail", "error")
            if k in r
        }  # fmt: skip
        with self._lock:
            if len(self._events) == self._events.maxlen:
                self._dropped += 1
            self._events.append(brief)
            req = str(r.get("requirement", ""))
            if event == "violation":
                self._last_violation[req] = {"ts": r.get("ts"), "tick": r.get("tick")}
            elif event == "mitigation":
                kept = self._actions.setdefault(req, deque(maxlen=ACTIONS_KEPT))
                kept.append(
                    {k: r.get(k) for k in ("action", "stage", "ok", "ts", "latency_ms", "dry_run")}
                )

    def document(
        self,
        core: Core,
        *,
        now_ns: int,
        reloads: int,
        recording: bool,
        watchdog_s: float | None,
        control_socket: str | None,
        peek: bool = False,
    ) -> dict[str, Any]:
        """``peek``: for a status request on the control socket, which must not take
        the events the next document's feed carries (they are left out)."""
        cfg = core.session.config
        stats = core.input_stats()
        tick = core.tick
        received = sum(st["messages"] + st["rejected"] for st in stats.values())
        tick_rate, receive_rate = (0.0, 0.0) if peek else self._rates(now_ns, tick, received)
        if self.started_mono is None:
            self.started_mono = now_ns
        events, dropped, actions, last = self._take_records(take=not peek)
        requirements = _requirements(core, now_ns, actions, last)
        margins = _margins(core, now_ns, self._prev_margins, update=not peek)
        for r, m in zip(requirements, margins, strict=True):
            r["margin"] = m
        inputs = _inputs(core, stats, now_ns, self._precision)
        doc = {
            "schema": SCHEMA,
            "supervisor": self.supervisor,
            "component": cfg.component,
            "config": cfg.path,
            "config_sha256": cfg.sha256,
            "pid": os.getpid(),
            "started": _iso(int(self.started_wall * 1e9)),
            "now": _iso(int(datetime.now(UTC).timestamp() * 1e9)),
            "uptime_s": round((now_ns - self.started_mono) / 1e9, 3),
            "policy": cfg.step.policy,
            "ticks": tick,
            "tick_rate_hz": round(tick_rate, 2),
            "receive_rate_hz": round(receive_rate, 2),
            "received": received,
            "lost": sum(st["lost"] for st in stats.values()),
            "violations": core.violations,
            "reloads": reloads,
            "recording": recording,
            "watchdog": {"enabled": watchdog_s is not None, "interval_s": watchdog_s},
            "control_socket": control_socket,
            "requirements": requirements,
            "inputs": inputs,
            "events": events,
            "events_dropped": dropped,
        }
        return json_safe(doc)

    def _precision(self, v: Any) -> str | None:
        key = (v.name, v.type, v.msg, v.field, v.reduce, v.service, v.call, v.event, v.age_of)
        if key not in self._precisions:
            self._precisions[key] = value_precision(v)
        return self._precisions[key]

    def _rates(self, now_ns: int, tick: int, received: int) -> tuple[float, float]:
        """Ticks and messages per second since the previous document (0 at the first)."""
        tick_rate = receive_rate = 0.0
        if self._prev is not None and now_ns > self._prev[0]:
            dt = (now_ns - self._prev[0]) / 1e9
            tick_rate = (tick - self._prev[1]) / dt
            receive_rate = (received - self._prev[2]) / dt
        self._prev = (now_ns, tick, received)
        return tick_rate, receive_rate

    def _take_records(
        self, *, take: bool = True
    ) -> tuple[
        list[dict[str, Any]], int, dict[str, list[dict[str, Any]]], dict[str, dict[str, Any]]
    ]:
        """The events since the previous document (taken: the next starts empty),
        how many were dropped, and each requirement's latest actions and violation."""
        with self._lock:
            events, dropped = list(self._events), self._dropped
            if take:
                self._events, self._dropped = deque(maxlen=EVENTS_KEPT), 0
            actions = {k: list(v) for k, v in self._actions.items()}
            last = dict(self._last_violation)
        return events, dropped, actions, last


def _requirements(
    core: Core,
    now_ns: int,
    actions: dict[str, list[dict[str, Any]]],
    last: dict[str, dict[str, Any]],
) -> list[dict[str, Any]]:
    """Each requirement's entry in the document: its state, counts and stale inputs."""
    session = core.session
    stale = set(core.stale_inputs())
    requirements = []
    for i, r in enumerate(session.requirements):
        pol = session.policies[i]
        reads = [n for n in session.reads[i] if n in stale] if stale else []
        requirements.append(
            {
                "id": r.id,
                "text": r.entry.text,
                "formula": session.formulas[i],
                "state": requirement_state(pol, now_ns),
                "violations": pol.violations,
                "last_violation": (last.get(r.id) or {}).get("ts"),
                "last_tick": pol.last_violation_tick,
                "stale_inputs": reads,
                "actions": actions.get(r.id, []),
            }
        )
    return requirements


MARGIN_DIGITS = 6  # significant digits of a margin's trend and a prediction's times


def _sig(x: float) -> float:
    return float(f"{x:.{MARGIN_DIGITS}g}")


def _margins(
    core: Core, now_ns: int, prev: dict[str, tuple[int, float]], *, update: bool
) -> list[dict[str, Any] | None]:
    """Each requirement's margin entry (docs/reference/ros-interfaces.md, "Status"),
    None where margins are off: the predictions' monitor's margin for a requirement
    with ``predict:`` (what its predictor fits), else the monitor's with
    ``step.margins``.  ``trend`` is the predictor's slope when it has a fit, else the
    difference to the previous document's margin (``prev``, updated unless a
    peek).  ``unit`` names the numeric inputs the requirement reads: a margin is in
    their units (docs/reference/margins.md, "Units")."""
    session = core.session
    latest = core.latest_margins()
    numeric = {v.name for v in session.config.inputs if v.type != "bool"}
    out: list[dict[str, Any] | None] = []
    for i, r in enumerate(session.requirements):
        pol = session.policies[i]
        m = latest[i]
        if m is None:
            out.append(None)
            continue
        est = pol.trend.estimate() if pol.trend is not None else None
        trend, by = None, None
        if est is not None:
            trend, by = est.slope, "predictor"
        elif r.id in prev:
            t0, m0 = prev[r.id]
            if now_ns > t0 and math.isfinite(m) and math.isfinite(m0):
                trend, by = (m - m0) / ((now_ns - t0) / 1e9), "difference"
        if update:
            prev[r.id] = (now_ns, m)
        if abs(m) > MAX_MARGIN:
            m = math.copysign(math.inf, m)
        if trend is not None and not abs(trend) <= MAX_MARGIN:
            trend, by = None, None
        unit = ", ".join(x for x in session.reads[i] if x in numeric) or None
        prediction = None
        if pol.predicted_ns is not None:
            prediction = {
                "tick": pol.predicted_tick,
                "since_ms": _sig(max(now_ns - pol.predicted_ns, 0) / MS),
                "ttv_ms": None if est is None or est.ttv_ms is None else _sig(est.ttv_ms),
            }
        out.append(
            {
                "value": m,  # json_safe writes an infinite one "inf" / "-inf"
                "trend_per_s": None if trend is None else _sig(trend),
                "trend_from": by,
                "unit": unit[:MAX_UNIT] if unit else None,
                "prediction": prediction,
            }
        )
    if len(prev) > len(out):  # ids of requirements a reload removed
        keep = {r.id for r in session.requirements}
        for k in [k for k in prev if k not in keep]:
            del prev[k]
    return out


def _inputs(
    core: Core,
    stats: dict[str, dict[str, Any]],
    now_ns: int,
    precision: Callable[[Any], str | None],
) -> list[dict[str, Any]]:
    """Each input's entry in the document: its latest value, age and counts, and
    ``precision`` ("float32" when the value is a float32 field's, else null)."""
    types = {v.name: v for v in core.session.config.inputs}
    inputs = []
    latest = core.snapshot()
    for name, st in stats.items():
        v = types.get(name)
        last_ns = st["last_ns"]
        inputs.append(
            {
                "name": name,
                "topic": v.topic if v else None,
                "type": v.type if v else None,
                "precision": precision(v) if v else None,
                "value": latest.get(name),
                "age_s": None if last_ns is None else round((now_ns - last_ns) / 1e9, 3),
                "stale": bool(st["stale"]),
                "messages": st["messages"],
                "lost": st["lost"],
            }
        )
    return inputs


# The keys of the status request's answer (docs/reference/commands.md, "status"):
# flat, so the answer stays small and shallow for the client's bounded reader.
STATUS_KEYS = (
    "supervisor", "component", "config", "config_sha256", "pid", "started", "now",
    "policy", "ticks", "received", "lost", "violations", "reloads", "recording",
)  # fmt: skip
REQUIREMENT_KEYS = ("id", "state", "violations", "last_violation", "last_tick", "stale_inputs")
INPUT_KEYS = ("name", "topic", "age_s", "stale", "messages", "lost")


def status_answer(doc: dict[str, Any], started_wall: float, now_wall: float) -> dict[str, Any]:
    """The control socket's ``status`` answer from a (peeked) status document."""
    out = {k: doc.get(k) for k in STATUS_KEYS}
    out["uptime_s"] = round(max(0.0, now_wall - started_wall), 3)
    out["requirements"] = [{k: r.get(k) for k in REQUIREMENT_KEYS} for r in doc["requirements"]]
    out["inputs"] = [{k: i.get(k) for k in INPUT_KEYS} for i in doc["inputs"]]
    return out
