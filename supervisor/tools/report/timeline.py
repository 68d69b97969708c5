"""The timeline as inline SVG: event lanes (violations, predictions with their lead
times, mitigations, resets, the supervisor's own events) over the inputs (numbers as
step lines, Booleans as bands, stale stretches shaded), and under them the violated
requirements' margins (margins.py) with their zero line.

Drawn in Python so that the page reads without scripts; the page's small script
(page.py) only zooms (one horizontal scale on the plot group, strokes kept by
``vector-effect``), redraws the time axis and shows the inputs' values under the cursor.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from html import escape
from typing import Any

from supervisor.tools.report.inputs import Series

LABEL = 170  # px left of the plot for the lane names
W = 1000  # plot width in user units (also px at zoom 1)
TOP = 6
LANE = 22  # an event lane
NUM = 56  # a numeric input
BAND = 20  # a Boolean input
AXIS = 26

# supervisor records worth a label on the timeline (the rest are markers only)
MAJOR = {"start", "stop", "reload", "replay", "record_stopped", "records_lost", "replay_damaged"}


@dataclass
class Lane:
    name: str
    y: float
    h: float
    kind: str


def _x(t: int, t0: int, t1: int) -> float:
    return round((t - t0) * W / (t1 - t0), 3)


def _title(text: str) -> str:
    return f"<title>{escape(text)}</title>"


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def marker_text(r: dict[str, Any]) -> str:
    """One line per record for the marker's hover text."""
    ev = r.get("event")
    ts = r.get("recorded_ts") or r.get("ts")
    if ev == "violation":
        lead = r.get("predicted_ms")
        ahead = f" predicted {_fmt(lead)} ms ahead" if lead is not None else ""
        return f"VIOLATION {r.get('requirement')} tick={r.get('tick')}{ahead} at {ts}"
    if ev == "prediction":
        return (
            f"PREDICTION {r.get('requirement')} tick={r.get('tick')}: violated in "
            f"{_fmt(r.get('ttv_ms'))} ms ({_fmt(r.get('ttv_lo_ms'))}..{_fmt(r.get('ttv_hi_ms'))}),"
            f" margin {_fmt(r.get('margin'))}, slope {_fmt(r.get('slope'))}/s, confidence "
            f"{_fmt(r.get('confidence'))} at {ts}"
        )
    if ev == "prediction_expired":
        return (
            f"prediction expired {r.get('requirement')}: the prediction of tick "
            f"{r.get('predicted_tick')} not followed by a violation "
            f"{_fmt(r.get('after_ms'))} ms later at {ts}"
        )
    if ev == "mitigation":
        ok = "ok" if r.get("ok") else f"FAILED ({r.get('error')})"
        dry = " dry_run" if r.get("dry_run") else ""
        return (
            f"mitigation {r.get('requirement')} {r.get('kind')}:{r.get('action')} {ok} "
            f"latency_ms={r.get('latency_ms')} attempt={r.get('attempt', 1)}{dry} at {ts}"
        )
    if ev == "reset":
        return f"reset {r.get('requirement')} {r.get('reason')} tick={r.get('tick', '-')} at {ts}"
    skip = {"ts", "event", "component", "config_sha256", "prev_sha256", "seq", "line_sha256"}
    rest = " ".join(
        f"{k}={json.dumps(v)[:80]}"
        for k, v in r.items()
        if k not in skip and k != "what" and not k.startswith("_")
    )
    return f"{r.get('what')} {rest} at {ts}".strip()


PREDICTIONS = ("prediction", "prediction_expired")


