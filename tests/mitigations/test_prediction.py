"""The time-to-violation estimator (mitigations/prediction.py): a least-squares line
over the last window of (time, margin) samples, its spread and its confidence."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from mitigations.prediction import Trend

MS = 1_000_000

periods_ms = st.integers(min_value=1, max_value=50)
slopes = st.floats(min_value=-100.0, max_value=-0.01)  # margin units per second
starts = st.floats(min_value=0.01, max_value=100.0)


def _feed(trend: Trend, t0_ns: int, period_ms: int, margins: list[float]) -> None:
    for k, m in enumerate(margins):
        trend.add(t0_ns + k * period_ms * MS, m)


@settings(max_examples=200, deadline=None)
@given(
    period=periods_ms,
    slope=slopes,
    left=starts,
    n=st.integers(min_value=3, max_value=80),
    t0_s=st.integers(min_value=0, max_value=10**6),
)
def test_a_linear_margin_gives_the_exact_time_to_zero(
    period: int, slope: float, left: float, n: int, t0_s: int
) -> None:
    # The run's length (t0) must not cost the window its precision.
    trend = Trend(window_ms=n * period, horizon_ms=1500)
    dt = period / 1000.0
    start = left - slope * (n - 1) * dt  # the last sample's margin is ``left`` > 0
    margins = [start + slope * k * dt for k in range(n)]
    _feed(trend, t0_s * 10**9, period, margins)
    est = trend.estimate()
    assert est is not None
    assert est.samples == n
    assert math.isclose(est.slope, slope, rel_tol=1e-6, abs_tol=1e-9)
    expected_ms = -margins[-1] / slope * 1000.0
    assert est.ttv_ms is not None
    assert math.isclose(est.ttv_ms, expected_ms, rel_tol=1e-6, abs_tol=1e-3)
    # No noise: no spread, and the interval collapses onto the estimate.
    assert est.slope_se <= 1e-6 * abs(slope) + 1e-9
    assert est.ttv_lo_ms is not None and est.ttv_hi_ms is not None
    assert math.isclose(est.ttv_lo_ms, expected_ms, rel_tol=1e-4, abs_tol=1e-2)
    assert math.isclose(est.ttv_hi_ms, expected_ms, rel_tol=1e-4, abs_tol=1e-2)
    # Sure to reach 0 within the horizon exactly when the line says so.
    assert est.confidence == (1.0 if expected_ms <= 1500 - 1e-3 else est.confidence)
    if expected_ms > 1500 + 1e-3:
        assert est.confidence == 0.0


@settings(max_examples=200, deadline=None)
@given(
    slope=slopes,
    ahead_s=st.floats(min_value=0.05, max_value=5.0),
    pattern=st.lists(st.floats(min_value=-1.0, max_value=1.0), min_size=8, max_size=40),
    k1=st.floats(min_value=0.0, max_value=0.2),
    extra=st.floats(min_value=0.05, max_value=0.5),
)
def test_noise_widens_the_spread(
    slope: float, ahead_s: float, pattern: list[float], k1: float, extra: float
) -> None:
    # Noise orthogonal to the line (its own line projected out) leaves the fit's
    # slope and time to zero where they are and widens only the spread.
    n = len(pattern)
    xs = [k * 0.01 for k in range(n)]
    mx, mp = sum(xs) / n, sum(pattern) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    b = sum((x - mx) * (p - mp) for x, p in zip(xs, pattern, strict=True)) / sxx
    noise = [p - mp - b * (x - mx) for x, p in zip(xs, pattern, strict=True)]
    if max(abs(e) for e in noise) < 1e-3:
        return  # the pattern was a line: no noise to scale
    k2 = k1 + extra
    # the line reaches 0 ahead_s after the window, the noisiest margin stays above 0
    start = -slope * (xs[-1] + ahead_s) + k2 * max(abs(e) for e in noise)
    ests = []
    for k in (k1, k2):
        trend = Trend(window_ms=n * 10, horizon_ms=1500)
        _feed(trend, 0, 10, [start + slope * x + k * e for x, e in zip(xs, noise, strict=True)])
        est = trend.estimate()
        assert est is not None
        ests.append(est)
    low, high = ests
    assert math.isclose(low.slope, high.slope, rel_tol=1e-6, abs_tol=1e-6)
    assert high.slope_se > low.slope_se
    assert low.ttv_lo_ms is not None and high.ttv_lo_ms is not None
    assert low.ttv_hi_ms is not None and high.ttv_hi_ms is not None
    # The interval reaches earlier and at least as late (its late end may be
    # unbounded in both: a slope that may be 0).
    assert high.ttv_lo_ms < low.ttv_lo_ms
    assert high.ttv_hi_ms >= low.ttv_hi_ms


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.floats(min_value=0.0, max_value=10.0), min_size=3, max_size=60),
    start=st.floats(min_value=0.001, max_value=50.0),
    period=periods_ms,
)
def test_a_rising_margin_predicts_nothing(steps: list[float], start: float, period: int) -> None:
    margins = []
    m = start
    for d in steps:
        m += d
        margins.append(m)
    trend = Trend(window_ms=len(margins) * period, horizon_ms=1500)
    _feed(trend, 0, period, margins)
    est = trend.estimate()
    assert est is not None
    assert est.slope >= -1e-9
    assert est.ttv_ms is None
    if margins[-1] > 0:
        assert est.confidence < 0.5  # a rising line is not below 0 at the horizon


def test_the_window_keeps_only_the_last_samples() -> None:
    # Rising for a second, then falling: a 300 ms window sees the fall alone.
    trend = Trend(window_ms=300, horizon_ms=1500)
    margins = [1.0 + 0.01 * k for k in range(100)] + [2.0 - 0.02 * k for k in range(1, 51)]
    _feed(trend, 0, 10, margins)
    est = trend.estimate()
    assert est is not None
    assert est.samples == 31  # 300 ms at 10 ms, both ends included
    assert math.isclose(est.slope, -2.0, rel_tol=1e-9)


def test_the_ring_is_bounded() -> None:
    # 16 samples cover 15 ms of the 10 s window: a full ring is fitted anyway
    trend = Trend(window_ms=10_000, horizon_ms=1500, capacity=16)
    _feed(trend, 0, 1, [5.0 - 0.001 * k for k in range(1000)])
    assert len(trend) == 16
    est = trend.estimate()
    assert est is not None and est.samples == 16
    assert math.isclose(est.slope, -1.0, rel_tol=1e-9)


def test_the_first_samples_of_a_stretch_are_not_fitted() -> None:
    # Half the window first: a reading's step in the first few samples is no trend.
    trend = Trend(window_ms=1000, horizon_ms=1500)
    _feed(trend, 0, 100, [4.0, 4.0, 3.0, 3.0, 3.0])  # 400 ms of a 1000 ms window
    assert len(trend) == 5 and trend.estimate() is None
    trend.add(500 * MS, 3.0)  # 500 ms: half the window
    est = trend.estimate()
    assert est is not None and est.samples == 6


def test_a_margin_that_is_no_distance_starts_the_history_again() -> None:
    trend = Trend(window_ms=40, horizon_ms=1500)
    _feed(trend, 0, 10, [3.0, 2.0, 1.0])
    assert trend.estimate() is not None
    trend.add(40 * MS, math.inf)  # a boolean atom decided the margin
    assert len(trend) == 0 and trend.estimate() is None
    trend.add(50 * MS, math.nan)
    trend.add(60 * MS, 1.0)
    assert len(trend) == 1
    # 0: a boundary (nobody there: classifier = 0), then a person at 4 m: the line
    # must not join the stretches, or it would fall from 6 through 0 to 4
    _feed(trend, 70 * MS, 10, [6.0, 6.0, 0.0, 0.0, 4.0, 4.0, 4.0])
    est = trend.estimate()
    assert est is not None and est.samples == 3 and est.slope == 0.0 and est.ttv_ms is None
