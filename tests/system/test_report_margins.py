"""``report`` draws margins under the timeline and predictions as their own markers
(docs/reference/commands.md, "report"): a log made by ``replay`` (the daemon's core)
of a scripted walk toward the lamp, one walk stopping short (its prediction expires)
and one reaching it (predicted, with its lead time); the page in headless Chromium.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import pytest
from browser import open_page
from inproc import cli_main

from mitigations.violationlog.reader import iter_records
from supervisor.tools.report.inputs import SHOWN_PER_REQUIREMENT

MS = 1_000_000

CONFIG = """\
component: lamp
step: {policy: periodic, period_ms: 20}
logging: {recent: 50}
variables:
  distance: {type: double, topic: /distance, msg: std_msgs/msg/Float64}
  uv_on: {type: bool, topic: /uv, msg: std_msgs/msg/Bool}
requirements:
  - id: keep_away
    text: lamp shall always satisfy uv_on -> distance >= 3.0
    on_violation: [halt]
    policy: {reset: after_mitigation}
    predict: {horizon_ms: 1500, window_ms: 500, actions: [slow]}
  - id: lamp_on
    text: lamp shall always satisfy uv_on
mitigations:
  halt: {log: {message: halt}}
  slow: {log: {message: slow}}
"""


def _trace(path: Path, walks: list[float]) -> Path:
    """Walks to these closest distances, each from 8 m at 1 m/s and then away at 2 m/s."""
    lines = [{"t_ns": 10**9, "name": "uv_on", "value": True}]
    t = 10**9
    for closest in walks:
        d = 8.0
        while d > closest:
            t += 20 * MS
            d = max(d - 0.02, closest)
            lines.append({"t_ns": t, "name": "distance", "value": round(d, 4)})
        for _ in range(150):
            t += 20 * MS
            d += 0.04
            lines.append({"t_ns": t, "name": "distance", "value": round(d, 4)})
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    return path


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """(config, trace, log): replay's log of a walk that stops at 3.2 m and one to 2 m."""
    d = tmp_path_factory.mktemp("report_margins")
    cfg = d / "c.yaml"
    cfg.write_text(CONFIG)
    trace = _trace(d / "t.jsonl", [3.2, 2.0])
    log = d / "log.jsonl"
    r = cli_main("replay", str(cfg), str(trace), "-o", str(log), "--quiet")
    assert r.returncode == 0, r.stderr
    return cfg, trace, log


def _timeline_data(html: str) -> dict[str, Any]:
    m = re.search(r"id='timeline-data'>(.*?)</script>", html)
    assert m
    return json.loads(m[1])


def _check_margins(html: str, log: Path) -> list[float]:
    """keep_away's margin line over the violations with a why-tree: distance - 3 at
    each one's tick (the formula without its H: the margin of now), the last shown
    one's last."""
    recs = list(iter_records(str(log)))
    shown = [r for r in recs if r["event"] == "violation" and r["requirement"] == "keep_away"]
    shown = shown[:SHOWN_PER_REQUIREMENT]
    data = _timeline_data(html)
    (line,) = [s for s in data["series"] if s["name"] == "margin keep_away"]
    assert not [s for s in data["series"] if s["name"] == "margin lamp_on"]  # never violated
    v = line["v"]
    assert all(isinstance(x, float) and math.isfinite(x) for x in v), v
    assert v[-1] == pytest.approx(shown[-1]["inputs"]["distance"] - 3.0)
    for r in shown:
        assert any(x == pytest.approx(r["inputs"]["distance"] - 3.0) for x in v), r["tick"]
    assert min(v) < 0 < max(v)
    return v


