"""Replay: a recording through the daemon's own monitoring core, offline.

The same compiled monitor, step policy, stale rules and mitigation policies as
``run`` (supervisor/daemon/core.py), on the recorded receive times; actions are
not executed but written as ``mitigation`` records with ``dry_run: true``.  A
recording made by the daemon (``run --record``) carries markers (the start of
monitoring, operator resets) that put the external events back where they were,
so its replay writes the violation, reset and mitigation decisions the daemon
logged (docs/reference/commands.md, "replay").
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from mitigations.engine import Request
from monitors.errors import UserError
from supervisor.config import Config
from supervisor.daemon.core import Core
from supervisor.daemon.session import Session
from supervisor.tools.replay.fast import forward, quiet
from supervisor.tools.replay.sources import Batch, Progress, Recording, Unread


class DryRun:
    """The core's ``submit`` in replay: each action becomes a record, none runs."""

    def __init__(self, log: Any, cfg: Config) -> None:
        self.log = log
        self.cfg = cfg
        self.requests = 0

    def __call__(self, request: Request) -> None:
        self.requests += 1
        for name in request.actions:
            m = self.cfg.mitigations.get(name)
            self.log.mitigation(
                request.requirement,
                action=name,
                kind=m.kind if m is not None else "undefined",
                ok=True,
                latency_ms=0.0,
                stage=request.stage,
                dry_run=True,
            )


@dataclass
class Outcome:
    """What one replay saw: counts, the first violation tick per requirement."""

    messages: int = 0
    ticks: int = 0
    violations: dict[str, list[tuple[int, int]]] = field(default_factory=dict)  # id -> (tick, t)
    predictions: dict[str, list[tuple[int, int]]] = field(default_factory=dict)  # id -> (tick, t)
    expired: dict[str, int] = field(default_factory=dict)  # id -> predictions expired
    leads: dict[str, list[float]] = field(default_factory=dict)  # id -> predicted_ms
    predicting: bool = False  # a requirement has predict:
    start_ns: int | None = None
    end_ns: int | None = None
    seconds: float = 0.0
    markers: list[str] = field(default_factory=list)
    requirements: list[str] = field(default_factory=list)  # the config's ids, in order
    warnings: list[str] = field(default_factory=list)
    error: UserError | None = None  # the damage that ended the recording early


