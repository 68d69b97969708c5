"""The margins ``report`` draws (supervisor/tools/report/margins.py): the reference
interpreter over the why-trees' windows, placed by the records' ticks and times."""

from __future__ import annotations

import math
from typing import Any

from supervisor.tools.report.data import Integrity, LogData
from supervisor.tools.report.margins import margin_series
from supervisor.tools.why import window

S = 1_000_000_000


def _violation(tick: int, t_s: int) -> dict[str, Any]:
    return {"event": "violation", "requirement": "keep_away", "tick": tick, "_t": t_s * S,
            "_run": 0, "formula": "(H (distance >= 3.0))"}  # fmt: skip


def test_windows_apart_are_a_gap_and_the_formula_is_judged_without_its_h() -> None:
    records = [_violation(10, 10), _violation(30, 30)]
    data = LogData(["log"], Integrity(True, None, []), records)
    windows = {
        0: window([{"tick": t, "distance": 12.0 - t} for t in (8, 9, 10)], "w"),
        1: window([{"tick": t, "distance": 31.0 - t} for t in (28, 29, 30)], "w"),
    }
    series, notes = margin_series(data, windows, None)
    assert notes == []
    (line,) = series.values()
    assert line.name == "margin keep_away"
    # one tick a second (the records' ticks and times); distance - 3 at each tick,
    # not H's running minimum; a gap (NaN) where the second window starts
    t = [p[0] // S for p in line.points]
    v = [p[1] for p in line.points]
    assert t == [8, 9, 10, 28, 28, 29, 30]
    assert v[:3] == [1.0, 0.0, -1.0] and math.isnan(v[3]) and v[4:] == [0.0, -1.0, -2.0]


def test_a_boolean_only_requirement_has_no_line() -> None:
    rec = dict(_violation(2, 2), formula="(H uv_on)")
    data = LogData(["log"], Integrity(True, None, []), [rec])
    w = window([{"tick": t, "uv_on": t < 2} for t in (0, 1, 2)], "w")
    assert margin_series(data, {0: w}, None) == ({}, [])