def domain(records: list[dict[str, Any]], series: dict[str, Series]) -> tuple[int, int]:
    ts = [r["_t"] for r in records]
    for s in series.values():
        if s.points:
            ts += [s.points[0][0], s.points[-1][0]]
    t0, t1 = min(ts), max(ts)
    pad = max((t1 - t0) // 50, 50_000_000)  # markers at the ends stay visible
    return t0 - pad, t1 + pad


def svg(
    records: list[dict[str, Any]],
    series: dict[str, Series],
    anchors: dict[int, str],
    margins: dict[str, Series] | None = None,
) -> tuple[str, dict[str, Any]]:
    """The SVG and the data the script reads (times in seconds from t0).

    ``anchors``: the index of a violation record -> the id of its why-tree section
    (its marker links there).  ``margins``: drawn under the inputs, each with its
    zero line; a predictions lane only when the records have predictions."""
    margins = margins or {}
    t0, t1 = domain(records, {**series, **margins})
    lanes: list[Lane] = []
    y = 0.0
    events = ["violations", "mitigations", "resets", "supervisor"]
    if any(r.get("event") in PREDICTIONS for r in records):
        events.insert(1, "predictions")
    for name in events:
        lanes.append(Lane(name, y, LANE, "event"))
        y += LANE
    for s in series.values():
        h = BAND if s.kind == "bool" else NUM
        lanes.append(Lane(s.name, y + 4, h, s.kind))
        y += h + 8
    for s in margins.values():
        lanes.append(Lane(s.name, y + 4, NUM, "margin"))
        y += NUM + 8
    height = y
    body: list[str] = []
    by_name = {ln.name: ln for ln in lanes}
    for ln in lanes:
        cls = "lane-event" if ln.kind == "event" else "lane-input"
        body.append(f'<rect class="{cls}" x="0" y="{ln.y}" width="{W}" height="{ln.h}"/>')
    for name, s in series.items():
        body.extend(_input(s, by_name[name], t0, t1))
    for name, s in margins.items():
        body.extend(_input(s, by_name[name], t0, t1, margin=True))
    if "predictions" in by_name:
        body.extend(_leads(records, by_name["predictions"], t0, t1))
    body.extend(_stale(records, by_name, t0, t1))
    body.extend(_events(records, by_name, t0, t1, height, anchors))
    labels = []
    for ln in lanes:
        text = ln.name
        s = series.get(ln.name) or margins.get(ln.name)
        extra = ""
        if s is not None and s.kind == "number":
            lo, hi = _range(s, margin=ln.kind == "margin")
            extra = f'<tspan class="range" x="{LABEL - 8}" dy="13">{_fmt(lo)} .. {_fmt(hi)}</tspan>'
        labels.append(
            f'<text class="lane-label" x="{LABEL - 8}" y="{ln.y + min(ln.h, 22) / 2 + 4 + TOP}">'
            f"{escape(text)}{extra}</text>"
        )
    total_h = TOP + height + AXIS
    out = (
        f'<svg id="timeline" xmlns="http://www.w3.org/2000/svg" '
        f'viewBox="0 0 {LABEL + W + 10} {total_h}" width="100%" '
        f'data-width="{W}" data-label="{LABEL}" data-top="{TOP}" data-height="{height}">'
        f'<defs><clipPath id="plotclip"><rect x="0" y="-2" width="{W}" '
        f'height="{height + 4}"/></clipPath></defs>'
        f'<g class="labels">{"".join(labels)}</g>'
        f'<g transform="translate({LABEL},{TOP})" clip-path="url(#plotclip)">'
        f'<g id="zoom">{"".join(body)}</g>'
        f'<line id="cursor" x1="-10" x2="-10" y1="0" y2="{height}"/></g>'
        f'<g id="axis" transform="translate({LABEL},{TOP + height})"></g>'
        "</svg>"
    )
    data = {
        "span": (t1 - t0) / 1e9,
        "series": [
            {
                "name": s.name,
                "kind": s.kind,
                "t": [round((t - t0) / 1e9, 9) for t, _ in s.points],
                "v": [_json_value(v) for _, v in s.points],
            }
            for s in (*series.values(), *margins.values())
        ],
    }
    return out, data


def _json_value(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v


def _range(s: Series, *, margin: bool = False) -> tuple[float, float]:
    """The values' range; a margin's always holds 0 (its zero line is in the lane)."""
    vals = [float(v) for _, v in s.points if math.isfinite(float(v))]
    if margin:
        vals.append(0.0)
    if not vals:
        return 0.0, 1.0
    return min(vals), max(vals)


def _input(s: Series, ln: Lane, t0: int, t1: int, *, margin: bool = False) -> list[str]:
    if not s.points:
        return []
    end = s.points[-1][0]
    if s.kind == "bool":
        out = []
        for i, (t, v) in enumerate(s.points):
            nxt = s.points[i + 1][0] if i + 1 < len(s.points) else end
            if v and nxt > t:
                a, b = _x(t, t0, t1), _x(nxt, t0, t1)
                out.append(
                    f'<rect class="band" x="{a}" y="{ln.y + 3}" width="{max(b - a, 0.3)}" '
                    f'height="{ln.h - 6}"/>'
                )
        return out
    lo, hi = _range(s, margin=margin)
    span = hi - lo

    def yv(v: float) -> float:
        # a constant (or a span floats cannot hold) is drawn mid-lane
        frac = (v - lo) / span if 0 < span < math.inf else 0.5
        return round(ln.y + ln.h - 3 - (frac if math.isfinite(frac) else 0.5) * (ln.h - 6), 2)

    parts: list[str] = []
    pen = False
    for t, v in s.points:
        f = float(v)
        x = _x(t, t0, t1)
        if not math.isfinite(f):  # NaN or an infinity: a gap in the line
            pen = False
            continue
        parts.append(f"H{x}V{yv(f)}" if pen else f"M{x} {yv(f)}")
        pen = True
    if not margin:
        return [f'<path class="line" d="{"".join(parts)}"/>'] if parts else []
    z = yv(0.0)
    zero = f'<line class="zero" x1="0" x2="{W}" y1="{z}" y2="{z}"/>'
    path = f'<path class="line margin" d="{"".join(parts)}"/>' if parts else ""
    return [zero, path]


def _leads(records: list[dict[str, Any]], ln: Lane, t0: int, t1: int) -> list[str]:
    """Each predicted violation's lead time: a bar in the predictions lane from
    ``predicted_ms`` before the violation to the violation."""
    out = []
    for r in records:
        lead = r.get("predicted_ms")
        if r.get("event") != "violation" or isinstance(lead, bool):
            continue
        if not isinstance(lead, int | float) or not 0 <= lead < 1e9:  # the log's: anything
            continue
        b = r["_t"]
        a = b - int(lead * 1_000_000)
        xa, xb = _x(a, t0, t1), _x(b, t0, t1)
        rid = str(r.get("requirement"))
        req = escape(rid)
        said = f"{rid} predicted {_fmt(lead)} ms ahead"
        out.append(
            f'<rect class="lead" data-requirement="{req}" data-lead-ms="{_fmt(lead)}" '
            f'x="{xa}" y="{ln.y + 6}" width="{max(xb - xa, 0.5)}" height="{ln.h - 12}">'
            f"{_title(said)}</rect>"
        )
    return out


def _stale(records: list[dict[str, Any]], lanes: dict[str, Lane], t0: int, t1: int) -> list[str]:
    """input_stale .. input_recovered, shaded on the input's lane."""
    out = []
    since: dict[str, int] = {}
    end = records[-1]["_t"] if records else t1
    for r in records:
        if r.get("event") != "supervisor":
            continue
        name = str(r.get("input"))
        if r.get("what") == "input_stale":
            since.setdefault(name, r["_t"])
        elif r.get("what") == "input_recovered" and name in since:
            out.append(_stale_rect(name, since.pop(name), r["_t"], lanes, t0, t1))
    for name, t in since.items():
        out.append(_stale_rect(name, t, end, lanes, t0, t1))
    return [s for s in out if s]


def _stale_rect(name: str, a: int, b: int, lanes: dict[str, Lane], t0: int, t1: int) -> str:
    ln = lanes.get(name)
    if ln is None:
        return ""
    xa, xb = _x(a, t0, t1), _x(b, t0, t1)
    return (
        f'<rect class="stale" data-input="{escape(name)}" x="{xa}" y="{ln.y}" '
        f'width="{max(xb - xa, 0.5)}" height="{ln.h}">{_title(f"{name} stale")}</rect>'
    )


def _events(
    records: list[dict[str, Any]],
    lanes: dict[str, Lane],
    t0: int,
    t1: int,
    height: float,
    anchors: dict[int, str],
) -> list[str]:
    out = []
    for i, r in enumerate(records):
        ev = r.get("event")
        x = _x(r["_t"], t0, t1)
        if ev == "violation":
            ln, cls = lanes["violations"], "violation"
            out.append(f'<line class="vline" x1="{x}" x2="{x}" y1="{LANE}" y2="{height}"/>')
        elif ev == "mitigation":
            ln = lanes["mitigations"]
            cls = "mitigation " + ("ok" if r.get("ok") else "failed")
            cls += " dry" if r.get("dry_run") else ""
        elif ev == "reset":
            ln, cls = lanes["resets"], "reset"
        elif ev in PREDICTIONS:
            ln, cls = (
                lanes["predictions"],
                "prediction" + (" expired" if ev != "prediction" else ""),
            )
        else:
            ln = lanes["supervisor"]
            what = str(r.get("what"))
            cls = "supervisor " + ("major" if what in MAJOR else "minor")
            cls += " input" if what.startswith("input_") else ""
        attrs = f' data-t="{r["_t"]}" data-event="{escape(str(ev))}"'
        if r.get("requirement") is not None:
            attrs += f' data-requirement="{escape(str(r["requirement"]))}"'
        if isinstance(r.get("tick"), int):
            attrs += f' data-tick="{r["tick"]}"'
        line = (
            f'<line class="mk {cls}" x1="{x}" x2="{x}" y1="{ln.y + 2}" y2="{ln.y + ln.h - 2}"'
            f"{attrs}>{_title(marker_text(r))}</line>"
        )
        if i in anchors:
            line = f'<a href="#{anchors[i]}">{line}</a>'
        out.append(line)
    return out
