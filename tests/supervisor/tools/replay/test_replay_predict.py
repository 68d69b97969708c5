"""``replay`` reports predictions beside violations (docs/reference/prediction.md):
the same core as the daemon, over a JSON-lines trace of a walk toward the lamp."""

from __future__ import annotations

import json
from pathlib import Path

from inproc import cli_main

from mitigations.violationlog.reader import iter_records

MS = 1_000_000

CONFIG = """\
component: lamp
step: {policy: periodic, period_ms: 20}
variables:
  distance: {type: double, topic: /distance, msg: std_msgs/msg/Float64}
  uv_on: {type: bool, topic: /uv, msg: std_msgs/msg/Bool}
requirements:
  - id: keep_away
    text: lamp shall always satisfy uv_on -> distance >= 3.0
    on_violation: [halt]
    policy: {reset: after_mitigation}
    predict: {horizon_ms: 1500, window_ms: 500, actions: [slow]}
  - id: lamp_known
    text: lamp shall always satisfy distance >= 0.0
mitigations:
  halt: {log: {message: halt}}
  slow: {log: {message: slow}}
"""


def _trace(path: Path, walks: list[tuple[float, float]]) -> Path:
    """Walks of (closest distance, seconds), each from 8 m at 1 m/s and then away."""
    lines = [{"t_ns": 10**9, "name": "uv_on", "value": True}]
    t = 10**9
    for closest, _ in walks:
        d = 8.0
        while d > closest:  # in
            t += 20 * MS
            d = max(d - 0.02, closest)
            lines.append({"t_ns": t, "name": "distance", "value": round(d, 4)})
        for _ in range(150):  # away at 2 m/s for 3 s
            t += 20 * MS
            d += 0.04
            lines.append({"t_ns": t, "name": "distance", "value": round(d, 4)})
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    return path


def test_replay_reports_predictions_beside_violations(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(CONFIG)
    # one walk stops at 3.2 m (a prediction that expires), one reaches 2 m (predicted)
    trace = _trace(tmp_path / "t.jsonl", [(3.2, 0.0), (2.0, 0.0)])
    out = tmp_path / "out.jsonl"
    r = cli_main("replay", str(cfg), str(trace), "-o", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    header = next(x for x in lines if x.startswith("requirement"))
    assert header.split() == [
        "requirement",
        "violations",
        "first",
        "tick",
        "first",
        "at",
        "(s)",
        "predictions",
        "expired",
        "predicted",
        "min",
        "lead",
        "(ms)",
    ]
    records = list(iter_records(str(out)))
    preds = [x for x in records if x["event"] == "prediction"]
    expired = [x for x in records if x["event"] == "prediction_expired"]
    violations = [x for x in records if x["event"] == "violation"]
    assert len(preds) == 2 and len(expired) == 1
    first = violations[0]
    assert first["predicted_ms"] >= 1000
    # the early action is recorded (dry run) after its prediction, before the violation
    early = [x for x in records if x["event"] == "mitigation" and x.get("stage") == "prediction"]
    assert [x["action"] for x in early] == ["slow", "slow"]
    assert records.index(preds[1]) < records.index(early[1]) < records.index(first)
    row = next(x for x in lines if x.startswith("keep_away")).split()
    assert row[0] == "keep_away" and row[1] == str(len(violations))
    assert row[4:7] == ["2", "1", "1"]
    assert float(row[7]) == first["predicted_ms"]
    other = next(x for x in lines if x.startswith("lamp_known")).split()
    assert other[4:] == ["0", "0", "0", "-"]

    j = cli_main("replay", str(cfg), str(trace), "--json", "--quiet")
    summary = json.loads(j.stdout)
    keep = summary["requirements"][0]
    assert summary["predicting"] is True
    assert (keep["predictions"], keep["expired"], keep["predicted"]) == (2, 1, 1)
    assert keep["min_lead_ms"] == first["predicted_ms"]
