"""``bench --predict`` (supervisor/tools/bench/predict.py): its scenarios' labels hold
(every approach breaks the requirement, no near miss or clean run does), its figures
come from replay's records, and the command prints them.  The figures themselves
are benchmarks (docs/BENCHMARKS.md), not asserted."""

from __future__ import annotations

import json

import pytest
from inproc import cli_main

from supervisor.tools.bench.predict import measure
from supervisor.tools.bench.predictgen import BASE_SPEEDS, SROBOT_SPEEDS, base_run, srobot_run

WALKS = {"approach": 3, "near_miss": 3, "clean": 2}


@pytest.fixture(scope="module")
def figures() -> dict:
    return measure(walks=WALKS)


@pytest.mark.parametrize(
    ("scenario", "speeds"), [("srobot", SROBOT_SPEEDS), ("mobile-base", BASE_SPEEDS)]
)
def test_every_approach_breaks_the_requirement_and_nothing_else_does(
    figures: dict, scenario: str, speeds: tuple[float, ...]
) -> None:
    (sc,) = [s for s in figures["scenarios"] if s["scenario"] == scenario]
    assert [r["speed"] for r in sc["rows"]] == list(speeds)
    for r in sc["rows"]:
        assert r["violations"] == WALKS["approach"], r  # one labelled violation a walk
        assert r["near_misses"] == WALKS["near_miss"]
        assert r["near_miss_violations"] == 0 and r["clean_violations"] == 0, r
        assert r["clean_hours"] > 0
    total = sc["all"]
    assert total["violations"] == WALKS["approach"] * len(speeds)
    assert total["false_predictions"] == sum(r["false_predictions"] for r in sc["rows"])


def test_the_generators_are_deterministic_and_ordered() -> None:
    for make in (lambda: srobot_run(3, 1.5, "approach", 2), lambda: base_run(3, 0.6, "clean", 1)):
        a, b = make(), make()
        assert a.events == b.events and a.walks == b.walks
        times = [t for t, _, _ in a.events]
        assert times == sorted(times)
        assert all(s < e for s, e in a.walks)


def test_a_fast_straight_approach_is_predicted_ahead(figures: dict) -> None:
    # The base drives at the wall at a constant speed: the line fits it exactly, so
    # each violation carries its lead time (the figures' own records, not a goal).
    (sc,) = [s for s in figures["scenarios"] if s["scenario"] == "mobile-base"]
    assert all(r["lead_p10_ms"] is not None and r["lead_p10_ms"] > 0 for r in sc["rows"])


@pytest.mark.slow
def test_bench_predict_prints_the_tables_and_the_goals(tmp_path) -> None:
    r = cli_main("bench", "--predict", "--quick", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "srobot" in r.stdout and "mobile-base" in r.stdout
    assert "goal: >= 90 % predicted >= 500 ms ahead" in r.stdout
    saved = json.loads((tmp_path / "predict.json").read_text())
    assert saved["ahead_ms"] == 500.0
    assert {s["scenario"] for s in saved["scenarios"]} == {"srobot", "mobile-base"}
