"""The report as one HTML file: everything inline, nothing fetched."""

from __future__ import annotations

import json
import math
from datetime import UTC, datetime
from html import escape
from pathlib import Path
from typing import Any

from monitors.verify.why import WhyNode
from supervisor.tools.report.assets import CSS, JS
from supervisor.tools.report.build import Report, Requirement
from supervisor.tools.report.data import median
from supervisor.tools.report.inputs import SHOWN_PER_REQUIREMENT
from supervisor.tools.report.timeline import MAJOR, domain, marker_text, svg
from supervisor.tools.why import Why

SHOWN_TICKS = 12  # columns of a why-tree: the violating tick and the ones before it


def e(x: Any) -> str:
    return escape(str(x))


def _v(x: Any) -> str:
    if isinstance(x, bool):
        return "T" if x else "F"
    if isinstance(x, float):
        return f"{x:.6g}" if math.isfinite(x) else str(x)
    return str(x)


def _ts(ns: int) -> str:
    try:
        dt = datetime.fromtimestamp(ns // 1_000_000_000, tz=UTC)
    except (OverflowError, ValueError, OSError):  # a time estimated far out of range
        return f"{ns} ns since 1970"
    return f"{dt:%Y-%m-%dT%H:%M:%S}.{ns % 1_000_000_000 // 1000:06d}Z"


# In JSON text these occur only inside strings, where the escapes mean the same; so
# no record's text can end the <script> element or open an HTML comment in it.
_SCRIPT_SAFE = str.maketrans(
    {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}
)


def script_json(doc: Any) -> str:
    """``doc`` as JSON that is safe inside a ``<script>`` element."""
    return json.dumps(doc, separators=(",", ":")).translate(_SCRIPT_SAFE)


def anchor(i: int) -> str:
    return f"v{i}"


def render(rep: Report) -> str:
    data = rep.data
    recs = data.records
    comp = next((r.get("component") for r in recs if r.get("component")), "?")
    violated = [q for q in rep.requirements if q.violations]
    timeline, tl_data = svg(recs, rep.series, {i: anchor(i) for i in rep.whys}, rep.margins)
    t0, _ = domain(recs, {**rep.series, **rep.margins})
    tl_json = script_json(tl_data)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>safety-supervisor report: {e(comp)}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>Safety supervisor report: {e(comp)}</h1>",
        f"<p class='muted'>made {e(_ts(int(datetime.now(UTC).timestamp() * 1e9)))} by "
        "<code>safety-supervisor report</code></p>",
        _integrity(rep),
        _meta(rep, comp, violated),
        *(f"<div class='note'>{e(n)}</div>" for n in rep.notes),
        "<h2 id='timeline-section'>Timeline</h2>",
        f"<p class='muted'>t = 0 s is {e(_ts(t0))}. Inputs: {e(rep.series_source)}. "
        "Wheel: zoom; drag: pan; double-click: whole run; hover: values; a violation's "
        "marker links to why it fired.</p>",
        _margins_note(rep),
        _legend(),
        timeline,
        "<div id='tip' hidden></div>",
        f"<script type='application/json' id='timeline-data'>{tl_json}</script>",
        "<h2 id='requirements'>Requirements</h2>",
        _req_table(rep),
        *(_req_detail(rep, q) for q in rep.requirements if q.violations or q.actions),
        "<h2 id='why'>Why it fired</h2>",
        _why_intro(rep),
        *(_why_section(rep, q) for q in violated),
        "<h2 id='supervisor'>Supervisor events</h2>",
        _supervisor(rep),
        f"<script>{JS}</script></body></html>",
    ]
    return "\n".join(parts)


def _integrity(rep: Report) -> str:
    integ = rep.data.integrity
    n, files = len(rep.data.records), len(rep.data.paths)
    if integ.ok:
        head = f"Hash chain verified: {n} records in {files} file(s), intact."
    else:
        head = f"HASH CHAIN DOES NOT VERIFY: {integ.first_problem}"
    lines = integ.lines + integ.skipped
    return (
        f"<div id='integrity' class='integrity {'ok' if integ.ok else 'broken'}' "
        f"data-ok='{str(integ.ok).lower()}'>{e(head)}</div>"
        f"<details{' open' if not integ.ok else ''}><summary>logs --verify</summary>"
        f"<pre>{e(chr(10).join(lines))}</pre></details>"
    )


