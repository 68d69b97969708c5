"""The inputs for the timeline and the windows the why-trees judge.

Two sources (docs/reference/commands.md, "report"):

- a recording (``--bag``, with the config that maps topics to variables): every
  message's values at its receive time; the windows come from replaying the bag with
  the config (supervisor/tools/replay/), the runtime's ``recent`` lengthened so that the
  replayed violation records carry the history since the requirement's last reset;
- the log alone: the ``recent`` ticks of the violation records, placed in time by the
  ticks and times the records give (``tick`` and ``ts`` of violations and resets).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mitigations.violationlog.discard import DiscardingLog
from monitors.errors import UserError
from supervisor.config.model import Config
from supervisor.progress import Line
from supervisor.tools.report.data import LogData
from supervisor.tools.why import Window, value, window

Value = bool | int | float
MAX_POINTS = 3000  # per input in the page: beyond it, min/max per time bucket
WINDOW_CAP = 1000  # ticks a why-tree may judge (the interpreter is quadratic in it)
SHOWN_PER_REQUIREMENT = 20  # violations with a why-tree, per requirement


@dataclass
class Series:
    name: str
    kind: str  # "bool" (drawn as bands) or "number" (a line)
    points: list[tuple[int, Value]] = field(default_factory=list)  # (t_ns, value), in time order


def _kind(values: list[Any], declared: str | None) -> str:
    if declared is not None:
        return "bool" if declared == "bool" else "number"
    return "bool" if values and all(isinstance(v, bool) for v in values) else "number"


def thin(points: list[tuple[int, Value]], kind: str) -> list[tuple[int, Value]]:
    """At most about MAX_POINTS points that draw the same picture: a band keeps its
    changes, a line its first, lowest, highest and last value per time bucket."""
    if kind == "bool":
        out = [p for i, p in enumerate(points) if i == 0 or p[1] != points[i - 1][1]]
        if points and out[-1] is not points[-1]:
            out.append(points[-1])  # where the data ends
        points = out
    if len(points) <= MAX_POINTS:
        return points
    t0, t1 = points[0][0], points[-1][0]
    size = max(1, (t1 - t0) // (MAX_POINTS // 4) + 1)
    out, bucket, start = [], [], None
    for p in points:
        b = (p[0] - t0) // size
        if start is not None and b != start:
            out.extend(_summary(bucket, kind))
            bucket = []
        start = b
        bucket.append(p)
    out.extend(_summary(bucket, kind))
    return out


def _summary(bucket: list[tuple[int, Value]], kind: str) -> list[tuple[int, Value]]:
    if len(bucket) <= 4:
        return bucket
    if kind == "bool":
        return [bucket[0], bucket[-1]]
    finite = [p for p in bucket if not (isinstance(p[1], float) and math.isnan(p[1]))]
    keep = {id(bucket[0]), id(bucket[-1])}
    if finite:
        keep |= {id(min(finite, key=lambda p: p[1])), id(max(finite, key=lambda p: p[1]))}
    return [p for p in bucket if id(p) in keep]


# ---------------------------------------------------------------- from the log


def _anchors(data: LogData) -> dict[int, list[tuple[int, int]]]:
    """Per run, (tick, t_ns) pairs the records give: a violation's tick was stepped at
    about its time; a reset's tick is the next one, the step before it just done."""
    out: dict[int, dict[int, int]] = {}
    for r in data.records:
        tick = r.get("tick")
        if not isinstance(tick, int):
            continue
        if r.get("event") == "violation":
            out.setdefault(r["_run"], {}).setdefault(tick, r["_t"])
        elif r.get("event") == "reset":
            out.setdefault(r["_run"], {}).setdefault(tick - 1, r["_t"])
    return {run: sorted(a.items()) for run, a in out.items()}


def tick_clock(data: LogData, period_ns: int | None) -> Callable[[int, int], int]:
    """(run, tick) -> estimated t_ns: between the records' ticks linearly, beyond them
    at the config's period (periodic policy), else at the rate the records show."""
    anchors = _anchors(data)

    def at(run: int, tick: int) -> int:
        a = anchors.get(run) or [(0, 0)]
        rate = period_ns
        if rate is None:
            (k0, t0), (k1, t1) = a[0], a[-1]
            rate = (t1 - t0) // (k1 - k0) if k1 > k0 else 100_000_000
        if tick <= a[0][0]:
            return a[0][1] - (a[0][0] - tick) * rate
        if tick >= a[-1][0]:
            return a[-1][1] + (tick - a[-1][0]) * rate
        for (k0, t0), (k1, t1) in zip(a, a[1:], strict=False):
            if k0 <= tick <= k1:
                return t0 + (t1 - t0) * (tick - k0) // max(1, k1 - k0)
        return a[-1][1]

    return at


def series_from_log(data: LogData, cfg: Config | None) -> dict[str, Series]:
    period = period_ns(cfg)
    at = tick_clock(data, period)
    seen: dict[str, dict[tuple[int, int], Value]] = {}
    for r in data.records:
        if r.get("event") != "violation":
            continue
        for row in r.get("recent") or []:
            tick = row.get("tick")
            if not isinstance(tick, int):
                continue
            for k, v in row.items():
                if k != "tick" and v is not None:  # null: no value yet
                    seen.setdefault(k, {})[(r["_run"], tick)] = value(v)
    out = {}
    for name, vals in seen.items():
        declared = cfg.variables[name].type if cfg and name in cfg.variables else None
        pts = sorted((at(run, tick), v) for (run, tick), v in vals.items())
        kind = _kind([v for _, v in pts], declared)
        out[name] = Series(name, kind, thin(pts, kind))
    return out


