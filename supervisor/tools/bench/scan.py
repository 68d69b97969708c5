"""A LaserScan beside the sRobot stream (``bench --scan``): what a 1,440-reading scan
at 40 Hz costs the daemon when its config reduces the ranges (``reduce: min``, REP 117)
and ages the stamp (``age_of``), with one requirement on both.

1. The daemon: the throughput experiment's run at one offered rate, once on the config
   as it is and once with the scan (:class:`~supervisor.tools.bench.plan.ScanPlan`: the
   same publisher sends the scan between the stream's slots, the daemon's config has
   ``obstacle``, ``scan_age_ms`` and the requirement more; the wait-set baseline takes
   the scan too). CPU per message counts every message the daemon took, scans included;
   ``cpu_us_per_scan_added`` is the run's CPU with the scan less what its stream
   messages cost at the run without it, per scan taken (one run each: noisy).
2. The reduction, in this process: the reader :func:`supervisor.inputs.readers.make_reader`
   makes of the config's ``obstacle`` called on a scan, ``perf_counter_ns`` around each
   call, on the message built by rclpy (as the publisher builds it) and on copies
   deserialised from its CDR (``deserialize_message``: what the daemon's
   ``take_message`` hands it); also that deserialisation and the age reader.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.numbers import percentiles
from supervisor.tools.bench.numbers import shown as _f
from supervisor.tools.bench.plan import SCAN_CLOSEST, Plan, ScanPlan
from supervisor.tools.bench.publisher import scan_message
from supervisor.tools.bench.session import Session
from supervisor.tools.bench.throughput import daemon_summary, throughput

COPIES = 64  # deserialised scans the reader cycles through (a fresh message each time)
WARMUP = 200


def _side(row: dict[str, Any], scan: str | None) -> dict[str, Any]:
    d = row["receivers"]["daemon"]
    ws = row["receivers"].get("rclpy wait-set")
    scans_sent = row["sent_per_topic"].get(scan, 0) if scan else 0
    scans_taken = int(d["received_per_topic"].get(scan, 0)) if scan else 0
    stream = d["received"] - scans_taken
    return {
        **daemon_summary(row),
        "loss_agree": row["daemon_loss"]["agree"],
        "loss": row["daemon_loss"],  # per topic: gaps, before the first, after the last
        "cpu_s": d["cpu_s"],
        "cpu_us_per_msg_to_exit": d["cpu_us_per_msg_to_exit"],
        "stream_received": stream,
        "scans_sent": scans_sent,
        "scans_received": scans_taken,
        "waitset": None
        if ws is None
        else {k: ws[k] for k in ("received", "loss_pct", "cpu_s", "cpu_us_per_msg")},
    }


def _pct(new: float | None, old: float | None) -> float | None:
    return None if new is None or not old else 100.0 * (new - old) / old


def _timed(fn: Callable[[Any], Any], args: list[Any], n: int) -> tuple[dict[str, Any], Any]:
    """``fn`` called ``n`` times on ``args`` in turn (after a warm-up): microseconds per
    call (p50, p90, p99, max, mean) and the last result."""
    perf = time.perf_counter_ns
    k = len(args)
    for i in range(WARMUP):
        fn(args[i % k])
    times = [0] * n
    out = None
    for i in range(n):
        a = args[i % k]
        t0 = perf()
        out = fn(a)
        times[i] = perf() - t0
    st = percentiles([t / 1000 for t in times])
    return {"n": n, **st}, out


def reduction_cost(plan: ScanPlan, where: Path, n: int) -> dict[str, Any]:
    """The readers the daemon makes of the scan plan's config, timed on ``n`` scans."""
    from rclpy.serialization import deserialize_message, serialize_message

    from monitors.errors import UserError
    from supervisor.config import load_config
    from supervisor.inputs.readers import make_reader

    work = Path(tempfile.mkdtemp(prefix="scan-readers-", dir=where))
    config = plan.write_config(work / "config.yaml", work / "violations.jsonl", latency=False)
    try:
        cfg = load_config(config)
    except UserError as e:
        raise BenchError(f"the scan's config: {e}") from None
    assert plan.scan is not None
    reduce = make_reader(cfg.variables["obstacle"])
    age = make_reader(cfg.variables["scan_age_ms"])
    built = scan_message(plan.scan)
    ns = time.time_ns()
    built.header.stamp.sec, built.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    klass = type(built)
    cdr = serialize_message(built)
    copies = [deserialize_message(cdr, klass) for _ in range(COPIES)]
    built_st, v_built = _timed(reduce, [built], n)
    des_st, v_des = _timed(reduce, copies, n)
    deser_st, _ = _timed(lambda b: deserialize_message(b, klass), [cdr], n)
    age_st, stamp = _timed(age, copies, n)
    for label, v in (("built", v_built), ("deserialised", v_des)):
        # float32 readings: SCAN_CLOSEST is exact in float32 (1.25)
        if not (isinstance(v, float) and math.isclose(v, SCAN_CLOSEST, rel_tol=1e-6)):
            raise BenchError(f"reduce: min of the {label} scan gave {v!r}, not {SCAN_CLOSEST}")
    if stamp != ns:
        raise BenchError(f"the age reader read stamp {stamp!r}, not {ns}")
    return {
        "scans": n,
        "readings": len(built.ranges),
        "cdr_bytes": len(cdr),
        "obstacle": v_built,
        "reduce_built_us": built_st,
        "reduce_deserialised_us": des_st,
        "deserialise_us": deser_st,
        "age_reader_us": age_st,
    }


