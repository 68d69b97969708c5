"""The recording overhead: the throughput experiment's daemon at one offered rate,
once without and once with ``run --record DIR``; what it received and lost, its CPU
per message, and the recording's own counts (its ``record_closed`` record). The goal,
printed and not asserted: recording costs the daemon at most ``GOAL_PCT`` % more CPU
per message (docs/reference/commands.md#bench).

The bags are written by a child of the daemon (docs/reference/config.md, record),
whose CPU is not the daemon's: it is sampled from /proc here (its pid is in the
daemon's ``record`` record) and printed next to the daemon's, from the publisher's
``matched`` (when the daemon's CPU window begins) to the writer's exit (its last
sample, every ``SAMPLE_S``: its last few milliseconds may be missed)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.session import Daemon, Helper, Session, cpu_seconds
from supervisor.tools.bench.throughput import throughput

GOAL_PCT = 10.0
SAMPLE_S = 0.01


class WriterSampler:
    """The CPU seconds of the recording's writer process over time, sampled from /proc
    on a thread while the throughput run (started after this) goes on."""

    def __init__(self, s: Session) -> None:
        self._s = s
        self._known = len(s.children)
        self._done = threading.Event()
        self.pid: int | None = None
        self.samples: list[tuple[float, float]] = []  # (monotonic time, CPU seconds)
        self._thread = threading.Thread(target=self._run, name="writer-cpu", daemon=True)
        self._thread.start()

    def _daemon(self) -> Daemon | None:
        new = self._s.children[self._known :]
        return next((c for c in new if isinstance(c, Daemon)), None)

    def _run(self) -> None:
        while not self._done.is_set() and self.pid is None:
            d = self._daemon()
            if d is not None and d.log.exists():
                for r in d.records():
                    if r.get("what") == "record" and r.get("writer_pid"):
                        self.pid = int(r["writer_pid"])
            self._done.wait(SAMPLE_S)
        while self.pid is not None and not self._done.is_set():
            cpu = cpu_seconds(self.pid)
            if math.isnan(cpu):
                return  # exited and reaped by the daemon
            self.samples.append((time.monotonic(), cpu))
            self._done.wait(SAMPLE_S)

    def result(self, received: int) -> dict[str, Any]:
        self._thread.join(30)  # the writer exits before the daemon
        self._done.set()
        new = self._s.children[self._known :]
        pub = next((c for c in new if isinstance(c, Helper) and c.name == "publisher"), None)
        matched = pub.latest("matched") if pub is not None else None
        out: dict[str, Any] = {"pid": self.pid, "cpu_s_total": None, "cpu_s_to_exit": None}
        out["cpu_us_per_msg_to_exit"] = None
        if not self.samples:
            return out
        out["cpu_s_total"] = self.samples[-1][1]  # its start (importing rosbags) too
        if matched is not None:
            before = [cpu for t, cpu in self.samples if t <= matched[0]] or [self.samples[0][1]]
            out["cpu_s_to_exit"] = self.samples[-1][1] - before[-1]
            if received:
                out["cpu_us_per_msg_to_exit"] = 1e6 * out["cpu_s_to_exit"] / received
        return out


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


def _us(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None else format(x, fmt)


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
    writer: dict[str, Any] = {}
    for label, record in (("off", False), ("on", True)):
        say(f"recording {label}: throughput at {rate:g} msg/s for {seconds:g} s")
        sampler = WriterSampler(s) if record else None
        runs[label] = _side(
            throughput(s, plan, rate, seconds, False, wd_usec=wd_usec, record=record)
        )
        if sampler is not None:
            writer = sampler.result(runs[label]["received"])
    off, on = runs["off"], runs["on"]
    on["writer"] = writer
    diff = _pct(on["cpu_us_per_msg"], off["cpu_us_per_msg"])
    say(
        f"recording at {rate:g} msg/s: daemon CPU {_us(off['cpu_us_per_msg'])} us/msg off, "
        f"{_us(on['cpu_us_per_msg'])} on ({_us(diff, '+.1f')} %, goal {GOAL_PCT:g} %); "
        f"to exit {_us(off['cpu_us_per_msg_to_exit'])} / {_us(on['cpu_us_per_msg_to_exit'])}; "
        f"writer process (pid {writer.get('pid')}) "
        f"{_us(writer.get('cpu_us_per_msg_to_exit'))} us/msg to its exit, "
        f"{_us(writer.get('cpu_s_total'), '.2f')} s CPU in all"
    )
    return {
        "offered": rate,
        "seconds": seconds,
        "off": off,
        "on": on,
        "cpu_diff_pct": diff,
        "cpu_diff_pct_to_exit": _pct(on["cpu_us_per_msg_to_exit"], off["cpu_us_per_msg_to_exit"]),
        "goal_pct": GOAL_PCT,
    }
