"""The recording overhead: the throughput experiment's daemon at one offered rate,
once without and once with ``run --record DIR``; what it received and lost, its CPU
per message, and the recording's own counts (its ``record_closed`` record). The goal,
printed and not asserted: recording costs at most ``GOAL_PCT`` % more CPU per message
(docs/reference/commands.md#bench)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.session import Session
from supervisor.tools.bench.throughput import throughput

GOAL_PCT = 10.0
RATES = (20_000.0,)


def _side(row: dict[str, Any]) -> dict[str, Any]:
    d = row["receivers"]["daemon"]
    return {
        "sent": row["sent"],
        "achieved": row["achieved"],
        "received": d["received"],
        "lost": row["sent"] - d["received"],
        "counted_lost": row["daemon_counted_lost"],
        "cpu_s": d["cpu_s"],
        "cpu_us_per_msg": d["cpu_us_per_msg"],
        "cpu_us_per_msg_to_exit": d["cpu_us_per_msg_to_exit"],
        "record": row["record"],
        "drained": row["drained"],
    }


def _pct(new: float | None, old: float | None) -> float | None:
    return None if new is None or not old else 100.0 * (new - old) / old


def recording_overhead(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    say: Callable[[str], None],
    *,
    wd_usec: int | None = None,
) -> dict[str, Any]:
    """Both runs at ``rate`` msg/s for ``seconds``, without recording first."""
    runs = {}
    for label, record in (("off", False), ("on", True)):
        say(f"recording {label}: throughput at {rate:g} msg/s for {seconds:g} s")
        runs[label] = _side(
            throughput(s, plan, rate, seconds, False, wd_usec=wd_usec, record=record)
        )
    off, on = runs["off"], runs["on"]
    return {
        "offered": rate,
        "seconds": seconds,
        "off": off,
        "on": on,
        "cpu_diff_pct": _pct(on["cpu_us_per_msg"], off["cpu_us_per_msg"]),
        "cpu_diff_pct_to_exit": _pct(on["cpu_us_per_msg_to_exit"], off["cpu_us_per_msg_to_exit"]),
        "goal_pct": GOAL_PCT,
    }
