"""``bench --predict``: how early and how falsely the predictions warn.

The scenarios of :mod:`~supervisor.tools.bench.predictgen` are replayed in this
process through ``replay``'s own core (the daemon's; no DDS is needed for what is
measured here).  Per scenario and walking speed:

- recall: the share of the labelled violations (the first violation record of each
  approach) whose record carries a lead time (``predicted_ms``) of at least
  ``ahead_ms``;
- the lead-time distribution over the same violations, p10 and p50 (a violation
  nobody predicted counts as 0 ms);
- false predictions per hour: ``prediction`` records of the clean runs (no
  approach), per hour of clean recording; beside them the near misses (an approach
  that stops short: nothing breaks) and how many of them were predicted, and the
  approach runs' predictions that expired.

Goals (docs/BENCHMARKS.md, "Prediction"), printed beside the sRobot figures, never
asserted: at least 90 % of the distance violations predicted at least 500 ms ahead,
at most 1 false prediction per hour on the clean runs.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mitigations.settings import PredictConfig
from supervisor.tools.bench.numbers import percentile, shown
from supervisor.tools.bench.predictgen import KINDS, SCENARIOS, Run, config_text, runs

GOAL_RECALL = 0.90  # of the sRobot's distance violations, predicted >= ahead_ms ahead
GOAL_FALSE_PER_HOUR = 1.0  # on the sRobot's clean runs
# Walks (approaches) per run of each kind and speed: 5 speeds x 200 clean walks of
# 10-30 s are about 1.5 h of clean sRobot recording.
WALKS: dict[str, dict[str, int]] = {
    "full": {"approach": 40, "near_miss": 40, "clean": 200},
    "quick": {"approach": 10, "near_miss": 10, "clean": 40},
}


def measure(
    *,
    seed: int = 1,
    walks: Mapping[str, int] | None = None,
    ahead_ms: float = 500.0,
    predict: Mapping[str, Any] | None = None,
    scenarios: tuple[str, ...] = SCENARIOS,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Every scenario's figures; ``predict`` overrides the requirement's ``predict:``
    settings (the defaults when empty: what the bench reports)."""
    from supervisor.tools.replay.session import replay_files

    walks = walks or WALKS["full"]
    settings = {**PredictConfig().__dict__, **(predict or {})}
    settings.pop("actions", None)
    out: dict[str, Any] = {"ahead_ms": ahead_ms, "predict": settings, "scenarios": []}
    with tempfile.TemporaryDirectory(prefix="safety-supervisor-bench-predict-") as tmp:
        d = Path(tmp)
        for scenario in scenarios:
            cfg = d / f"{scenario}.yaml"
            cfg.write_text(config_text(scenario, predict))
            rows: list[dict[str, Any]] = []
            for run in runs(scenario, seed, walks):
                if progress is not None:
                    progress(f"predict: {scenario} {run.kind} at {run.speed:g} m/s")
                trace = run.write(d / "trace.jsonl")
                log = d / "records.jsonl"
                log.unlink(missing_ok=True)
                result = replay_files(cfg, [trace], log, None)
                if result["error"]:
                    raise RuntimeError(f"bench --predict: replay failed: {result['error']}")
                rows.append(_judge(run, _records(log), ahead_ms))
            out["scenarios"].append(
                {
                    "scenario": scenario,
                    "rows": _merge(rows, ahead_ms),
                    "all": _total(rows, ahead_ms),
                }
            )
    return out


def _records(path: Path) -> list[dict[str, Any]]:
    from mitigations.violationlog.reader import iter_records

    return [r for r in iter_records(str(path)) if r["event"] != "supervisor"]


def _ns(recorded_ts: str) -> int:
    """replay's ``recorded_ts`` (the logical time, ns digits) as ns."""
    whole = datetime.fromisoformat(recorded_ts[:19]).replace(tzinfo=UTC)
    return int(whole.timestamp()) * 1_000_000_000 + int(recorded_ts[20:29])


def _judge(run: Run, records: list[dict[str, Any]], ahead_ms: float) -> dict[str, Any]:
    """One run's labelled violations, lead times and predictions."""
    violations = [(_ns(r["recorded_ts"]), r) for r in records if r["event"] == "violation"]
    predictions = [r for r in records if r["event"] == "prediction"]
    expired = [r for r in records if r["event"] == "prediction_expired"]
    leads: list[float] = []
    missed_walks = 0
    for start, end in run.walks:
        first = next((r for t, r in violations if start <= t < end), None)
        if first is None:
            missed_walks += 1  # an approach whose walk broke nothing (not labelled)
            continue
        leads.append(float(first.get("predicted_ms", 0.0)))
    return {
        "speed": run.speed,
        "kind": run.kind,
        "seconds": run.seconds,
        "walks": len(run.walks),
        "violating_walks": len(run.walks) - missed_walks,
        "leads": leads,
        "predictions": len(predictions),
        "expired": len(expired),
    }


