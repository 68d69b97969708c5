"""The margins drawn under the timeline: each violated requirement's margin over the
windows its why-trees judge (docs/reference/commands.md, "report").

Computed by the reference interpreter (monitors/verify/robustness.py) over the same
windows as the why-trees (from the recording's replay, else the records' recent
ticks), so no monitor is built for the page.  The formula is the requirement's
without an unbounded ``H`` at its top, as the predictions fit it
(docs/reference/prediction.md): the margin of "now", which rises as well as falls,
where the ``H``'s running minimum only falls.  Ticks are placed in time by the
records' ticks and times (inputs.tick_clock), the line broken between windows
that do not meet, and thinned to inputs.MAX_POINTS points.
"""

from __future__ import annotations

import math
from typing import Any

from monitors.errors import UserError
from monitors.ir.formula import Formula, Past
from monitors.verify.robustness import margins
from monitors.verify.why import formula_for_record, missing_inputs
from supervisor.config.model import Config
from supervisor.tools.report.data import LogData
from supervisor.tools.report.inputs import Series, period_ns, thin, tick_clock
from supervisor.tools.why import Window

PREFIX = "margin "  # a margin's series name: no input's name has a space


def _now_part(f: Formula) -> Formula:
    """``f`` of ``H f`` (unbounded): what a prediction fits (supervisor/pipeline.py)."""
    if isinstance(f, Past) and f.op == "H" and not f.lo and f.hi is None:
        return f.arg
    return f


def margin_series(
    data: LogData, windows: dict[int, Window], cfg: Config | None
) -> tuple[dict[str, Series], list[str]]:
    """Each requirement's margin at the ticks of its violations' windows (record
    index -> window), and notes on the ones that cannot be computed.  A requirement
    whose margins are all infinite (boolean atoms only) has no line."""
    bool_margin = math.inf if cfg is None or cfg.step.margins is None else cfg.step.margins
    at = tick_clock(data, period_ns(cfg))
    per: dict[str, dict[tuple[int, int], float]] = {}
    problems: dict[str, str] = {}
    for i in sorted(windows):
        w, rec = windows[i], data.records[i]
        rid = str(rec.get("requirement"))
        if not w.trace:
            continue
        try:
            formula = _now_part(formula_for_record(rec))
            if missing_inputs(formula, w.trace):
                problems.setdefault(rid, "its window lacks inputs the formula reads")
                continue
            ms = margins(formula, w.trace, bool_margin=bool_margin)
        except (ValueError, TypeError, KeyError, UserError, RecursionError) as e:
            problems.setdefault(rid, f"the interpreter cannot judge its window: {e}")
            continue
        got = per.setdefault(rid, {})
        for tick, m in zip(w.ticks, ms, strict=True):
            got[(rec["_run"], tick)] = m
    out: dict[str, Series] = {}
    for rid, got in per.items():
        if not any(math.isfinite(m) for m in got.values()):
            continue  # boolean atoms only: nothing to draw on a scale
        pts: list[tuple[int, Any]] = []
        prev: tuple[int, int] | None = None
        for run, tick in sorted(got):
            if prev is not None and (run, tick - 1) != prev:
                pts.append((at(run, tick), math.nan))  # windows apart: a gap, not a line
            pts.append((at(run, tick), got[(run, tick)]))
            prev = (run, tick)
        pts.sort(key=lambda p: p[0])  # stable: a gap stays before its point
        out[PREFIX + rid] = Series(PREFIX + rid, "number", thin(pts, "number"))
    notes = [f"no margins of {rid}: {why}" for rid, why in problems.items() if rid not in per]
    return out, notes
