"""``fleet report``'s page: one HTML file, its style inline and no script, a
Content-Security-Policy that admits that style alone (nothing is fetched); every
dataset string (robots, bags, requirements, reasons) escaped as text
(docs/reference/fleet.md, "fleet report")."""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Callable
from datetime import UTC, datetime

from monitors.untrusted import shown
from supervisor.tools.fleet.summary import (
    MAX_DAYS,
    MAX_LISTED,
    MAX_REASONS,
    MAX_ROBOTS,
    MAX_TEXT,
    HeatMap,
    Summary,
    Violation,
)
from supervisor.tools.report.assets import CSS as REPORT_CSS
from supervisor.tools.report.page import _ts
from supervisor.tools.report.page import e as _e

# Heat-map classes: the count's order of magnitude; the number is in every cell too.
BINS = [(1, 1, "h1"), (2, 9, "h2"), (10, 99, "h3"), (100, 999, "h4"), (1000, None, "h5")]
CSS = (
    REPORT_CSS
    + """
table.heat td.c{text-align:right;font-variant-numeric:tabular-nums;min-width:34px}
.h1{background:#fde8d7}.h2{background:#f9c49a}.h3{background:#f08a4b}
.h4{background:#d4481f;color:#fff}.h5{background:#8c1d06;color:#fff}
.new{color:#a40000;font-weight:600}.lost{color:#1f6a2e;font-weight:600}
"""
)
_STYLE_HASH = base64.b64encode(hashlib.sha256(CSS.encode()).digest()).decode()
CSP = f"default-src 'none'; style-src 'sha256-{_STYLE_HASH}'"

# A violation's bag -> the relative URL of its incident page, or None (no page).
Link = Callable[[Violation], "str | None"]


def e(x: object) -> str:
    """Dataset text as HTML text, its control and bidi characters shown escaped
    (``\\x1b``, ``\\u202e``: a name written right to left looks like another), cut to
    ``MAX_TEXT`` characters."""
    return _e(shown(str(x), MAX_TEXT))