def period_ns(cfg: Config | None) -> int | None:
    if cfg is None or cfg.step.policy != "periodic" or not cfg.step.period_ms:
        return None
    return int(cfg.step.period_ms * 1e6)


# ---------------------------------------------------------------- from a bag


def bag_paths(names: list[str]) -> list[Path]:
    from supervisor.tools.replay.session import expand

    paths = [Path(n) for n in names]
    for p in paths:
        if not p.exists():
            raise UserError("no such bag or trace", file=str(p))
    return expand(paths)


def series_from_bag(
    paths: list[Path], cfg: Config, quiet: bool, namespace: str | None = None
) -> tuple[dict[str, Series], list[str]]:
    """Every input value in the recording at its receive time; damage ends the
    reading where it is (a note), as it ends a replay."""
    from supervisor.tools.replay.sources import open_recordings

    # names as replay resolves them (docs/reference/commands.md, replay)
    rec = open_recordings(paths, cfg, namespace)
    notes = list(rec.warnings)
    pts: dict[str, list[tuple[int, Value]]] = {}
    line = Line("report: reading", on=False if quiet else None)
    try:
        for t, topic, vals in rec.events(progress=line.messages if line.on else None):
            if topic == "record":
                continue
            for name, v in vals:  # type: ignore[union-attr]
                pts.setdefault(name, []).append((int(t), value(v)))
    except UserError as e:
        notes.append(f"the recording is damaged; read up to the damage: {e}")
    finally:
        line.end()
    out = {}
    for v in cfg.inputs:
        if v.name in pts:
            kind = _kind([], v.type)
            out[v.name] = Series(v.name, kind, thin(pts[v.name], kind))
    return out, notes


class _Capture(DiscardingLog):
    """The replay's log: keeps, for the violations wanted, the replayed history since
    the requirement's last reset (resets tracked as the core makes them)."""

    def __init__(self, runtime: Any, wanted: set[tuple[str, int]]) -> None:
        self.runtime = runtime
        self.wanted = wanted
        self.last: dict[str, int] = {}
        self.every = 0
        self.got: dict[tuple[str, int], tuple[list[dict[str, Any]], int, dict[str, Any]]] = {}

    def violation(self, requirement: str, **fields: Any) -> bool:
        key = (requirement, int(fields["tick"]))
        if key in self.wanted:
            start = max(self.last.get(requirement, 0), self.every)
            rows = [r for r in fields["recent"] if r["tick"] >= start]
            self.got[key] = (rows, start, dict(fields["inputs"]))
        return True

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        if requirement == "*":
            self.every = self.runtime.tick  # every monitor judges afresh from the next tick
        else:
            self.last[requirement] = int(extra.get("tick", self.runtime.tick))
        return True


def windows_from_bag(
    config: Path,
    paths: list[Path],
    data: LogData,
    wanted: dict[int, tuple[str, int]],
    quiet: bool,
    namespace: str | None = None,
) -> tuple[dict[int, Window], list[str]]:
    """Replay the recording with the config (the daemon's core, as ``replay`` does),
    keeping up to WINDOW_CAP ticks of history: the windows of the violations wanted
    (record index -> (requirement, tick)) that the replay reproduces, same inputs at
    the same tick."""
    from supervisor.tools.replay.engine import replay
    from supervisor.tools.replay.session import loaded
    from supervisor.tools.replay.sources import open_recordings

    with loaded(config) as session:
        session.runtime.recent = deque(maxlen=WINDOW_CAP)
        cap = _Capture(session.runtime, set(wanted.values()))
        line = Line("report: replaying", on=False if quiet else None)
        try:
            outcome = replay(
                session,
                open_recordings(paths, session.config, namespace),
                cap,
                progress=line.messages if line.on else None,
            )
        finally:
            line.end()
    notes = [f"the replay ended early: {outcome.error}"] if outcome.error else []
    out = {}
    missed = 0
    for i, key in wanted.items():
        got = cap.got.get(key)
        rec = data.records[i]
        if got is None or _values(got[2]) != _values(rec.get("inputs") or {}):
            missed += 1
            continue
        rows, start, _ = got
        first = rows[0]["tick"]
        if first > start:
            note = (
                f"replayed from the bag: the last {len(rows)} ticks of the "
                f"{key[1] - start + 1} since tick {start} (the page keeps at most {WINDOW_CAP})"
            )
        else:
            note = f"replayed from the bag: ticks {first}..{key[1]}, every tick since " + (
                "the requirement's last reset" if start > 0 else "monitoring started"
            )
        out[i] = window(rows, note)
    if missed:
        notes.append(
            f"{missed} violation(s) of the log were not reproduced by replaying the bag with "
            "the config (another run, or a bag not recorded by this daemon): their why-trees "
            "judge the record's recent ticks"
        )
    return out, notes


def _values(d: dict[str, Any]) -> dict[str, Any]:
    """Inputs compared as the log writes them (NaN as "nan", so NaN equals NaN)."""
    return {
        k: (repr(v) if isinstance(v, float) and not math.isfinite(v) else v)
        for k, v in ((k, value(v)) for k, v in d.items())
    }
