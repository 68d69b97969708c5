"""Message stamps on the loop's clock (docs/reference/config.md, "age_of").

A stamp is wall-clock time (ROS time of the robot's clock); the loop keeps time
with the monotonic clock, which never jumps.  A stamp is moved onto the
monotonic clock with the offset between the two clocks measured at its
message's receipt, so an age is the sensor's latency at receipt plus the
monotonic time since: a step of this machine's wall clock (NTP, an operator)
changes neither, and is said once as a ``clock_jump`` record.
"""

from __future__ import annotations

import time

JUMP_NS = 20_000_000  # offset changes above 20 ms are steps, not NTP's slewing


class WallClock:
    def __init__(self) -> None:
        self.offset_ns = time.time_ns() - time.monotonic_ns()

    def to_monotonic(self, stamp_ns: int, received_ns: int) -> tuple[int, int]:
        """``stamp_ns`` (wall) on the monotonic clock of ``received_ns`` (the
        message's receipt, just now); and by how much the wall clock stepped since
        the last call (0 when it did not)."""
        offset = time.time_ns() - received_ns
        step = offset - self.offset_ns
        self.offset_ns = offset
        return stamp_ns - offset, step if abs(step) > JUMP_NS else 0