def _merge(rows: list[dict[str, Any]], ahead_ms: float) -> list[dict[str, Any]]:
    """Per speed: the approach run's recall and leads beside the clean run's
    false predictions."""
    by_speed: dict[float, dict[str, Any]] = {}
    for r in rows:
        by_speed.setdefault(r["speed"], {"speed": r["speed"]})[r["kind"]] = r
    return [_figures(v, v["speed"], ahead_ms) for v in by_speed.values()]


def _total(rows: list[dict[str, Any]], ahead_ms: float) -> dict[str, Any]:
    def joined(kind: str) -> dict[str, Any]:
        part = [r for r in rows if r["kind"] == kind]
        return {
            "seconds": sum(r["seconds"] for r in part),
            "walks": sum(r["walks"] for r in part),
            "violating_walks": sum(r["violating_walks"] for r in part),
            "leads": [x for r in part for x in r["leads"]],
            "predictions": sum(r["predictions"] for r in part),
            "expired": sum(r["expired"] for r in part),
        }

    return _figures({k: joined(k) for k in KINDS}, None, ahead_ms)


def _figures(runs: Mapping[str, Any], speed: float | None, ahead_ms: float) -> dict[str, Any]:
    approach, near, clean = runs.get("approach"), runs.get("near_miss"), runs.get("clean")
    leads = approach["leads"] if approach else []
    hours = clean["seconds"] / 3600 if clean else 0.0
    return {
        "speed": speed,
        "violations": len(leads),
        "recall": None if not leads else sum(x >= ahead_ms for x in leads) / len(leads),
        "lead_p10_ms": percentile(leads, 10),
        "lead_p50_ms": percentile(leads, 50),
        "approach_expired": approach["expired"] if approach else 0,
        "clean_hours": hours,
        "clean_violations": len(clean["leads"]) if clean else 0,
        "near_misses": near["walks"] if near else 0,
        "near_misses_predicted": near["predictions"] if near else 0,
        "near_miss_violations": len(near["leads"]) if near else 0,
        "false_predictions": clean["predictions"] if clean else 0,
        "false_per_hour": (clean["predictions"] / hours) if clean and hours else None,
    }


def run_predict(args: Any, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """``bench --predict``'s figures for the command's options."""
    return measure(
        walks=WALKS["quick" if args.quick else "full"],
        ahead_ms=args.predict_ahead_ms,
        progress=progress,
    )


def format_predict(results: dict[str, Any]) -> str:
    """The tables ``bench --predict`` prints."""
    x = f"{results['ahead_ms']:g}"
    p = results["predict"]
    lines = [
        f"Prediction (predict: horizon_ms {p['horizon_ms']:g}, window_ms {p['window_ms']:g}, "
        f"min_confidence {p['min_confidence']:g}); recall: violations predicted >= {x} ms ahead",
    ]
    for sc in results["scenarios"]:
        lines += [
            "",
            f"{sc['scenario']}",
            f"{'speed m/s':>9}  {'violations':>10}  {'recall':>7}  {'lead p10':>8}  "
            f"{'lead p50':>8}  {'expired':>7}  {'near miss':>9}  {'warned':>6}  "
            f"{'clean h':>7}  {'false':>5}  {'false/h':>7}",
        ]
        for r in [*sc["rows"], sc["all"]]:
            speed = "all" if r["speed"] is None else f"{r['speed']:g}"
            recall = "-" if r["recall"] is None else f"{100 * r['recall']:.1f} %"
            lines.append(
                f"{speed:>9}  {r['violations']:>10}  {recall:>7}  "
                f"{shown(r['lead_p10_ms'], '.0f'):>8}  {shown(r['lead_p50_ms'], '.0f'):>8}  "
                f"{r['approach_expired']:>7}  {r['near_misses']:>9}  "
                f"{r['near_misses_predicted']:>6}  {r['clean_hours']:>7.2f}  "
                f"{r['false_predictions']:>5}  {shown(r['false_per_hour'], '.2f'):>7}"
            )
        if sc["scenario"] == "srobot":
            a = sc["all"]
            met_r = a["recall"] is not None and a["recall"] >= GOAL_RECALL
            met_f = a["false_per_hour"] is not None and a["false_per_hour"] <= GOAL_FALSE_PER_HOUR
            lines.append(
                f"goal: >= {100 * GOAL_RECALL:.0f} % predicted >= {x} ms ahead "
                f"({'met' if met_r else 'NOT met'}); <= {GOAL_FALSE_PER_HOUR:g} false "
                f"prediction per hour on clean runs ({'met' if met_f else 'NOT met'})"
            )
    return "\n".join(lines)