class _Log:
    """Passes records to the output log, each with the recorded time it belongs to
    (``recorded_ts``: a record's own ``ts`` is when replay wrote it), and keeps what
    the summary needs."""

    def __init__(self, out: Any, outcome: Outcome) -> None:
        self.out = out
        self.outcome = outcome
        self.core: Core | None = None

    def _t(self) -> int:
        return self.core.now if self.core is not None and self.core.now is not None else 0

    def _at(self) -> str:
        t = self._t()
        stamp = datetime.fromtimestamp(t // 1_000_000_000, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S")
        return f"{stamp}.{t % 1_000_000_000:09d}Z"

    def violation(self, requirement: str, **fields: Any) -> bool:
        self.outcome.violations.setdefault(requirement, []).append((fields["tick"], self._t()))
        if "predicted_ms" in fields:
            self.outcome.leads.setdefault(requirement, []).append(fields["predicted_ms"])
        if self.out is None:
            return True
        return self.out.violation(requirement, recorded_ts=self._at(), **fields)

    def mitigation(self, requirement: str, **fields: Any) -> bool:
        if self.out is None:
            return True
        return self.out.mitigation(requirement, recorded_ts=self._at(), **fields)

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        if self.out is None:
            return True
        return self.out.reset(requirement, reason=reason, recorded_ts=self._at(), **extra)

    def supervisor(self, what: str, **fields: Any) -> bool:
        if self.out is None:
            return True
        return self.out.supervisor(what, recorded_ts=self._at(), **fields)

    def prediction(self, requirement: str, **fields: Any) -> bool:
        self.outcome.predictions.setdefault(requirement, []).append((fields["tick"], self._t()))
        if self.out is None:
            return True
        return self.out.prediction(requirement, recorded_ts=self._at(), **fields)

    def prediction_expired(self, requirement: str, **fields: Any) -> bool:
        self.outcome.expired[requirement] = self.outcome.expired.get(requirement, 0) + 1
        if self.out is None:
            return True
        return self.out.prediction_expired(requirement, recorded_ts=self._at(), **fields)


def replay(
    session: Session,
    recording: Recording,
    out: Any,
    *,
    progress: Progress | None = None,
    fast: bool = True,
    warn: Callable[[str], None] = lambda _text: None,
) -> Outcome:
    """Run ``session`` over ``recording``; records go to ``out`` (a ViolationLog, or
    None for counts only).  ``fast``: quiet stretches are stepped in bulk
    (supervisor/tools/replay/fast.py), with the same result.  A damaged recording
    ends the replay where the damage is: what came before is judged and written,
    and ``Outcome.error`` says where."""
    outcome = Outcome(requirements=[r.id for r in session.config.requirements])
    log = _Log(out, outcome)
    core = log.core = Core(session, log, DryRun(log, session.config), warn=warn)
    outcome.predicting = bool(core.supervision.predicting)
    names = {
        recording.ids[t]: [v.name for v in vs]
        for t, vs in recording.by_topic.items()
        if t in recording.ids
    }
    started = False
    t0 = time.perf_counter()
    last = None
    try:
        for batch in recording.batches(progress=progress):
            ts = batch.t_ns
            n = len(ts)
            marks = sorted(batch.records)
            m = 0  # the next record row
            odd, o = sorted(batch.odd), 0
            i = 0
            while i < n:
                if m < len(marks) and marks[m] == i:
                    record = batch.records[i]
                    if isinstance(record, dict) and record.get("event") == "marker":
                        started = _marker(core, record, int(ts[i]), outcome, started)
                    m += 1
                    i += 1
                    continue
                end = marks[m] if m < len(marks) else n
                if not started:  # a bag recorded on the robot: monitoring starts with it
                    core.start(int(ts[i]))
                    outcome.start_ns, started = int(ts[i]), True
                if odd:  # a row with a value no column holds is stepped alone
                    while o < len(odd) and odd[o] < i:
                        o += 1
                    if o < len(odd):
                        end = min(end, odd[o])
                if fast and end > i and quiet(core):
                    j = forward(core, batch, i, end, names)
                    if j > i:
                        outcome.messages += j - i
                        last = int(ts[j - 1])
                        i = j
                        continue
                t = int(ts[i])
                row = _row(batch, i, names)
                for name, x in batch.odd.get(i, ()):
                    if isinstance(x, Unread):
                        core.reject(name, t, x.why)  # as the daemon logs it
                    else:
                        row.append((name, x))  # the runtime rejects it, as online
                core.fields(row, t)
                outcome.messages += 1
                last = t
                i += 1
    except UserError as e:
        outcome.error = e
    end_ns = outcome.end_ns if outcome.end_ns is not None else last
    if end_ns is not None:
        core.advance(end_ns)  # timers up to the end of the recording
        outcome.end_ns = end_ns
    outcome.ticks = session.runtime.tick
    outcome.seconds = time.perf_counter() - t0
    return outcome


def _row(batch: Batch, i: int, names: dict[int, list[str]]) -> list[tuple[str, Any]]:
    """Row ``i``'s values for its topic's variables, as Recording.events gives them."""
    vals = [(v, batch.values[v][i].item()) for v in names[int(batch.topic[i])] if v in batch.values]
    if batch.given:
        return [(v, x) for v, x in vals if v not in batch.given or batch.given[v][i]]
    return vals


def _marker(core: Core, record: dict[str, Any], t: int, outcome: Outcome, started: bool) -> bool:
    """Put an external event of the recorded run back at its time."""
    what = str(record.get("what"))
    outcome.markers.append(what)
    if what == "start" and not started:
        core.start(t)
        outcome.start_ns = t
        return True
    if what == "operator_reset" and started:
        extra = {k: v for k, v in record.items() if k in ("via", "caller", "client")}
        requirement = record.get("requirement")
        try:
            core.operator_reset(t, requirement if isinstance(requirement, str) else None, **extra)
        except KeyError:
            outcome.warnings.append(f"the recorded run reset {requirement}, not in this config")
    elif what == "stop":
        outcome.end_ns = t
    elif what == "reload":
        outcome.warnings.append(
            f"the recorded run reloaded its config ({record.get('config')}); replay goes on "
            "with the config it was given"
        )
    return started