def test_report_draws_predictions_their_lead_and_margins_from_the_bag(
    made: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    cfg, trace, log = made
    recs = list(iter_records(str(log)))
    preds = [r for r in recs if r["event"] == "prediction"]
    expired = [r for r in recs if r["event"] == "prediction_expired"]
    # reset after_mitigation: a violation a tick after the predicted one, not predicted
    viol, *later = [
        r for r in recs if r["event"] == "violation" and r["requirement"] == "keep_away"
    ]
    assert len(preds) == 2 and len(expired) == 1 and viol["predicted_ms"] > 500  # the core's
    assert later and all("predicted_ms" not in x for x in later)
    out = tmp_path / "r.html"
    r = cli_main("report", str(log), "--bag", str(trace), "--config", str(cfg), "-o", str(out),
                 "--quiet")  # fmt: skip
    assert r.returncode == 0, r.stderr
    html = out.read_text()
    # a marker per prediction record in its own lane, the expired one told apart
    marks = re.findall(r'<line class="mk (prediction(?: expired)?)"[^>]*data-tick="(\d+)"', html)
    assert sorted(marks) == sorted(
        [("prediction", str(p["tick"])) for p in preds]
        + [("prediction expired", str(x["tick"])) for x in expired]
    )
    # the predicted violation's lead time, as the violation record gives it
    leads = re.findall(
        r'<rect class="lead" data-requirement="keep_away" data-lead-ms="([^"]+)"', html
    )
    assert [float(x) for x in leads] == [pytest.approx(viol["predicted_ms"], rel=1e-5)]
    assert f"predicted {viol['predicted_ms']:.6g} ms ahead" in html
    # and in the requirement's section: its predictions and the lead they gave
    assert (
        f"<td class='predictions'>2 made, 1 expired; 1 violation(s) predicted, lead min "
        f"{viol['predicted_ms']:.6g} ms, p50 {viol['predicted_ms']:.6g} ms</td>"
    ) in html
    # the margin replayed from the bag: from the reset before the violation to it
    v = _check_margins(html, log)
    assert len(v) > 50  # the whole window since the last reset, not the record's recent
    assert "margins-note" in html

    pw, page, console, requests = open_page(out.as_uri())
    try:
        assert page.locator("#timeline .mk.prediction").count() == len(preds) + len(expired)
        assert page.locator("#timeline .lead").count() == 1
        assert page.locator("#timeline path.line.margin").count() == 1
        assert page.locator("#timeline line.zero").count() == 1
        box = page.locator("#timeline").bounding_box()
        page.mouse.move(box["x"] + box["width"] * 0.7, box["y"] + box["height"] * 0.5)
        assert "margin keep_away = " in page.locator("#tip").inner_text()
        assert console == [], console
        assert requests == [out.as_uri()], requests
    finally:
        pw.stop()


def test_report_of_the_log_alone_draws_the_margins_of_the_recent_ticks(
    made: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    _cfg, _trace, log = made
    out = tmp_path / "r.html"
    r = cli_main("report", str(log), "-o", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    v = _check_margins(out.read_text(), log)
    # the union of the shown violations' recent ticks (logging.recent: 50 each)
    recs = list(iter_records(str(log)))
    ticks = [
        r["tick"] for r in recs if r["event"] == "violation" and r["requirement"] == "keep_away"
    ]
    covered = {t for tick in ticks[:SHOWN_PER_REQUIREMENT] for t in range(tick - 49, tick + 1)}
    assert len(v) == len(covered)


def test_a_forged_formula_is_a_note_not_a_margin(
    made: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    _cfg, _trace, log = made
    # the log is anybody's to write: a formula that does not parse, in a copy whose
    # chain is then broken (exit 1, the page says so), is no margin line but a note
    bad = tmp_path / "bad.jsonl"
    lines = []
    for line in log.read_text().splitlines():
        rec = json.loads(line)
        if rec["event"] == "violation" and rec["requirement"] == "keep_away":
            rec["formula"] = "(H ((distance >= "
        lines.append(json.dumps(rec))
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "r.html"
    r = cli_main("report", str(bad), "-o", str(out), "--quiet")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    html = out.read_text()
    assert "HASH CHAIN DOES NOT VERIFY" in html
    assert not [s for s in _timeline_data(html)["series"] if s["name"].startswith("margin ")]
    assert "no margins of keep_away: the interpreter cannot judge its window" in html