def render(s: Summary, link: Link, notes: list[str]) -> str:
    now = _ts(int(datetime.now(UTC).timestamp() * 1e9))
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<meta http-equiv='Content-Security-Policy' content=\"{CSP}\">",
        f"<title>safety-supervisor fleet report: {e(s.root.name)}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>Fleet report: {e(s.root)}</h1>",
        f"<p class='muted'>made {e(now)} by <code>safety-supervisor fleet report</code></p>",
        _meta(s),
        *(f"<div class='note'>{e(n)}</div>" for n in notes),
        "<h2 id='bags'>Bags</h2>",
        _bags(s),
    ]
    if s.changes is not None:
        parts += ["<h2 id='changes'>New and lost against the baseline</h2>", _changes(s, link)]
    parts += ["<h2 id='requirements'>Violations per robot and day</h2>", _legend()]
    parts += [_heat(s, m, i, link) for i, m in enumerate(s.maps)]
    if not s.maps:
        parts.append("<p class='muted'>no violation in the dataset</p>")
    if s.maps_left:
        parts.append(f"<p class='more'>{s.maps_left} more requirement(s) not shown</p>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _meta(s: Summary) -> str:
    rows = [
        ("dataset", str(s.root)),
        ("configs (config_sha256)", ", ".join(s.configs) or "-"),
        ("bags", f"{sum(s.statuses.values()):,}"),
        ("messages replayed", f"{s.messages:,}"),
        ("violations", f"{s.violations:,}"),
    ]
    body = "".join(f"<tr><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in rows)
    return f"<table class='meta' id='meta'>{body}</table>"


def _bags(s: Summary) -> str:
    statuses = list(s.statuses)
    head = "<tr><th>robot</th>" + "".join(f"<th>{e(x)}</th>" for x in statuses) + "</tr>"
    rows = []
    for robot, counts in list(s.per_robot.items())[:MAX_ROBOTS]:
        cells = "".join(
            f"<td class='num' data-status='{e(x)}'>{counts.get(x, 0)}</td>" for x in statuses
        )
        rows.append(
            f"<tr class='bag-robot' data-robot='{e(robot)}'><td>{e(robot)}</td>{cells}</tr>"
        )
    total = "".join(f"<td class='num'>{s.statuses[x]}</td>" for x in statuses)
    rows.append(f"<tr class='total'><th>all</th>{total}</tr>")
    more = len(s.per_robot) - MAX_ROBOTS
    out = [f"<table id='bag-table'>{head}{''.join(rows)}</table>"]
    if more > 0:
        out.append(f"<p class='more'>{more} more robot(s) not shown</p>")
    if s.not_read:
        out.append("<h3>Bags not read whole</h3><table id='not-read'>")
        out.append("<tr><th>robot</th><th>bag</th><th>status</th><th>reason</th></tr>")
        for robot, bag, status, reason in s.not_read:
            out.append(
                f"<tr class='not-read' data-status='{e(status)}'><td>{e(robot)}</td>"
                f"<td class='mono'>{e(bag)}</td><td>{e(status)}</td><td>{e(reason)}</td></tr>"
            )
        out.append("</table>")
        if s.not_read_left:
            out.append(f"<p class='more'>{s.not_read_left} more bag(s) not read whole</p>")
    return "".join(out)


def _legend() -> str:
    items = "".join(
        f"<span><i class='{c}'></i>{lo}{'' if hi == lo else ('+' if hi is None else f'–{hi}')}"
        "</span>"
        for lo, hi, c in BINS
    )
    return (
        "<p class='legend' id='heat-legend'>violations per robot and day (each cell shows its "
        f"number; the colour its order of magnitude): {items}</p>"
    )


def _bin(n: int) -> str:
    for lo, hi, c in BINS:
        if n >= lo and (hi is None or n <= hi):
            return c
    return ""


def _heat(s: Summary, m: HeatMap, i: int, link: Link) -> str:
    several = len(s.configs) > 1
    title = e(m.requirement) + (f" <span class='muted'>(config {e(m.config_sha256[:12])})</span>"
                                if several else "")  # fmt: skip
    head = "<tr><th>robot \\ day</th>" + "".join(f"<th>{e(d)}</th>" for d in m.days) + "</tr>"
    rows = []
    for robot in m.robots:
        cells = []
        for d in m.days:
            n = m.cells.get((robot, d), 0)
            cells.append(
                f"<td class='c {_bin(n)}' data-day='{e(d)}' data-count='{n}'>{n or ''}</td>"
            )
        rows.append(f"<tr data-robot='{e(robot)}'><th>{e(robot)}</th>{''.join(cells)}</tr>")
    more = []
    if m.robots_left:
        more.append(
            f"{m.robots_left} more robot(s) with {m.robots_left_count:,} violation(s) not "
            f"shown (the {MAX_ROBOTS} with the most are)"
        )
    if m.days_left:
        more.append(
            f"{m.days_left} earlier day(s) with {m.days_left_count:,} violation(s) not shown "
            f"(the last {MAX_DAYS} are)"
        )
    out = [
        f"<section class='heat-map' id='req-{i}' data-requirement='{e(m.requirement)}' "
        f"data-config='{e(m.config_sha256)}' data-total='{m.total}'>",
        f"<h3>{title}: {m.total:,} violation(s)</h3>",
        f"<table class='heat'>{head}{''.join(rows)}</table>",
        *(f"<p class='more'>{e(x)}</p>" for x in more),
        _list(m.listed, m.bags, link, "violation"),
        "</section>",
    ]
    return "".join(out)


def _list(vs: list[Violation], bags: int, link: Link, cls: str) -> str:
    """The top bags of a requirement's violations, each linked to its incident page."""
    if not vs:
        return ""
    rows = []
    for v in vs:
        href = link(v)
        bag = f"<a href='{e(href)}'>{e(v.bag)}</a>" if href else e(v.bag)
        rows.append(
            f"<tr class='{cls}' data-robot='{e(v.robot)}' data-count='{v.count}'>"
            f"<td>{e(v.robot)}</td><td class='mono'>{bag}</td><td class='num'>{v.count}</td>"
            f"<td>{e(_ts(v.recorded_ns))} (tick {v.tick})</td></tr>"
        )
    more = bags - len(vs)
    tail = f"<p class='more'>{more:,} more bag(s) not listed</p>" if more > 0 else ""
    return (
        f"<table class='list'><tr><th>robot</th><th>bag (its incident page)</th>"
        f"<th>violations</th><th>first</th></tr>{''.join(rows)}</table>{tail}"
    )


def _changes(s: Summary, link: Link) -> str:
    c = s.changes
    assert c is not None
    out = [
        f"<p>Baseline (A): {e(c.base_label)}; B: {e(c.new_label)}. "
        f"Compared over the {c.bags_compared:,} bag(s) both judged (by content); "
        f"{c.bags_one_side:,} judged by one side only are left out. A violation is the same "
        "when its bag, requirement and recorded time are. <span class='new'>new</span>: only "
        "B reports it; <span class='lost'>lost</span>: only A does.</p>"
    ]
    if not c.rows:
        out.append("<p class='muted'>no violation on either side</p>")
        return "".join(out)
    out.append(
        "<table id='changes-table'><tr><th>requirement</th><th>robot</th><th>A</th><th>B</th>"
        "<th>new</th><th>lost</th><th>both</th><th>first in bags (A/B)</th></tr>"
    )
    for r in c.rows[: MAX_ROBOTS * 10]:
        out.append(
            f"<tr class='change' data-requirement='{e(r.requirement)}' data-robot='{e(r.robot)}' "
            f"data-new='{r.only_b}' data-lost='{r.only_a}'><td>{e(r.requirement)}</td>"
            f"<td>{e(r.robot)}</td><td class='num'>{r.a}</td><td class='num'>{r.b}</td>"
            f"<td class='num new'>{r.only_b}</td><td class='num lost'>{r.only_a}</td>"
            f"<td class='num'>{r.both}</td><td class='num'>{r.a_first}/{r.b_first}</td></tr>"
        )
    out.append("</table>")
    if len(c.rows) > MAX_ROBOTS * 10:
        out.append(f"<p class='more'>{len(c.rows) - MAX_ROBOTS * 10} more row(s) not shown</p>")
    for what, lists in (("new", c.new), ("lost", c.lost)):
        for req, (bags, vs) in lists.items():
            out.append(
                f"<h3 class='{what}' data-requirement='{e(req)}'>{what}: {e(req)}, "
                f"in {bags:,} bag(s)</h3>"
            )
            out.append(_list(vs, bags, link, f"{what}-violation"))
    return "".join(out)


__all__ = ["CSP", "MAX_LISTED", "MAX_REASONS", "render"]
