"""The receive loop: one rclpy wait set, messages taken into the core.

rclpy's default executor receives only about 4k msg/s on the 7 srobot topics on
the reference machine, a loop over rclpy's wait set with ``take_message`` about
24k msg/s (``safety-supervisor bench``).  The daemon therefore creates its
subscriptions with rclpy (so they exist in the graph and are destroyed with the
node) but never spins an executor: :meth:`Receiver.serve` waits on one
``_rclpy.WaitSet`` holding every subscription, the reset service and a guard
condition, and drains each ready subscription with ``take_message``.  This is
the same private API ``rclpy.executors`` uses (rclpy 7.1.6).  All timed work is
done in the same loop (the node's ``timed_work``), the wait's timeout being the
earliest deadline, so the core is only ever touched by this one thread.

The hot path of a halt (docs/reference/log.md, ``logging.durability``): take,
read the fields, step in the core (which writes the violation record and hands
the inline publish to the engine), then ``log.flush()`` (the fsync under
``after_publish``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.serialization import deserialize_message

from mitigations.violationlog.writer import ViolationLog
from supervisor.daemon import heap
from supervisor.daemon.clock import WallClock
from supervisor.daemon.core import Core, warn
from supervisor.daemon.graph import InputGraph, Sub
from supervisor.daemon.interfaces import Interfaces
from supervisor.daemon.loss import OwnWrites
from supervisor.inputs.paths import ReadError
from supervisor.inputs.readers import SKIP, arrival_only

if TYPE_CHECKING:  # rosbags loads only when recording is on
    from supervisor.daemon.recorder import Recorder

# Longest a loop turn spends taking messages before its timed work (watchdog,
# heartbeat, timers) runs: a flood never starves them (docs/reference/ros-interfaces.md).
TURN_BUDGET_NS = 20_000_000


class Receiver:
    """Takes the messages of ``inputs``' subscriptions into ``core``."""

    def __init__(
        self,
        core: Core,
        log: ViolationLog,
        inputs: InputGraph,
        own_writes: OwnWrites,
        interfaces: Interfaces,
        recorder: Recorder | None,
    ) -> None:
        self.core = core
        self.log = log
        self.inputs = inputs
        self.recorder = recorder
        self._own = own_writes
        # The same list object as the core's ``published`` sink appends to.
        self._unpublished = interfaces.unpublished
        self._publish_reports = interfaces.publish_reports
        self._clock = WallClock()  # message stamps onto the loop's clock (age_of)
        self.rebuild = False  # leave serve(): the subscriptions changed

    def serve(
        self,
        ctx: Context,
        wake: Any,
        stop: threading.Event,
        *,
        reset_service: Callable[[], Any],
        deadline: Callable[[int], int],
        timed_work: Callable[[int], None],
        serve_reset: Callable[[Any], None],
        trigger: str | None,
    ) -> None:
        """Wait and receive until ``stop`` or :attr:`rebuild`.  ``reset_service()``
        brings the reset service in line with the config and returns it (or None),
        ``deadline(now)`` is the latest time to wake, ``timed_work(now)`` runs after
        each wait, ``trigger`` names the step trigger."""
        # This loop's records are echoed and teed at flush(), after each message's
        # actions, and under after_publish fsynced there: the halt follows the
        # record's write directly (docs/reference/log.md).
        self.log.defer_thread = threading.get_ident()
        subs = self.inputs.subs
        by_ptr: dict[int, Sub] = {}
        with contextlib.ExitStack() as stack:
            for s in subs:
                stack.enter_context(s.sub.handle)
                by_ptr[s.sub.handle.pointer] = s
                s.take = s.sub.handle.take_message
            service = reset_service()
            srv = service.handle if service is not None else None
            if srv is not None:
                stack.enter_context(srv)
            stack.enter_context(wake.handle)
            stack.enter_context(ctx.handle)
            wait_set = _rclpy.WaitSet(len(subs), 1, 0, 0, 0 if srv is None else 1, 0, ctx.handle)
            # Finalised before the handles it holds are released, on every way out.
            stack.callback(wait_set.destroy_when_not_in_use)
            # The step trigger is taken last in each round (see _receive).
            order = {
                s.sub.handle.pointer: (any(v.name == trigger for v in s.vars), i)
                for i, s in enumerate(subs)
            }
            handles = [s.sub.handle for s in subs]  # rclpy's property, once
            guard = wake.handle
            while not stop.is_set() and not self.rebuild and ctx.ok():
                now = time.monotonic_ns()
                wait_set.clear_entities()
                for h in handles:
                    wait_set.add_subscription(h)
                if srv is not None:
                    wait_set.add_service(srv)
                wait_set.add_guard_condition(guard)
                wait_set.wait(max(0, deadline(now) - now))
                ready = wait_set.get_ready_entities("subscription")
                if ready:
                    self._receive([by_ptr[p] for p in sorted(ready, key=order.__getitem__)])
                if srv is not None and wait_set.get_ready_entities("service"):
                    serve_reset(srv)
                timed_work(time.monotonic_ns())
                self.log.flush()  # what this turn logged: to the journal and the copies
                heap.collect()  # after the turn's halts, not inside one (heap.py)

    def _receive(self, ready: list[Sub]) -> None:
        """Take one message from each ready subscription in turn, until all are
        empty or the turn's budget is spent; what is left stays queued in the
        middleware for the next turn, after the timed work. Round by round, a
        backlog of the robot's cycles is replayed cycle by cycle, trigger last."""
        end = time.monotonic_ns() + TURN_BUDGET_NS
        while ready:
            ready = [s for s in ready if self._take(s)]
            if time.monotonic_ns() >= end:
                return

    def _take(self, s: Sub) -> bool:
        """One message of ``s`` into the core; False when its queue is empty."""
        raw = self.recorder is not None and s.recorded is not None
        assert s.take is not None
        taken = s.take(s.msg_type, raw)
        if taken is None:
            return False
        msg, info = taken
        t = time.monotonic_ns()
        data = msg
        seq = info.get("publication_sequence_number") if isinstance(info, dict) else None
        if seq:
            if self._own.is_own(s.topic, seq, info.get("source_timestamp")):
                for v in s.vars:
                    self.core.count_own(v.name)  # our own mitigation: not the robot's value
                return True
            assert s.streams is not None
            gap = s.streams.on_sequence(seq)
            if gap:
                for v in s.vars:
                    self.core.count_lost(v.name, gap)
        values = None
        if raw:
            assert self.recorder is not None and s.recorded is not None
            if not s.offered:  # its publisher is matched, so in the graph, by now
                self.inputs.offer_qos(s, self.inputs.publishers(s))
            self.recorder.message(s.recorded, t, data)
            values = self._read_raw(s, data)
            if values is None:
                msg = deserialize_message(data, s.msg_type)
        if values is None:
            values = self._read(s, msg, t)
        if values:
            self.core.fields(values, t)
        if self._unpublished:
            self._publish_reports()
        self.log.flush()  # a violation's fsync, echo and copies, after its actions are out
        return True

    def _read(self, s: Sub, msg: Any, t: int) -> list[tuple[str, Any]]:
        """Each variable's value in ``msg`` (those its message carries)."""
        values = []
        for v, read, age in zip(s.vars, s.readers, s.ages, strict=True):
            try:
                x = read(msg)
            except (ReadError, AttributeError, TypeError, ValueError) as e:
                self.core.reject(v.name, t, str(e))  # e.g. an element past the end
                continue
            if x is SKIP:
                continue
            if age:
                x, step = self._clock.to_monotonic(x, t)
                if step:
                    warn(f"the wall clock stepped by {step / 1e6:+.1f} ms")
                    self.log.supervisor("clock_jump", by_ms=round(step / 1e6, 3))
            values.append((v.name, x))
        return values

    def _read_raw(self, s: Sub, data: bytes) -> list[tuple[str, Any]] | None:
        """The subscription's fields read from the serialized message where the CDR
        layout places them (supervisor/daemon/cdr.py), without building the message:
        recording then costs the loop less than deserialising would.  None: the
        caller deserialises.  The first messages of each topic are read both ways,
        and a disagreement turns this off for the topic (and is logged)."""
        if s.plans is None:
            return None
        out = []
        for v, plan in zip(s.vars, s.plans, strict=True):
            x = True if arrival_only(v) else plan.read(data) if plan is not None else None
            if x is None:
                return None
            out.append((v.name, x))
        if s.checks:
            s.checks -= 1
            msg = deserialize_message(data, s.msg_type)
            try:
                want = [(v.name, read(msg)) for v, read in zip(s.vars, s.readers, strict=True)]
            except (ReadError, AttributeError, TypeError, ValueError):
                return None
            if any(a != b and a == a for (_, a), (_, b) in zip(want, out, strict=True)):
                s.plans = None
                self.log.supervisor("record_read_fallback", topic=s.var.topic)
                return want
        return out
