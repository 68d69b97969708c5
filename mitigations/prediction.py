"""Time to violation: from a requirement's margin history, how long until it reaches 0.

Pure and tick-precise, like :mod:`mitigations.policy`: no threads, no clocks, no
rclpy.  The monitoring core adds each step's margin of a requirement with
``predict:`` to its :class:`Trend` and asks :meth:`Trend.estimate`; the policy
decides what an estimate inside the horizon does (docs/reference/prediction.md).

The estimate is an ordinary least-squares line through the (time, margin) samples
of the last ``window_ms``: its slope, the slope's standard error, and the time at
which the line crosses 0.  Memory is constant per requirement (a ring of at most
``capacity`` samples) and each step costs O(1): the sums of the fit are kept
incrementally, and recomputed from the ring only when the time origin is moved
(so that float64 sums of squares never lose the window's precision to the run's
length: the sums are of offsets from a time and a margin inside the window, so
that a sum of squares minus its mean's square keeps its digits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MS = 1_000_000
S = 1_000_000_000
DEFAULT_CAPACITY = 256  # samples kept per requirement: 500 ms at 500 Hz
MIN_SAMPLES = 3  # a line and a spread need at least three points
Z_INTERVAL = 1.96  # the interval of the time to zero: slope +- 1.96 standard errors
# A slope smaller than this, relative to the margins' size per second of window, is
# the float rounding of a flat line, not a trend.
_FLAT = 1e-9


@dataclass(frozen=True)
class Estimate:
    """Where a requirement's margin is heading, at the latest sample's time.

    ``slope`` is in margin units per second.  ``ttv_ms`` is the time from ``t_ns``
    until the fitted line reaches 0 (None when it is not falling), with the interval
    ``ttv_lo_ms``..``ttv_hi_ms`` from the slope's 95 % interval (``ttv_hi_ms`` is
    ``math.inf`` when the slope's interval reaches 0).  ``confidence`` is the
    probability, under the fit's normal errors, that the line's value at
    ``t_ns + horizon`` is at most 0: how sure the fit is that the margin is gone
    within the horizon (docs/reference/prediction.md, "Confidence")."""

    t_ns: int
    margin: float  # the latest observed margin
    fitted: float  # the line's value at t_ns
    slope: float
    slope_se: float
    ttv_ms: float | None
    ttv_lo_ms: float | None
    ttv_hi_ms: float | None
    confidence: float
    samples: int
    window_ms: float


class Trend:
    """The last ``window_ms`` of one requirement's margins, fitted by a line."""

    def __init__(
        self, window_ms: float, horizon_ms: float, capacity: int = DEFAULT_CAPACITY
    ) -> None:
        if capacity < MIN_SAMPLES:
            raise ValueError(f"capacity must be at least {MIN_SAMPLES}")
        self.window_ns = int(window_ms * MS)
        self.horizon_s = horizon_ms / 1000.0
        self.window_ms = window_ms
        self._cap = capacity
        self._t = [0] * capacity
        self._m = [0.0] * capacity
        self._head = 0  # index of the oldest sample
        self._n = 0
        self._origin = 0  # time of the sums' x = 0
        self._ref = 0.0  # margin of the sums' y = 0
        self._sx = self._sy = self._sxx = self._sxy = self._syy = 0.0

    def __len__(self) -> int:
        return self._n

    def clear(self) -> None:
        """Forget the history (a monitor reset, a margin that is not a number)."""
        self._n = 0
        self._head = 0
        self._sx = self._sy = self._sxx = self._sxy = self._syy = 0.0

    def add(self, t_ns: int, margin: float) -> None:
        """The margin at ``t_ns`` (not before the previous sample's time).  A margin
        that is not finite (a boolean atom's +-inf, a NaN) has no trend, and one at or
        below 0 is no distance still to cover (violated, or a boundary: the 0 of
        ``classifier = 0`` where nobody is there): the history is cleared and starts
        again at the next positive one, so that a line never joins two stretches of
        a formula whose margin switched between terms."""
        if not (math.isfinite(margin) and margin > 0.0):
            self.clear()
            return
        if self._n and t_ns < self._t[(self._head + self._n - 1) % self._cap]:
            self.clear()  # time went back (a reload's new session): start afresh
        if self._n == self._cap:
            self._drop()
        if self._n == 0:
            self._origin, self._ref = t_ns, margin
        i = (self._head + self._n) % self._cap
        self._t[i] = t_ns
        self._m[i] = margin
        self._n += 1
        self._include(t_ns, margin, 1.0)
        while self._n and self._t[self._head] < t_ns - self.window_ns:
            self._drop()
        # Once a window's length past the origin, move it (O(capacity) once per
        # window: O(1) a sample).
        if self._n and self._t[self._head] - self._origin > self.window_ns:
            self._rebase()

    def estimate(self) -> Estimate | None:
        """The fit of the window, or None while it has fewer than three samples, or
        they span less than half the window (and the ring is not full): a line
        through the first few samples of a stretch is mostly the sensor's
        resolution (a whole-metre reading's step looks like a sprint)."""
        n = self._n
        if n < MIN_SAMPLES:
            return None
        first, last = self._t[self._head], self._t[(self._head + n - 1) % self._cap]
        if 2 * (last - first) < self.window_ns and n < self._cap:
            return None
        mx, my = self._sx / n, self._sy / n
        sxx = self._sxx - self._sx * mx
        if sxx <= 0.0:
            return None
        sxy = self._sxy - self._sx * my
        syy = max(self._syy - self._sy * my, 0.0)
        slope = sxy / sxx
        sse = max(syy - slope * sxy, 0.0)
        s2 = sse / (n - 2)
        slope_se = math.sqrt(s2 / sxx)
        last = (self._head + n - 1) % self._cap
        t_ns = self._t[last]
        x_now = (t_ns - self._origin) / S
        fitted = self._ref + my + slope * (x_now - mx)
        # The fitted line's value at the horizon and its standard error (the mean
        # response's: intercept and slope together).
        x_h = x_now + self.horizon_s
        at_h = self._ref + my + slope * (x_h - mx)
        se_h = math.sqrt(s2 * (1.0 / n + (x_h - mx) ** 2 / sxx))
        confidence = _falls_below_zero(at_h, se_h)
        ttv = lo = hi = None
        span_s = max(x_now - (self._t[self._head] - self._origin) / S, 1e-9)
        scale = abs(self._ref + my) + math.sqrt(syy / n)
        if slope < -_FLAT * scale / span_s:
            ttv = max(-fitted / slope, 0.0) * 1000.0
            steep = slope - Z_INTERVAL * slope_se
            shallow = slope + Z_INTERVAL * slope_se
            lo = max(-fitted / steep, 0.0) * 1000.0
            hi = max(-fitted / shallow, 0.0) * 1000.0 if shallow < 0.0 else math.inf
        return Estimate(
            t_ns=t_ns,
            margin=self._m[last],
            fitted=fitted,
            slope=slope,
            slope_se=slope_se,
            ttv_ms=ttv,
            ttv_lo_ms=lo,
            ttv_hi_ms=hi,
            confidence=confidence,
            samples=n,
            window_ms=self.window_ms,
        )

    # ------------------------------------------------------------ the sums

    def _include(self, t_ns: int, m: float, sign: float) -> None:
        x = (t_ns - self._origin) / S
        m -= self._ref
        self._sx += sign * x
        self._sy += sign * m
        self._sxx += sign * x * x
        self._sxy += sign * x * m
        self._syy += sign * m * m

    def _drop(self) -> None:
        h = self._head
        self._include(self._t[h], self._m[h], -1.0)
        self._head = (h + 1) % self._cap
        self._n -= 1
        if self._n == 0:
            self.clear()

    def _rebase(self) -> None:
        self._origin, self._ref = self._t[self._head], self._m[self._head]
        self._sx = self._sy = self._sxx = self._sxy = self._syy = 0.0
        for k in range(self._n):
            i = (self._head + k) % self._cap
            self._include(self._t[i], self._m[i], 1.0)


def _falls_below_zero(mean: float, se: float) -> float:
    """P(X <= 0) for X ~ N(mean, se^2); a step function when se is 0."""
    if se <= 0.0 or not math.isfinite(se):
        return 1.0 if mean <= 0.0 else 0.0
    return 0.5 * math.erfc(mean / (se * math.sqrt(2.0)))
