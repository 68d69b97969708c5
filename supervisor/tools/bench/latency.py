"""The latency experiment: violating trigger published -> halt received, against a
bare rclpy echo and against the daemon, and where the daemon's time goes."""

from __future__ import annotations

import calendar
import json
import os
import statistics
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from supervisor.tools.bench.breakdown import breakdown
from supervisor.tools.bench.numbers import percentiles
from supervisor.tools.bench.plan import (
    LATENCY_REQUIREMENT,
    SROBOT_NOMINAL_CHECK,
    SROBOT_VIOLATING,
    Plan,
)
from supervisor.tools.bench.session import Session

# (result key, logging.durability) of the daemon's latency runs
DURABILITY_RUNS = (("daemon", "after_publish"), ("daemon_before_action", "before_action"))
THESIS_MEAN_MS = 33.0  # thesis: OGMA/Copilot node, violation -> halt, average
TESSLA_MEAN_MS = 15.0  # thesis: TeSSLa-ROS-Bridge, average


def latency(
    s: Session, plan: Plan, trials: int, say: Callable[[str], None], rounds: int = 3
) -> dict[str, Any]:
    """The echo and the daemon under each durability, ``trials`` trials each, taken
    in ``rounds`` rounds of echo then daemons: the machine drifts between runs (the
    echo's own p50 moved twofold between runs minutes apart: docs/BENCHMARKS.md), so
    each figure pools the rounds and every round's ratio is kept too."""
    work = s.tmp / "latency"
    work.mkdir()
    spec = json.dumps(plan.topics)
    halt_topic, halt_msg = plan.halt
    warmup = 10
    common = ["--spec", spec, "--trigger", plan.trigger, "--halt-topic", halt_topic]
    common += ["--halt-msg", halt_msg]
    rounds = max(1, min(rounds, trials))
    out: dict[str, Any] = {"trials": trials, "warmup": warmup, "rounds": []}
    echo_runs: list[dict[str, Any]] = []
    daemon_runs: dict[str, list[tuple[list[dict[str, Any]], dict[str, Any]]]] = {
        key: [] for key, _ in DURABILITY_RUNS
    }
    for r in range(rounds):
        n = trials // rounds + (r < trials % rounds)
        tag = f" (round {r + 1} of {rounds})" if rounds > 1 else ""
        driver_args = [
            *common,
            "--nominal",
            json.dumps(plan.nominal),  # halt false: each trial starts from a holding state
            "--violating",
            json.dumps(SROBOT_VIOLATING),
            "--trials",
            str(n),
            "--warmup",
            str(warmup),
        ]
        budget = 120 + n * 0.2
        say(f"latency: bare rclpy echo, {n} trials{tag}")
        ework = work / f"echo-{r}"
        echo = s.child(
            "echo",
            "echo",
            *common,
            "--when",
            f"classifier={SROBOT_VIOLATING['classifier']}",
            workdir=ework,
        )
        driver = s.child("driver", "driver", *driver_args, workdir=ework)
        try:
            echo.wait_event("started", 60, (echo, driver))
            result = driver.wait_event("result", budget, (echo, driver))
        finally:
            driver.kill()
            echo.kill()
        echo_runs.append(result)
        # Both orders of logging.durability, side by side
        # (docs/reference/log.md#durability): "daemon" is the default, after_publish.
        this_round = {"echo_p50": _p50(result)}
        for key, durability in DURABILITY_RUNS:
            say(f"latency: daemon, durability {durability}, {n} trials{tag}")
            dwork = work / f"{key}-{r}"
            dwork.mkdir()
            config = plan.write_config(
                dwork / "config.yaml", dwork / "violations.jsonl", latency=True,
                durability=durability,
            )  # fmt: skip
            daemon = s.daemon(config, dwork)
            try:
                daemon.wait_ready(60)
                log_args = ["--log", str(daemon.log), "--requirement", LATENCY_REQUIREMENT]
                driver = s.child("driver", "driver", *driver_args, *log_args, workdir=dwork)
                try:
                    result = driver.wait_event("result", budget, (daemon, driver))
                finally:
                    driver.kill()
                daemon.stop_cleanly()
                records = daemon.records()
            finally:
                daemon.kill()
            daemon_runs[key].append((records, result))
            this_round[f"{key}_p50"] = _p50(result)
        out["rounds"].append(this_round)
    out["echo"] = _latency_stats(_pooled(echo_runs))
    for key, durability in DURABILITY_RUNS:
        runs = daemon_runs[key]
        out[key] = _latency_stats(_pooled([result for _, result in runs]))
        out[key].update(_daemon_internals(runs, warmup))
        out[key]["durability"] = durability
    out["fsync"] = _fsync_times(s.tmp, out["daemon"].get("violation_record_bytes") or 2048)
    say(f"latency: the daemon's stages in one process, {trials} violations")
    out["breakdown"] = breakdown(plan, work / "breakdown", trials)
    # the same after 20 ms of idling before each violation, as in the daemon between trials
    out["breakdown_idle"] = breakdown(plan, work / "breakdown-idle", min(trials, 300), 20.0)
    say(f"latency: the daemon's stages, durability after_publish, {trials} violations")
    out["breakdown_after_publish"] = breakdown(
        plan, work / "breakdown-after-publish", trials, durability="after_publish"
    )
    out["thesis_mean_ms"] = THESIS_MEAN_MS
    out["tessla_mean_ms"] = TESSLA_MEAN_MS
    return out