def scan_bench(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    reductions: int,
    say: Callable[[str], None],
    *,
    wd_usec: int | None = None,
) -> dict[str, Any]:
    """The reduction timed in this process, then the daemon at ``rate`` msg/s for
    ``seconds`` without and with the scan."""
    scan_plan = ScanPlan(plan.path)
    assert scan_plan.scan is not None
    spec = scan_plan.scan
    say(f"scan: reduce: min over {spec['readings']} readings, {reductions} times in this process")
    cost = reduction_cost(scan_plan, s.tmp, reductions)
    runs = {}
    for label, p in (("off", plan), ("on", scan_plan)):
        with_scan = f" with a {spec['readings']}-reading LaserScan at {spec['hz']:g} Hz"
        say(f"scan {label}: throughput at {rate:g} msg/s{with_scan if p.scan else ''}")
        row = throughput(s, p, rate, seconds, False, wd_usec=wd_usec)
        runs[label] = _side(row, spec["name"] if p.scan else None)
    off, on = runs["off"], runs["on"]
    added = None
    if on["scans_received"] and off["cpu_us_per_msg"] is not None:
        stream_cpu = off["cpu_us_per_msg"] * on["stream_received"] / 1e6
        added = 1e6 * (on["cpu_s"] - stream_cpu) / on["scans_received"]
    out = {
        "offered": rate,
        "seconds": seconds,
        "topic": spec["topic"],
        "hz": spec["hz"],
        "readings": spec["readings"],
        "off": off,
        "on": on,
        "cpu_diff_pct": _pct(on["cpu_us_per_msg"], off["cpu_us_per_msg"]),
        "loss_pct_diff": on["loss_pct"] - off["loss_pct"],
        "cpu_us_per_scan_added": added,
        "reduction": cost,
    }
    r = cost
    say(
        f"scan at {rate:g} msg/s: daemon CPU {_f(off['cpu_us_per_msg'])} us/msg without, "
        f"{_f(on['cpu_us_per_msg'])} with ({_f(out['cpu_diff_pct'], '+.1f')} %), lost "
        f"{off['lost']} / {on['lost']}; reduce: min p50 {r['reduce_built_us']['p50']:.1f} us "
        f"(rclpy-built), {r['reduce_deserialised_us']['p50']:.1f} us (deserialised)"
    )
    return out
