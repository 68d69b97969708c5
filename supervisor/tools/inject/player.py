"""Publishing an injection with the timing the step policy needs: the warm-up,
the ticks, then the nominal state."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from monitors.verify.interpret import Value
from supervisor.tools.inject.injection import Injection
from supervisor.tools.inject.node import RosOut
from supervisor.tools.inject.target import Target

WARMUP_PERIOD_S = 0.1
NOMINAL_PERIOD_S = 0.1  # the nominal state after an injection, well under stale_after_ms


@dataclass
class Timing:
    gap_s: float = 0.02  # before the trigger (on_trigger) / between messages (on_message)
    tick_s: float = 0.05  # between two injected ticks
    hold_s: float = 0.5  # the nominal state after an injection


class Player:
    """Publishes injections with the timing the step policy needs."""

    def __init__(self, out: RosOut, target: Target, timing: Timing) -> None:
        self.out = out
        self.timing = timing
        self.policy = target.cfg.step.policy
        self.period_s = (target.cfg.step.period_ms or 100.0) / 1000

    def state(self, s: Mapping[str, Value]) -> None:
        """One tick's worth of messages."""
        topics = self.out.topics
        if self.policy == "on_trigger":
            *rest, trig = topics
            for t in rest:
                self.out.publish(t, s)
            time.sleep(self.timing.gap_s)  # DDS does not order topics: the trigger last
            self.out.publish(trig, s)
        elif self.policy == "on_message":
            for i, t in enumerate(topics):
                if i:
                    time.sleep(self.timing.gap_s)  # one step per message, in this order
                self.out.publish(t, s)
        elif self.policy == "periodic":
            # hold the values for 2 periods, every topic at the period
            for _ in range(2):
                for t in topics:
                    self.out.publish(t, s)
                time.sleep(self.period_s)
        else:
            for t in topics:
                self.out.publish(t, s)

    def hold(
        self, s: Mapping[str, Value], seconds: float, until: Callable[[], bool] | None = None
    ) -> None:
        """Publish ``s`` at 10 Hz for ``seconds`` (or until ``until()``)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.state(s)
            if until is not None and until():
                return
            time.sleep(NOMINAL_PERIOD_S)

    def play(self, inj: Injection, warmup: int) -> list[list[str]]:
        """Warm-up, the ticks, then the nominal state; returns the at_ms column."""
        t0 = time.monotonic()
        ms = [[f"{0:.0f} (x{warmup})"]]
        for i in range(warmup):
            if i:
                time.sleep(WARMUP_PERIOD_S)
            self.state(inj.trace[0])
        time.sleep(WARMUP_PERIOD_S)
        for t in range(1, inj.k):
            if t > 1:
                time.sleep(self.timing.tick_s)
            ms.append([f"{(time.monotonic() - t0) * 1000:.0f}"])
            self.state(inj.trace[t])
        time.sleep(self.timing.tick_s)
        return ms
