"""The bench's figures: percentiles of samples, and a number as the reports print it."""

from __future__ import annotations

import math
import statistics


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50, p90, p99 (nearest rank), max and mean of ``values`` (all None if empty)."""
    if not values:
        return {k: None for k in ("p50", "p90", "p99", "max", "mean")}
    v = sorted(values)

    def pct(p: int) -> float:
        # nearest rank: the smallest value with at least p % of the samples at or below it
        return v[max(0, min(len(v) - 1, -(-len(v) * p // 100) - 1))]

    return {
        "p50": pct(50),
        "p90": pct(90),
        "p99": pct(99),
        "max": v[-1],
        "mean": statistics.fmean(v),
    }


def percentile(values: list[float], p: float) -> float | None:
    """The ``p``-th percentile of ``values`` by nearest rank (None if empty), as
    :func:`percentiles` ranks them: for the figures it does not list (p10)."""
    if not values:
        return None
    v = sorted(values)
    return v[max(0, min(len(v) - 1, math.ceil(len(v) * p / 100) - 1))]


def shown(x: float | None, fmt: str = ".1f") -> str:
    """``x`` formatted, or '-' when there is no figure."""
    return "-" if x is None else format(x, fmt)
