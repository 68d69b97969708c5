"""The prediction records (docs/reference/log.md, docs/reference/prediction.md) on a
real file: chained, verified, read back and shown by ``logs``, and checked by the
reader's schema like every other record."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from inproc import cli_main

from mitigations.violationlog.format import BadRecord, parse_record
from mitigations.violationlog.writer import ViolationLog

CFG = "c0" * 32


def _write(path: Path) -> None:
    with ViolationLog(path, "lamp", CFG, echo=False) as log:
        log.prediction(
            "keep_away",
            tick=176,
            margin=1.48,
            fitted=1.48,
            slope=-1.0,
            slope_se=0.0,
            ttv_ms=1480.0,
            ttv_lo_ms=1470.5,
            ttv_hi_ms=math.inf,
            confidence=0.97,
            samples=26,
            window_ms=500.0,
            horizon_ms=1500.0,
            min_confidence=0.9,
            actions=["slow"],
            cooldown="ok",
            inputs={"distance": 4.48, "uv_on": True},
        )
        log.mitigation("keep_away", action="slow", kind="log", ok=True, latency_ms=0.1)
        log.violation(
            "keep_away",
            text="lamp shall always satisfy uv_on -> distance >= 3.0",
            formula="H (uv_on -> distance >= 3.0)",
            tick=251,
            inputs={"distance": 2.98, "uv_on": True},
            policy_state={"predicted_tick": 176},
            predicted_ms=1500.0,
        )
        log.prediction_expired(
            "keep_away", tick=400, predicted_tick=300, horizon_ms=1500.0, after_ms=1500.001
        )


def test_prediction_records_chain_verify_and_read_back(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    _write(path)
    r = cli_main("logs", "--verify", str(path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.strip() == f"{path}: 4 records, chain intact"
    recs = [parse_record(line) for line in path.read_bytes().splitlines(keepends=True)]
    assert [x["event"] for x in recs] == [
        "prediction",
        "mitigation",
        "violation",
        "prediction_expired",
    ]
    assert recs[0]["ttv_hi_ms"] == "inf" and recs[0]["ttv_ms"] == 1480.0
    assert recs[2]["predicted_ms"] == 1500.0


def test_logs_shows_and_selects_prediction_records(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    _write(path)
    r = cli_main("logs", str(path), "--event", "prediction", "--event", "prediction_expired")
    assert r.returncode == 0, r.stderr
    head, *lines = r.stdout.strip().splitlines()
    assert head.split() == ["TIME", "EVENT", "REQUIREMENT", "DETAILS"]
    assert len(lines) == 2
    assert lines[0].split()[1:3] == ["prediction", "keep_away"]
    assert "tick=176 ttv_ms=1480.0 [1470.5, inf]" in lines[0]
    assert "confidence=0.97" in lines[0]
    assert lines[1].split()[1:3] == ["prediction_expired", "keep_away"]
    assert "predicted_tick=300 horizon_ms=1500.0" in lines[1]
    r = cli_main("logs", str(path), "--event", "violation")
    assert "tick=251 distance=2.98 uv_on=true predicted_ms=1500.0" in r.stdout


@pytest.mark.parametrize(
    ("field", "value", "error"),
    [
        ("ttv_ms", "soon", "ttv_ms must be a number, not str"),
        ("tick", -1, "tick must be a whole number from 0 to 2^63-1"),
        ("actions", "slow", "actions must be a list of strings"),
        ("inputs", {"d": "far"}, "inputs.'d' must be a Boolean or a number, not a string"),
    ],
)
def test_a_prediction_record_of_the_wrong_shape_is_refused(
    tmp_path: Path, field: str, value: object, error: str
) -> None:
    path = tmp_path / "v.log"
    _write(path)
    rec = json.loads(path.read_bytes().splitlines()[0])
    rec[field] = value
    with pytest.raises(BadRecord) as e:
        parse_record(json.dumps(rec).encode())
    assert str(e.value) == error


def test_a_prediction_record_needs_its_estimate(tmp_path: Path) -> None:
    path = tmp_path / "v.log"
    _write(path)
    rec = json.loads(path.read_bytes().splitlines()[0])
    del rec["slope"]
    with pytest.raises(BadRecord) as e:
        parse_record(json.dumps(rec).encode())
    assert str(e.value) == "slope is missing"