def _p50(result: dict[str, Any]) -> float | None:
    ns = result["latencies_ns"]
    return statistics.median(ns) / 1e6 if ns else None


def _pooled(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The drivers' results of several rounds as one."""
    return {
        "latencies_ns": [x for r in results for x in r["latencies_ns"]],
        "published_wall_ns": [x for r in results for x in r.get("published_wall_ns") or []],
        "missed": sum(r["missed"] for r in results),
        "strays": sum(r["strays"] for r in results),
        "sync_timeouts": sum(r.get("sync_timeouts", 0) for r in results),
    }


def _latency_stats(result: dict[str, Any]) -> dict[str, Any]:
    ms = [ns / 1e6 for ns in result["latencies_ns"]]
    return {
        "n": len(ms),
        "missed": result["missed"],
        "stray_halts": result["strays"],
        "sync_timeouts": result.get("sync_timeouts", 0),
        **percentiles(ms),
    }


def _daemon_internals(
    runs: list[tuple[list[dict[str, Any]], dict[str, Any]]], warmup: int
) -> dict[str, Any]:
    """From the daemon's logs of each round (its records and the driver's result):
    detection -> halt published (the mitigation record's latency_ms, fsync of the
    violation record included), and trigger published -> violation record rendered
    (wall clocks of one machine)."""
    parts = [_run_internals(records, warmup, result) for records, result in runs]
    return {
        "violation_records": sum(p["violation_records"] for p in parts),
        "trigger_to_record_ms": percentiles([x for p in parts for x in p["to_record"]]),
        "other_violations": sum(p["other_violations"] for p in parts),
        "not_from_holding_state": sum(p["not_holding"] for p in parts),
        "detect_to_publish_ms": percentiles([x for p in parts for x in p["internal"]]),
        "violation_record_bytes": (
            int(statistics.median(sizes))
            if (sizes := [x for p in parts for x in p["sizes"]])
            else None
        ),
    }


def _run_internals(
    records: list[dict[str, Any]], warmup: int, result: dict[str, Any]
) -> dict[str, Any]:
    """:func:`_daemon_internals`' samples of one daemon run."""
    violations = [r for r in records if r.get("event") == "violation"]
    mitigations = [
        r
        for r in records
        if r.get("event") == "mitigation"
        and r.get("requirement") == LATENCY_REQUIREMENT
        and r.get("stage") == "violation"
    ]
    internal = [float(r["latency_ms"]) for r in mitigations[warmup:]]
    sizes = [len(r["_line"].encode()) + 1 for r in violations]  # bytes written, newline too
    mine = [r for r in violations if r.get("requirement") == LATENCY_REQUIREMENT]
    # A trial starts from a holding state when the tick before its violation
    # was the nominal state the driver published (classifier 0, halt false).
    not_holding = 0
    for r in mine[warmup:]:
        recent = r.get("recent") or []
        before = recent[-2] if len(recent) >= 2 else {}
        if any(before.get(k) != v for k, v in SROBOT_NOMINAL_CHECK.items()):
            not_holding += 1
    # Each trial's record: the first after its trigger went out (strays aside).
    to_record: list[float] = []
    stamps = [_epoch_ns(r["ts"]) for r in mine]
    j = 0
    for wall in result.get("published_wall_ns") or []:
        while j < len(stamps) and stamps[j] < wall:
            j += 1
        if j < len(stamps):
            to_record.append((stamps[j] - wall) / 1e6)
            j += 1
    return {
        "violation_records": len(violations),
        "to_record": to_record,
        "other_violations": len(violations) - len(mine),
        "not_holding": not_holding,
        "internal": internal,
        "sizes": sizes,
    }


def _epoch_ns(ts: str) -> int:
    """The log's ``ts`` (ISO 8601 UTC, microseconds) as ns since the epoch."""
    dt = datetime.strptime(ts, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC)
    return (calendar.timegm(dt.timetuple()) * 1_000_000 + dt.microsecond) * 1000


def _fsync_times(where: Path, size: int, n: int = 200) -> dict[str, Any]:
    """write + fsync of a violation-record-sized append, on the log's file system."""
    path = where / "fsync-probe.jsonl"
    line = b"x" * (size - 1) + b"\n"
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o640)
    times = []
    try:
        for _ in range(n):
            t = time.perf_counter_ns()
            os.write(fd, line)
            os.fsync(fd)
            times.append((time.perf_counter_ns() - t) / 1e6)
    finally:
        os.close(fd)
        path.unlink()
    return {"bytes": size, "n": n, **percentiles(times)}