def _meta(rep: Report, comp: Any, violated: list[Requirement]) -> str:
    recs = rep.data.records
    rows = [
        ("component", comp),
        ("log files", ", ".join(rep.data.paths)),
        ("records", f"{len(recs)}, {_ts(recs[0]['_t'])} .. {_ts(recs[-1]['_t'])}"),
        ("config_sha256", ", ".join(sorted(rep.data.hashes)) or "-"),
        ("config", str(rep.config) if rep.config else f"none: {rep.no_config}"),
        ("recordings", ", ".join(rep.bags) or "none (inputs from the records' recent ticks)"),
        (
            "violations",
            f"{sum(len(q.violations) for q in violated)} of {len(violated)} requirement(s)",
        ),
    ]
    if rep.data.dry_run:
        rows.append(("mitigations", "dry run (a replay's log: no action was executed)"))
    body = "".join(f"<tr><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in rows)
    return f"<table class='meta'>{body}</table>"


def _margins_note(rep: Report) -> str:
    """What the margin lanes under the inputs are, when there are any."""
    if not rep.margins:
        return ""
    return (
        "<p class='muted' id='margins-note'>Under the inputs, each violated requirement's "
        "margin (how far from breaking, in its inputs' units; below 0: violated), "
        "computed by the reference interpreter over the ticks its why-trees judge, for "
        "the requirement's formula without an unbounded H at its top, as predictions "
        "fit it.</p>"
    )


def _legend() -> str:
    items = [
        ("#d0202a", "violation"),
        ("#1f8a3a", "mitigation ok"),
        ("#7a0010", "mitigation failed"),
        ("#3060c0", "reset"),
        ("#7040a0", "start/stop/reload/recording"),
        ("#e08a00", "input event"),
        ("#f0a03060", "input stale"),
        ("#5a8fd0", "Boolean true"),
        ("#e06000", "prediction"),
        ("#a0a0a0", "prediction expired"),
        ("#f4b07a", "lead time of a predicted violation"),
        ("#8a3ab9", "margin (0: dashed)"),
    ]
    return (
        "<p class='legend'>"
        + "".join(f"<span><i style='background:{c}'></i>{e(t)}</span>" for c, t in items)
        + "</p>"
    )


def _actions(q: Requirement) -> str:
    if not q.actions:
        return "-"
    out = []
    for name, a in q.actions.items():
        s = f"{a['kind']}:{name} ok {a['ok']}, failed {a['failed']}"
        if a["dry_run"]:
            s += f" (dry_run {a['dry_run']})"
        out.append(e(s))
    return "<br>".join(out)


def _latency(q: Requirement) -> str:
    lat = q.latency
    if lat is None:
        return "dry run" if any(a["dry_run"] for a in q.actions.values()) else "-"
    return f"p50 {lat[0]:.3f} ms, max {lat[1]:.3f} ms"


def _first_last(rep: Report, q: Requirement) -> tuple[str, str]:
    if not q.violations:
        return "-", "-"
    recs = rep.data.records
    a, b = recs[q.violations[0]], recs[q.violations[-1]]
    return (
        f"{a.get('recorded_ts') or a['ts']} (tick {a.get('tick')})",
        f"{b.get('recorded_ts') or b['ts']} (tick {b.get('tick')})",
    )


def _req_table(rep: Report) -> str:
    head = (
        "<tr><th>requirement</th><th>violations</th><th>first</th><th>last</th>"
        "<th>mitigations</th><th>detection to action</th></tr>"
    )
    rows = []
    for q in rep.requirements:
        first, last = _first_last(rep, q)
        link = f"<a href='#req-{e(q.id)}'>{e(q.id)}</a>" if q.violations or q.actions else e(q.id)
        rows.append(
            f"<tr class='req-row' data-requirement='{e(q.id)}' data-violations='{len(q.violations)}'>"
            f"<td>{link}</td><td class='num'>{len(q.violations)}</td><td>{e(first)}</td>"
            f"<td>{e(last)}</td><td>{_actions(q)}</td><td>{e(_latency(q))}</td></tr>"
        )
    return f"<table id='req-table'>{head}{''.join(rows)}</table>"


def _predictions(q: Requirement) -> str:
    """Its predictions, the expired ones, and the lead times of the violations they
    predicted (docs/reference/prediction.md)."""
    text = f"{q.predictions} made, {q.expired} expired; {len(q.leads)} violation(s) predicted"
    if q.leads:
        text += f", lead min {min(q.leads):.6g} ms, p50 {median(q.leads):.6g} ms"
    return text


def _req_detail(rep: Report, q: Requirement) -> str:
    no_cfg = f"(needs the config: {rep.no_config})"
    first, last = _first_last(rep, q)
    rows = [
        ("text", q.text or "-"),
        ("formula", q.formula or "-"),
        ("reading", q.reading if q.reading is not None else no_cfg),
        ("rationale", q.rationale if q.rationale is not None else no_cfg),
        ("violations", str(len(q.violations))),
        ("first", first),
        ("last", last),
    ]
    body = "".join(
        f"<tr><td>{e(k)}</td><td class='{'mono' if k == 'formula' else ''}'>{e(v) or '-'}</td></tr>"
        for k, v in rows
    )
    body += f"<tr><td>mitigations</td><td>{_actions(q)}</td></tr>"
    body += f"<tr><td>detection to action</td><td>{e(_latency(q))}</td></tr>"
    if q.predictions or q.expired or q.leads:
        body += f"<tr><td>predictions</td><td class='predictions'>{e(_predictions(q))}</td></tr>"
    return (
        f"<section class='requirement' id='req-{e(q.id)}' data-requirement='{e(q.id)}'>"
        f"<h3>{e(q.id)}</h3><table class='meta'>{body}</table></section>"
    )


def _why_intro(rep: Report) -> str:
    return (
        "<p class='muted'>For each violation (the first "
        f"{SHOWN_PER_REQUIREMENT} per requirement), the formula as a tree with every "
        "subformula's value at the violating tick (last column) and the ticks before it, "
        "as the reference interpreter judges them; outlined cells are the reason. "
        "T: holds, F: does not.</p>"
    )


def _why_section(rep: Report, q: Requirement) -> str:
    out = [f"<h3>{e(q.id)}</h3>"]
    for i in q.violations[:SHOWN_PER_REQUIREMENT]:
        out.append(_why_one(rep, i, rep.whys.get(i)))
    rest = len(q.violations) - SHOWN_PER_REQUIREMENT
    if rest > 0:
        out.append(f"<p class='muted'>and {rest} more violation(s) of {e(q.id)} not shown.</p>")
    return "".join(out)


def _why_one(rep: Report, i: int, why: Why | None) -> str:
    rec = rep.data.records[i]
    head = (
        f"<b>{e(rec.get('requirement'))}</b> at tick {e(rec.get('tick'))}, "
        f"{e(rec.get('recorded_ts') or rec.get('ts'))}"
    )
    extra = []
    if rec.get("stale"):
        extra.append(f"stale inputs: {', '.join(map(str, rec['stale']))}")
    ps = rec.get("policy_state")
    if isinstance(ps, dict):
        extra.append("policy: " + ", ".join(f"{k}={v}" for k, v in ps.items()))
    body = [f"<div>{head}</div>"]
    if why is None:
        body.append("<div class='note'>no window for this violation</div>")
    else:
        if why.sentence:
            body.append(f"<div class='sentence'>{e(why.sentence)}</div>")
        if why.problem:
            body.append(f"<div class='note problem'>{e(why.problem)}</div>")
        if why.window is not None:
            body.append(f"<div class='muted'>window: {e(why.window.note)}</div>")
        if why.tree is not None and why.window is not None:
            body.append(_tree(why.tree, why.window.ticks))
    body += [f"<div class='muted'>{e(x)}</div>" for x in extra]
    return (
        f"<div class='why' id='{anchor(i)}' data-requirement='{e(rec.get('requirement'))}' "
        f"data-tick='{e(rec.get('tick'))}'>{''.join(body)}</div>"
    )


def _tree(root: WhyNode, ticks: list[int]) -> str:
    n = len(ticks)
    cols = list(range(max(0, n - SHOWN_TICKS), n))
    head = "".join(f"<th class='{'now' if c == n - 1 else ''}'>{ticks[c]}</th>" for c in cols)
    rows: list[str] = []

    def walk(node: WhyNode, depth: int) -> None:
        blamed = set(getattr(node, "blame_ticks", ()) or ())
        cells = []
        for c in cols:
            v = node.values[c]
            cls = ["v"]
            if isinstance(v, bool):
                cls.append("true" if v else "false")
            if c in blamed or (node.blame and c == n - 1 and not blamed):
                cls.append("blame")
            cells.append(f"<td class='{' '.join(cls)}' data-tick='{ticks[c]}'>{e(_v(v))}</td>")
        rows.append(
            f"<tr class='node{' blame' if node.blame else ''}' data-text='{e(node.text)}' "
            f"data-depth='{depth}'><td class='f'>{'  ' * depth}{e(node.text)}</td>"
            f"{''.join(cells)}</tr>"
        )
        for c in node.children:
            walk(c, depth + 1)

    walk(root, 0)
    shown = (
        ""
        if n <= SHOWN_TICKS
        else (
            f"<div class='muted'>the last {SHOWN_TICKS} of the window's {n} ticks shown; "
            "the values judge all of them</div>"
        )
    )
    return (
        f"<table class='why-tree'><tr><th>subformula \\ tick</th>{head}</tr>"
        f"{''.join(rows)}</table>{shown}"
    )


def _supervisor(rep: Report) -> str:
    rows = []
    for r in rep.data.records:
        if r.get("event") != "supervisor":
            continue
        what = str(r.get("what"))
        cls = "major" if what in MAJOR else ""
        rows.append(
            f"<tr class='{cls}'><td>{e(r.get('recorded_ts') or r.get('ts'))}</td>"
            f"<td>{e(what)}</td><td class='mono'>{e(marker_text(r))}</td></tr>"
        )
    if not rows:
        return "<p class='muted'>none</p>"
    return (
        "<table id='supervisor-table'><tr><th>time</th><th>what</th><th>record</th></tr>"
        + "".join(rows)
        + "</table>"
    )


def write(rep: Report, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render(rep), encoding="utf-8")
