"""Stamps onto the loop's monotonic clock (supervisor/daemon/clock.py): an age is
the latency at receipt plus the monotonic time since, so a step of this machine's
wall clock changes neither and is reported once, by its size."""

from __future__ import annotations

import time

import pytest

from supervisor.daemon import clock
from supervisor.daemon.clock import JUMP_NS, WallClock

S = 1_000_000_000


def test_a_stamp_keeps_its_latency_at_receipt() -> None:
    c = WallClock()
    mono = time.monotonic_ns()
    wall = time.time_ns()
    stamp, step = c.to_monotonic(wall - 40_000_000, mono)  # 40 ms old at receipt
    assert step == 0
    # on the monotonic clock, the stamp lies 40 ms (and the call's few µs) before receipt
    assert 40_000_000 <= mono - stamp < 41_000_000


def test_a_wall_clock_step_is_reported_once_and_ages_stay_right(monkeypatch) -> None:
    wall = [1_700_000_000 * S]
    monkeypatch.setattr(clock.time, "time_ns", lambda: wall[0])
    monkeypatch.setattr(clock.time, "monotonic_ns", lambda: 5 * S)
    c = WallClock()
    stamp, step = c.to_monotonic(wall[0] - 10_000_000, 5 * S)
    assert (5 * S - stamp, step) == (10_000_000, 0)
    wall[0] += 1 * S + 3_600 * S  # an hour's NTP step, one second later
    stamp, step = c.to_monotonic(wall[0] - 10_000_000, 6 * S)
    assert step == 3_600 * S  # said once, by its size
    assert 6 * S - stamp == 10_000_000  # the age does not jump
    wall[0] += 1 * S
    stamp, step = c.to_monotonic(wall[0] - 10_000_000, 7 * S)
    assert (7 * S - stamp, step) == (10_000_000, 0)


@pytest.mark.parametrize(
    ("drift_ns", "said"), [(1_000, 0), (JUMP_NS, 0), (JUMP_NS + 1, JUMP_NS + 1)]
)
def test_only_a_step_beyond_20_ms_is_said(monkeypatch, drift_ns: int, said: int) -> None:
    wall = [1_700_000_000 * S]
    monkeypatch.setattr(clock.time, "time_ns", lambda: wall[0])
    monkeypatch.setattr(clock.time, "monotonic_ns", lambda: 5 * S)
    c = WallClock()
    wall[0] += drift_ns  # NTP slewing moves the offset a little; a step moves it a lot
    _, step = c.to_monotonic(wall[0], 5 * S)
    assert step == said
