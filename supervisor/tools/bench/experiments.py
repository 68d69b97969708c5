"""The bench's run: the config's plan, the chosen experiments in one session, and
the machine they ran on."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.latency import latency
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.recording import recording_overhead
from supervisor.tools.bench.replay import replay_bench
from supervisor.tools.bench.scale import scale_bench
from supervisor.tools.bench.scan import scan_bench
from supervisor.tools.bench.session import Session, session
from supervisor.tools.bench.soak import soak_bench
from supervisor.tools.bench.throughput import throughput
from supervisor.tools.bench.ui import ui_load


def run(args: argparse.Namespace, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    say = progress or (lambda _text: None)
    config = Path(args.config)
    plan = Plan(config)
    if not args.skip_latency:
        problem = plan.latency_problem()
        if problem:
            raise BenchError(f"{config}: {problem} (use --skip-latency)")
    results: dict[str, Any] = {
        "config": str(config),
        "topics": [t["topic"] for t in plan.topics],
        "trigger": plan.trigger,
        "cpus": os.cpu_count(),
        "loadavg_before": _loadavg(),
        "python": sys.version.split()[0],
        "rmw": os.environ.get("RMW_IMPLEMENTATION") or "default (rmw_fastrtps_cpp)",
    }
    with session(args.domain_id) as s:
        results["domain_id"] = s.domain_id
        if not args.skip_throughput:
            results["throughput"] = _throughput_rows(s, plan, args, say)
        if not args.skip_record:
            results["recording"] = [
                recording_overhead(s, plan, rate, args.seconds, say, wd_usec=args.watchdog_usec)
                for rate in args.record_rates
            ]
        if not args.skip_ui:
            results["ui"] = [
                ui_load(
                    s,
                    plan,
                    rate,
                    args.ui_seconds,
                    say,
                    clients=args.ui_clients,
                    wd_usec=args.watchdog_usec,
                    chromium=args.ui_chromium,
                )
                for rate in args.ui_rates
            ]
        if args.scan:
            results["scan"] = scan_bench(
                s,
                plan,
                args.scan_rate,
                args.seconds,
                args.scan_reductions,
                say,
                wd_usec=args.watchdog_usec,
            )
        if not args.skip_scale:
            results["scale"] = scale_bench(
                s,
                plan,
                args.scale_sizes,
                args.scale_rate,
                args.seconds,
                say,
                wd_usec=args.watchdog_usec,
            )
        if not args.skip_soak:
            results["soak"] = soak_bench(
                s, plan, args.soak_rate, args.soak_seconds, say, wd_usec=args.watchdog_usec
            )
        if not args.skip_latency:
            results["latency"] = latency(
                s, plan, args.latency_trials, say, rounds=args.latency_rounds
            )
        if not args.skip_replay:
            # In this process: no ROS, only the session's temp dir.
            min_s = 0.2 if args.quick else 1.0
            results["replay"] = replay_bench(
                plan, args.replay_messages, say, where=s.tmp, min_seconds=min_s
            )
    results["loadavg_after"] = _loadavg()
    return results


def _throughput_rows(
    s: Session, plan: Plan, args: argparse.Namespace, say: Callable[[str], None]
) -> list[dict[str, Any]]:
    """One throughput run per rate, evenly paced and then in each burst size."""
    rows = []
    for burst in (0, *args.burst):
        for rate in args.rates:
            how = f" in bursts of {burst} rounds" if burst else ""
            say(f"throughput at {rate:g} msg/s{how} for {args.seconds:g} s")
            rows.append(
                throughput(
                    s, plan, rate, args.seconds, args.naive, burst=burst, wd_usec=args.watchdog_usec
                )
            )
    return rows


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"
