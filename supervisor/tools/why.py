"""Why a violation record fired, from the log: the window of inputs its monitor
judged, and the why-engine (monitors/verify/why.py) on it.  Shared by ``logs --why``
and ``report`` (docs/reference/commands.md).

The interpreter judges only the window it is given. When the window starts later
than the history the monitor judged (the record's ``recent`` is short, or a cap cut
it), the formula may hold at the violating tick in the window: that is said rather
than a verdict explained that the window does not show.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from monitors.errors import UserError
from monitors.verify.why import WhyNode, explain, formula_for_record, missing_inputs, why_tree

Value = bool | int | float


@dataclass
class Window:
    """The trace a why-tree judges: oldest first, the violating tick last."""

    ticks: list[int]
    trace: list[dict[str, Value]]
    note: str  # where it comes from and how it starts


@dataclass
class Why:
    window: Window | None
    tree: WhyNode | None = None
    sentence: str = ""
    problem: str | None = None  # why there is no tree, or why it does not explain


def value(x: Any) -> Any:
    """JSON's stand-ins for NaN and the infinities back to floats (docs/reference/log.md)."""
    if isinstance(x, str) and x in ("nan", "inf", "-inf"):
        return float(x)
    return x


def is_start(r: dict[str, Any]) -> bool:
    """A daemon's start or a replay: a new run, ticks from 0."""
    return r.get("event") == "supervisor" and r.get("what") in ("start", "replay")


def mark_runs(records: list[dict[str, Any]]) -> None:
    """``_run`` on each record: a new run starts with each daemon start or replay."""
    run = -1
    for r in records:
        # seq starts at 1 with each daemon or replay (docs/reference/log.md, "seq"); a
        # log written before seq existed has its start records only
        if run < 0 or r.get("seq") == 1 or ("seq" not in r and is_start(r)):
            run += 1
        r["_run"] = run


def reset_ticks(records: list[dict[str, Any]]) -> dict[int, int]:
    """Index of each violation record in ``records`` (with ``_run``, see mark_runs) ->
    the first tick its requirement's monitor judged: its last reset, else the run's
    start (0).  A requirement's reset, an operator reset (``*``) and a reload carry
    that tick; logs written before the last two did are given the tick after the
    newest the log shows."""
    out: dict[int, int] = {}
    last: dict[tuple[int, str], int] = {}
    every: dict[int, int] = {}
    newest: dict[int, int] = {}  # per run, the highest tick seen
    for i, r in enumerate(records):
        run, tick, ev = r["_run"], r.get("tick"), r.get("event")
        every_requirement = (ev == "reset" and r.get("requirement") == "*") or (
            ev == "supervisor" and r.get("what") == "reload" and r.get("ok")
        )
        if every_requirement:
            # the record's tick where it has one, else the tick after the newest seen
            every[run] = tick if isinstance(tick, int) else newest.get(run, -1) + 1
        elif ev == "violation" and isinstance(tick, int):
            req = str(r.get("requirement"))
            out[i] = max(last.get((run, req), 0), every.get(run, 0))
            newest[run] = max(newest.get(run, -1), tick)
        elif ev == "reset" and isinstance(tick, int):
            last[(run, str(r.get("requirement")))] = tick
            newest[run] = max(newest.get(run, -1), tick - 1)
    return out


def windows_from_log(records: list[dict[str, Any]]) -> dict[int, Window]:
    """Per violation record (by index): its ``recent`` ticks since its requirement's
    monitor last started judging afresh."""
    starts = reset_ticks(records)
    out = {}
    for i, start in starts.items():
        r = records[i]
        rows = [row for row in r.get("recent") or [] if row.get("tick", -1) >= start]
        if not rows:
            continue
        first = rows[0]["tick"]
        if first > start:
            note = (
                f"the record's last {len(rows)} ticks (logging.recent); the monitor judged "
                f"{r['tick'] - start + 1} ticks since tick {start}"
            )
        else:
            note = f"ticks {first}..{r['tick']}: every tick since " + (
                "the requirement's last reset" if start > 0 else "monitoring started"
            )
        out[i] = window(rows, note)
    return out


def window(rows: list[dict[str, Any]], note: str) -> Window:
    """A window of ``recent``-style rows (each with its ``tick``)."""
    return Window(
        [int(row["tick"]) for row in rows],
        [{k: value(v) for k, v in row.items() if k != "tick"} for row in rows],
        note,
    )


def why_of(record: dict[str, Any], window: Window | None) -> Why:
    if window is None or not window.trace:
        return Why(window, problem="the record has no recent ticks to judge")
    try:
        formula = formula_for_record(record)
    except (ValueError, UserError, RecursionError) as e:  # the log's text: anything
        return Why(window, problem=f"the record's formula cannot be read: {e}")
    missing = missing_inputs(formula, window.trace)
    if missing:
        return Why(
            window,
            problem=f"the window lacks {', '.join(missing)} (the formula reads internal "
            "variables and the record has no formula_inputs)",
        )
    last = len(window.trace) - 1
    try:
        tree = why_tree(formula, window.trace, last)
        sentence = explain(formula, window.trace, last, first_tick=window.ticks[0])
    except (ValueError, TypeError, KeyError, UserError, RecursionError) as e:
        return Why(window, problem=f"the interpreter cannot judge this window: {e}")
    if bool(tree.values[last]):
        return Why(
            window,
            tree,
            problem=f"over these {len(window.trace)} ticks the formula holds at tick "
            f"{record.get('tick')}: the window is too short to show why the monitor, which "
            "judged a longer history, flagged it (give --bag and --config for a longer one)",
        )
    return Why(window, tree, sentence)
