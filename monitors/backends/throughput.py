"""How many ticks per second a loaded monitor steps: one ``tick()`` call per tick
against ``tick_batch`` (one C call per batch, what ``replay`` uses), and the cost
of ``pack_columns``.  For ``safety-supervisor bench``; prints nothing, asserts
nothing.  The inputs are random (seeded) values of each input's type, packed
before the clock starts; the monitor's state carries over between repetitions.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monitors.backends.load import LoadedMonitor, compile_spec
from monitors.ir.spec import MonitorSpec

if TYPE_CHECKING:
    import numpy as np


def random_columns(spec: MonitorSpec, n: int, seed: int = 0) -> list[np.ndarray]:
    """``n`` values per input (``spec.inputs`` order): bools half true, small
    integers and reals, so that comparisons with config constants go both ways."""
    import numpy as np

    rng = np.random.default_rng(seed)
    columns: list[np.ndarray] = []
    for v in spec.inputs:
        if v.type == "bool":
            columns.append(rng.random(n) < 0.5)
        elif v.type == "int64":
            columns.append(rng.integers(-2, 11, n, dtype=np.int64))
        else:
            columns.append(rng.uniform(-2.0, 11.0, n))
    return columns


def _rate(step: Callable[[], Any], ticks_per_call: int, min_seconds: float) -> float:
    """Ticks per second of ``step`` repeated for at least ``min_seconds``."""
    step()  # warm up: page faults, first-call costs
    calls, start = 0, time.perf_counter()
    while True:
        step()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * ticks_per_call / elapsed


def tick_rate(mon: LoadedMonitor, *, ticks: int = 100_000, min_seconds: float = 1.0) -> float:
    """Ticks/s of ``mon.tick(values)``, one Python call per tick (the daemon's path)."""
    columns = [c.tolist() for c in random_columns(mon.spec, ticks)]
    rows = [list(r) for r in zip(*columns, strict=True)]

    def run() -> None:
        tick = mon.tick
        for values in rows:
            tick(values)

    return _rate(run, len(rows), min_seconds)


def batch_rate(mon: LoadedMonitor, batch_size: int, *, min_seconds: float = 1.0) -> float:
    """Ticks/s of ``mon.tick_batch`` on batches of ``batch_size`` packed rows."""
    rows = mon.pack_columns(random_columns(mon.spec, batch_size))
    return _rate(lambda: mon.tick_batch(rows), batch_size, min_seconds)


def pack_rate(mon: LoadedMonitor, batch_size: int, *, min_seconds: float = 1.0) -> float:
    """Rows/s of ``mon.pack_columns`` (numpy columns to packed rows)."""
    columns: Sequence[Any] = random_columns(mon.spec, batch_size)
    return _rate(lambda: mon.pack_columns(columns), batch_size, min_seconds)


def spec_rates(
    spec: MonitorSpec,
    batch_sizes: Sequence[int] = (10_000, 100_000),
    *,
    out_dir: Path | None = None,
    min_seconds: float = 1.0,
) -> dict[str, float]:
    """Build ``spec`` (native backend) and measure it: ``{"tick": ticks/s,
    "batch <n>": ticks/s, "pack <n>": rows/s}`` for each batch size."""
    with tempfile.TemporaryDirectory(prefix="ss-throughput-") as tmp:
        mon = compile_spec(spec, Path(out_dir or tmp))
        rates = {"tick": tick_rate(mon, min_seconds=min_seconds)}
        for n in batch_sizes:
            rates[f"batch {n}"] = batch_rate(mon, n, min_seconds=min_seconds)
            rates[f"pack {n}"] = pack_rate(mon, n, min_seconds=min_seconds)
    return rates
