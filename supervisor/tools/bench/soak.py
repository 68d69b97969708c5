"""A long run of the daemon under the stream (``bench``'s soak): does it leak?

The throughput experiment's run on the bench's config (sRobot by default) at
``--soak-rate`` for ``--soak-seconds``, the wait-set baseline beside it; from the
daemon's READY=1 until it is stopped, a thread samples its VmRSS and VmHWM
(/proc/PID/status) and its open file descriptors (the entries of /proc/PID/fd)
every few seconds. Reported: first, last and largest of each, the slope of RSS
over the second half of the publishing (least squares, kB per minute), the growth
of the descriptors, and the messages the daemon lost.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from supervisor.tools.bench.numbers import shown as _f
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.scale import fd_count, proc_memory
from supervisor.tools.bench.session import Session
from supervisor.tools.bench.throughput import daemon_summary, throughput


def sample_interval(seconds: float) -> float:
    """Every 5 s, more often in a short run (ten samples at least)."""
    return max(0.5, min(5.0, seconds / 10))


def slope_per_minute(points: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of (seconds, value) points, per minute; None under 2 points."""
    if len(points) < 2:
        return None
    n = len(points)
    mt = sum(t for t, _ in points) / n
    mv = sum(v for _, v in points) / n
    var = sum((t - mt) ** 2 for t, _ in points)
    if var == 0:
        return None
    cov = sum((t - mt) * (v - mv) for t, v in points)
    return 60.0 * cov / var


class Sampler:
    """RSS, HWM and descriptors of one pid every ``interval`` s on a thread."""

    def __init__(self, interval: float) -> None:
        self.interval = interval
        self.samples: list[dict[str, Any]] = []
        self.go: float | None = None  # monotonic time the publisher was told to go
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.pid = 0

    def sample(self) -> None:
        mem = proc_memory(self.pid)
        self.samples.append({"t": time.monotonic(), **mem, "fds": fd_count(self.pid)})

    def start(self, pid: int) -> None:
        self.pid = pid
        self.sample()

        def run() -> None:
            while not self._stop.wait(self.interval):
                self.sample()

        self._thread = threading.Thread(target=run, name="soak-sampler", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.sample()


def soak_bench(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    say: Callable[[str], None],
    *,
    wd_usec: int | None = None,
) -> dict[str, Any]:
    sampler = Sampler(sample_interval(seconds))

    def go(t: float) -> None:
        sampler.go = t

    say(
        f"soak: the daemon on {plan.path.name} at {rate:g} msg/s for {seconds:g} s, "
        f"RSS and fds every {sampler.interval:g} s"
    )
    try:
        row = throughput(
            s,
            plan,
            rate,
            seconds,
            False,
            wd_usec=wd_usec,
            on_ready=sampler.start,
            on_go=go,
            before_stop=sampler.stop,
        )
    finally:
        sampler._stop.set()
    go_t = sampler.go if sampler.go is not None else sampler.samples[0]["t"]
    samples = [
        {"t_s": x["t"] - go_t, **{k: x[k] for k in ("rss_kb", "hwm_kb", "fds")}}
        for x in sampler.samples
        if x["rss_kb"] is not None
    ]
    second_half = [
        (x["t_s"], float(x["rss_kb"])) for x in samples if seconds / 2 <= x["t_s"] <= seconds
    ]
    fds = [x["fds"] for x in samples if x["fds"] is not None]
    rss = [x["rss_kb"] for x in samples]
    hwm = [x["hwm_kb"] for x in samples if x["hwm_kb"] is not None]
    out = {
        "offered": rate,
        "seconds": row["seconds"],
        "config": str(plan.path),
        "interval_s": sampler.interval,
        "n_samples": len(samples),
        "samples": samples,
        "rss_first_kb": rss[0] if rss else None,
        "rss_last_kb": rss[-1] if rss else None,
        "rss_max_kb": max(rss) if rss else None,
        "hwm_last_kb": hwm[-1] if hwm else None,
        "rss_slope_kb_per_min_second_half": slope_per_minute(second_half),
        "second_half_samples": len(second_half),
        "fds_first": fds[0] if fds else None,
        "fds_last": fds[-1] if fds else None,
        "fds_max": max(fds) if fds else None,
        "fds_growth": fds[-1] - fds[0] if fds else None,
        **daemon_summary(row),
        "loss": row["daemon_loss"],
    }
    say(
        f"soak: RSS {out['rss_first_kb']} -> {out['rss_last_kb']} kB (max {out['rss_max_kb']}), "
        f"second half {_f(out['rss_slope_kb_per_min_second_half'])} kB/min; fds "
        f"{out['fds_first']} -> {out['fds_last']}; lost {out['lost']} of {out['sent']}"
    )
    return out
