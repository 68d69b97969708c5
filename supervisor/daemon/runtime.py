"""The runtime core: latest values -> step policy -> monitor -> violations.

No rclpy here: the ROS node feeds messages in, and ``replay`` feeds a recorded
trace in, through the same code, so online and offline verdicts are equal.

Time is passed in explicitly (monotonic nanoseconds) so tests are tick-precise
and replay uses the recorded timestamps.

Step policies (config ``step.policy``), the thesis's asynchronous-topic problem
(sec. 5.1.2) being the reason there is more than one:
- ``periodic``: a timer samples the latest values every ``period_ms``
  (Copilot's synchronous model);
- ``on_message``: step after every message (OGMA's behaviour; shows transient
  false violations while a burst of topics is half updated);
- ``on_trigger``: step after the ``trigger`` variable's message (the thesis's fix);
- ``synchronized``: step once every input has a message newer than the last
  step, or ``max_skew_ms`` after the first new message when some never came.
Nothing is stepped until every input has a value (or an ``initial:`` value).

A batch of messages (``replay``'s recordings) goes through :meth:`Runtime.step_rows`:
the same decisions as :meth:`Runtime.on_values` message by message, made by the same
``_steps_on``, with the monitor stepped in one C call (numpy's part is in
``bulk.py``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, cast, runtime_checkable

from mitigations.violationlog.format import Row

INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1
# A stamp later than its receipt by more than this is said (input_future_stamp):
# clocks synchronised by NTP or PTP agree far better.
FUTURE_TOLERANCE_NS = 1_000_000


class Monitor(Protocol):
    """What the runtime needs of a loaded monitor (monitors.backends.load.LoadedMonitor)."""

    def tick(self, values: Sequence[Any]) -> Sequence[int]: ...
    def reset(self) -> None: ...
    def reset_requirement(self, index: int) -> None: ...

    # margins(): each requirement's margin after the last tick, where the monitor
    # has them (LoadedMonitor with MonitorSpec.margins): Runtime.margins asks it.


@runtime_checkable
class BatchMonitor(Monitor, Protocol):
    """A monitor that steps many rows in one call (LoadedMonitor): what
    :meth:`Runtime.step_rows` needs besides :class:`Monitor`."""

    def pack_columns(self, columns: Sequence[Any]) -> Any: ...
    def tick_until(self, rows: Any) -> tuple[int, bytes]: ...


# The policies whose decision to step is a function of the message alone
# (Runtime._steps_on): a batch of their messages can be stepped in bulk.
MESSAGE_POLICIES = ("on_message", "on_trigger")


@dataclass(frozen=True)
class InputSpec:
    name: str
    type: str  # bool | int64 | double
    initial: Any = None
    stale_after_ns: int | None = None
    event: bool = False  # true at the step after its message, false otherwise
    # value | event | age | rate (supervisor/inputs/readers.py): an age is fed its
    # message's stamp and a rate each arrival; both are worked out at each step.
    kind: str = "value"
    sporadic: bool = False  # silence is normal: only its own stale_after_ns applies
    window_ns: int = 1_000_000_000  # a rate's window


@dataclass
class StepResult:
    tick: int
    t_ns: int
    violated: list[int]  # requirement indices whose handler fired
    inputs: dict[str, Any]


@dataclass(frozen=True)
class Rows:
    """A batch of messages for :meth:`Runtime.step_rows`, in receive order: row i
    was received at ``t_ns[i]`` (int64 nanoseconds, not decreasing).  ``values``
    maps an input to ``(mask, column)``: numpy arrays as long as ``t_ns``, the
    rows whose message sets that input and its value on them (other rows: any)."""

    t_ns: Any
    values: Mapping[str, tuple[Any, Any]]


@dataclass(frozen=True)
class Bulk:
    """What :meth:`Runtime.step_rows` did: the first ``rows`` rows were taken
    (0: none, step them one by one), the monitor stepped ``ticks`` times, and
    ``result`` is the last step when it violated (for the policies, as
    :meth:`Runtime.on_values` returns a step)."""

    rows: int = 0
    ticks: int = 0
    result: StepResult | None = None


@dataclass
class InputEvent:
    """Something the operator should know about an input (logged as `supervisor`)."""

    what: str  # input_stale | input_recovered | input_rejected | input_nan | input_future_stamp
    name: str
    t_ns: int
    detail: str = ""


@dataclass
class _Input:
    spec: InputSpec
    value: Any = None
    has_value: bool = False
    last_ns: int | None = None  # time of the last accepted message
    stale: bool = False
    fresh: bool = False  # updated since the last step (synchronized policy)
    messages: int = 0
    rejected: int = 0
    nan: int = 0  # NaN doubles accepted (the formula decides; reported all the same)
    future: int = 0  # stamps later than their receipt (an age's input)
    lost: int = 0  # skipped in the publishers' sequence numbers (supervisor.daemon.loss)
    own: int = 0  # the supervisor's own messages on this topic, never taken as input
    stamp: int | None = None  # an age's latest message stamp, on the runtime's clock
    arrivals: deque = field(default_factory=deque)  # a rate's receive times in its window
    first_ns: int | None = None  # a rate's first message: known a full window after it


def _limit(spec: InputSpec, default_after_ns: int | None) -> int | None:
    """An input's silence limit: its own, else the step's; an event (an estop that
    is rarely pressed) and the other sporadic inputs only their own, as silence is
    their normal state."""
    if spec.event or spec.sporadic:
        return spec.stale_after_ns
    return spec.stale_after_ns or default_after_ns


def coerce(value: Any, vtype: str) -> tuple[Any, str | None]:
    """Convert a message field to the monitor's C type; (value, None) or (None, why)."""
    if vtype == "bool":
        if isinstance(value, bool):
            return value, None
        if isinstance(value, int) and value in (0, 1):
            return bool(value), None
        return None, f"{value!r} is not a bool"
    if isinstance(value, bytes) and len(value) == 1:  # rclpy's byte/octet/char: b'\x02'
        value = value[0]
    if vtype == "int64":
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and math.isfinite(value) and value.is_integer():
                value = int(value)
            else:
                return None, f"{value!r} is not an integer"
        if not INT64_MIN <= value <= INT64_MAX:
            return None, f"{value} does not fit in int64"
        return value, None
    if isinstance(value, bool):
        return None, f"{value!r} is not a number"
    if isinstance(value, int | float):
        return float(value), None
    return None, f"{value!r} is not a number"


@dataclass
class Runtime:
    inputs: Sequence[InputSpec]
    monitor: Monitor
    policy: str = "periodic"
    trigger: str | None = None
    period_ns: int | None = None
    max_skew_ns: int | None = None
    recent_len: int = 10
    tick: int = 0
    _in: list[_Input] = field(default_factory=list)
    _index: dict[str, int] = field(default_factory=dict)
    recent: deque = field(default_factory=deque)
    _pending_since: int | None = None  # synchronized: first new message after the last step
    _next_periodic: int | None = None
    _derived: list[_Input] = field(default_factory=list)  # ages and rates
    _events: list[_Input] = field(default_factory=list)
    _ready: bool = False
    _bulk: bool = False  # step_rows may take batches (policy, inputs and monitor allow)
    # The monitor of the predicted requirements' margins (Project.prediction_spec),
    # stepped with the same values after the monitor; None when nothing predicts.
    margin_monitor: Any = None
    _names: tuple[str, ...] = ()
    # per input: its C type when a plain value (neither an event, an age nor a rate),
    # else None: on_values takes a value of exactly that type as it is (coerce would)
    _plain: tuple[str | None, ...] = ()

    def __post_init__(self) -> None:
        self._in = [_Input(s) for s in self.inputs]
        self._index = {s.name: i for i, s in enumerate(self.inputs)}
        self.recent = deque(maxlen=max(1, self.recent_len))
        for inp in self._in:
            if inp.spec.initial is not None:
                inp.value, inp.has_value = inp.spec.initial, True
            if inp.spec.event:  # false until its first message: never blocks stepping
                inp.value, inp.has_value = False, True
        self._derived = [i for i in self._in if i.spec.kind in ("age", "rate")]
        self._events = [i for i in self._in if i.spec.event]
        self._names = tuple(s.name for s in self.inputs)
        self._plain = tuple(
            s.type if s.kind == "value" and not s.event else None for s in self.inputs
        )
        if self.policy == "on_trigger" and self.trigger not in self._index:
            raise ValueError(f"trigger '{self.trigger}' is not an input")
        if self.policy == "periodic" and not self.period_ns:
            raise ValueError("periodic policy needs a period")
        # An event is true for one step only, an age or a rate changes with time
        # alone: a forward fill of the rows' values cannot say that.
        self._bulk = (
            self.policy in MESSAGE_POLICIES
            and isinstance(self.monitor, BatchMonitor)
            and all(i.spec.kind == "value" and not i.spec.event for i in self._in)
        )

    # ------------------------------------------------------------ state

    @property
    def ready(self) -> bool:
        """Every input has a value: the monitor may be stepped (once true, it stays
        true: a value is never taken away, so it is looked at once)."""
        if not self._ready:
            self._ready = all(i.has_value for i in self._in)
        return self._ready

    def values(self) -> list[Any]:
        return [i.value for i in self._in]

    def snapshot(self) -> dict[str, Any]:
        return {i.spec.name: i.value for i in self._in}

    def stale_inputs(self) -> list[str]:
        return [i.spec.name for i in self._in if i.stale]

    def missing_inputs(self) -> list[str]:
        return [i.spec.name for i in self._in if not i.has_value]

    def input_stats(self) -> dict[str, dict[str, Any]]:
        return {
            i.spec.name: {
                "messages": i.messages,
                "rejected": i.rejected,
                "nan": i.nan,
                "future": i.future,
                "lost": i.lost,
                "own": i.own,
                "stale": i.stale,
                "last_ns": i.last_ns,
            }
            for i in self._in
        }

    def adopt(self, old: Runtime) -> None:
        """After a config reload: keep the latest values (same name and type),
        message counts and the tick count, so the new monitor steps at once
        instead of waiting for every input again."""
        self.tick = old.tick
        previous = {i.spec.name: i for i in old._in}
        for inp in self._in:
            o = previous.get(inp.spec.name)
            if o is None or o.spec.type != inp.spec.type:
                continue
            if o.has_value:
                inp.value, inp.has_value = o.value, True
            inp.last_ns, inp.stale, inp.messages, inp.rejected = (
                o.last_ns,
                o.stale,
                o.messages,
                o.rejected,
            )
            inp.nan, inp.lost, inp.own = o.nan, o.lost, o.own
            if o.spec.kind == inp.spec.kind:
                inp.stamp, inp.arrivals, inp.first_ns = o.stamp, o.arrivals, o.first_ns
        self.recent.extend(old.recent)

    # ------------------------------------------------------------ feeding

    def on_message(
        self, name: str, raw: Any, t_ns: int
    ) -> tuple[StepResult | None, list[InputEvent]]:
        """A message for input ``name`` arrived at ``t_ns``; maybe step."""
        return self.on_values(((name, raw),), t_ns)

    def on_values(
        self, values: Sequence[tuple[str, Any]], t_ns: int
    ) -> tuple[StepResult | None, list[InputEvent]]:
        """One message carrying inputs ``values`` (fields of one topic) arrived at
        ``t_ns``: every value is set, then the policy steps at most once."""
        events: list[InputEvent] = []
        accepted = []
        index, plain = self._index, self._plain
        for name, raw in values:
            i = index[name]
            inp = self._in[i]
            vtype = plain[i]
            if vtype is not None and not inp.stale:
                # The common case in fewer steps: a value of exactly its C type is
                # what coerce returns for it; anything else goes the whole way below.
                kind = type(raw)
                if (
                    (kind is float and vtype == "double" and raw == raw)
                    or (kind is bool and vtype == "bool")
                    or (kind is int and vtype == "int64" and INT64_MIN <= raw <= INT64_MAX)
                ):
                    accepted.append(name)
                    inp.value, inp.has_value, inp.last_ns, inp.fresh = raw, True, t_ns, True
                    inp.messages += 1
                    continue
            if inp.spec.kind in ("age", "rate"):
                accepted.append(name)
                self._arrived(inp, raw, t_ns, events)
                continue
            # an event's value is its message's arrival
            value, why = (True, None) if inp.spec.event else coerce(raw, inp.spec.type)
            if why is not None:
                inp.rejected += 1
                events.append(InputEvent("input_rejected", name, t_ns, why))
                continue
            accepted.append(name)
            inp.value, inp.has_value, inp.last_ns, inp.fresh = value, True, t_ns, True
            inp.messages += 1
            if value != value:  # NaN: a valid double, but almost always a sensor fault
                inp.nan += 1
                events.append(
                    InputEvent("input_nan", name, t_ns, "NaN (every comparison with it is false)")
                )
            if inp.stale:
                inp.stale = False
                events.append(InputEvent("input_recovered", name, t_ns))
        if not accepted:
            return None, events
        if self._steps_on(accepted):
            return self.step(t_ns), events
        if self.policy == "synchronized":
            if self._pending_since is None:
                self._pending_since = t_ns
            if all(i.fresh for i in self._in):
                return self.step(t_ns), events
        return None, events

    def _steps_on(self, accepted: Collection[str]) -> bool:
        """Whether one message that set the inputs ``accepted`` steps the monitor
        under a policy of MESSAGE_POLICIES (the others: False, they decide from
        state and time).  The one place of that decision, message by message
        (:meth:`on_values`) and in bulk (:meth:`step_rows`)."""
        if not accepted:
            return False
        return self.policy == "on_message" or (
            self.policy == "on_trigger" and self.trigger in accepted
        )

    def _arrived(self, inp: _Input, raw: Any, t_ns: int, events: list[InputEvent]) -> None:
        """An age's stamp or a rate's arrival: the value itself is worked out at
        each step (:meth:`_derive`)."""
        inp.last_ns, inp.fresh = t_ns, True
        inp.messages += 1
        if inp.spec.kind == "rate":
            if inp.first_ns is None:
                inp.first_ns = t_ns
            inp.arrivals.append(t_ns)
            return
        stamp = int(raw)
        ahead = stamp - t_ns
        if ahead > FUTURE_TOLERANCE_NS:  # the sender's clock is ahead of ours
            inp.future += 1
            events.append(
                InputEvent(
                    "input_future_stamp",
                    inp.spec.name,
                    t_ns,
                    f"stamp {ahead / 1e6:.1f} ms after its receipt: the age is negative",
                )
            )
        inp.stamp, inp.has_value = stamp, True
        if inp.stale:
            inp.stale = False
            events.append(InputEvent("input_recovered", inp.spec.name, t_ns))

    def _derive(self, t_ns: int) -> None:
        """Ages and rates at ``t_ns``, the step's time."""
        for inp in self._derived:
            if inp.spec.kind == "age":
                if inp.stamp is not None:
                    inp.value = (t_ns - inp.stamp) / 1e6
                continue
            window = inp.spec.window_ns
            arrivals = inp.arrivals
            while arrivals and arrivals[0] <= t_ns - window:
                arrivals.popleft()
            if inp.first_ns is not None and t_ns - inp.first_ns >= window:
                inp.value, inp.has_value = len(arrivals) * 1e9 / window, True

    def count_lost(self, name: str, n: int) -> None:
        """``n`` messages of input ``name`` never arrived (a sequence gap)."""
        self._in[self._index[name]].lost += n

    def count_own(self, name: str) -> None:
        """The supervisor's own message came back on input ``name``'s topic: it
        is not the robot's, so it changes neither the value nor the freshness."""
        self._in[self._index[name]].own += 1

    def due(self, t_ns: int) -> int | None:
        """When the next timer-driven step is due (periodic / synchronized skew)."""
        if self.policy == "periodic":
            return self._next_periodic if self._next_periodic is not None else t_ns
        if self.policy == "synchronized" and self._pending_since is not None and self.max_skew_ns:
            return self._pending_since + self.max_skew_ns
        return None

    def on_timer(self, t_ns: int) -> StepResult | None:
        """Called by the node's timer (and by replay between messages)."""
        if self.policy == "periodic":
            if self._next_periodic is None:
                self._next_periodic = t_ns
            if t_ns < self._next_periodic:
                return None
            assert self.period_ns
            # Keep the grid even if a timer callback ran late: ticks stay period-aligned.
            missed = (t_ns - self._next_periodic) // self.period_ns
            self._next_periodic += (missed + 1) * self.period_ns
            return self.step(t_ns)
        if self.policy == "synchronized" and self._pending_since is not None and self.max_skew_ns:
            if t_ns - self._pending_since >= self.max_skew_ns:
                return self.step(t_ns)
        return None

    def stale_due(self, default_after_ns: int | None) -> int | None:
        """When the next input turns stale if nothing arrives: silent for more than
        its limit, so one nanosecond after ``last + limit``."""
        times = [
            inp.last_ns + after + 1
            for inp in self._in
            if not inp.stale
            and inp.last_ns is not None
            and (after := _limit(inp.spec, default_after_ns))
        ]
        return min(times) if times else None

    def stale_after(self, name: str, default_after_ns: int | None) -> int | None:
        """Input ``name``'s silence limit in ns (None: never stale)."""
        return _limit(self._in[self._index[name]].spec, default_after_ns)

    def check_stale(self, t_ns: int, default_after_ns: int | None) -> list[InputEvent]:
        events = []
        for inp in self._in:
            after = _limit(inp.spec, default_after_ns)
            if not after or inp.stale:
                continue
            since = inp.last_ns
            if since is None:
                continue  # never received: reported as missing, not stale
            if t_ns - since > after:
                inp.stale = True
                events.append(
                    InputEvent(
                        "input_stale",
                        inp.spec.name,
                        t_ns,
                        f"silent for {(t_ns - since) / 1e6:.0f} ms",
                    )
                )
        return events

    # ------------------------------------------------------------ stepping

    def step(self, t_ns: int) -> StepResult | None:
        """Evaluate all requirements once with the latest values."""
        if self._derived:
            self._derive(t_ns)
        if not self.ready:
            return None
        values = self.values()
        flags = self.monitor.tick(values)
        if self.margin_monitor is not None:
            self.margin_monitor.tick(values)
        if self.policy == "synchronized":  # the one policy that reads freshness
            for inp in self._in:
                inp.fresh = False
        for inp in self._events:
            inp.value = False  # its tick is over
        self._pending_since = None
        snap = dict(zip(self._names, values, strict=True))
        tick = self.tick
        result = StepResult(tick, t_ns, [i for i, f in enumerate(flags) if f], snap)
        # encoded now, once: the violation record joins the rows' JSON (writer.Row)
        self.recent.append(Row.of({"tick": tick, **snap}))
        self.tick = tick + 1
        return result

    @property
    def bulk_ready(self) -> bool:
        """:meth:`step_rows` may take a batch now: a message-driven policy with
        plain values, every input has one and none is stale (a recovery would be
        an event to report)."""
        return (
            self._bulk
            and self.margin_monitor is None  # margins are read after every step
            and self.ready
            and not any(i.stale for i in self._in)
        )

    def step_rows(
        self, rows: Rows, default_after_ns: int | None = None, *, min_rows: int = 1
    ) -> Bulk:
        """The messages of ``rows`` (one :meth:`on_values` call each), stepped in
        bulk as far as nothing but stepping happens: up to the first value that
        would be reported (NaN, rejected), the first time an input could turn
        stale (``default_after_ns`` as in :meth:`check_stale`), and through the
        first violating step at most.  The state after is exactly what
        :meth:`on_values` row by row leaves; the rows not taken are for it.
        Nothing is taken unless :attr:`bulk_ready`, the quiet rows number at
        least ``min_rows`` and the monitor steps among them."""
        if not self.bulk_ready or len(rows.t_ns) < min_rows:
            return Bulk()
        from supervisor.daemon import bulk  # numpy: only when a batch comes

        t = rows.t_ns
        masks, columns = [], []
        cut = len(t)
        for inp in self._in:
            mask, column = rows.values.get(inp.spec.name, (None, None))
            masks.append(mask)
            columns.append(column)
            if mask is not None:
                bad = bulk.unfit(column[mask], inp.spec.type)
                if bad is not None:
                    cut = min(cut, bulk.nth_true(mask, bad))
            after = _limit(inp.spec, default_after_ns)
            if after and inp.last_ns is not None:
                times = t[mask] if mask is not None else t[:0]
                cut = min(cut, bulk.stale_cut(inp.last_ns, times, after, t))
        if cut < min_rows:
            return Bulk()
        t = t[:cut]
        masks = [None if m is None else m[:cut] for m in masks]
        types = [inp.spec.type for inp in self._in]
        columns = bulk.typed(columns, types, cut)
        names = [inp.spec.name for inp in self._in]
        ticks = bulk.stepping_rows(masks, names, self._steps_on, cut)
        if len(ticks) == 0:
            return Bulk()
        seen = bulk.tick_columns(masks, columns, self.values(), types, ticks)
        monitor = cast(BatchMonitor, self.monitor)  # _bulk: it is one
        stepped, flags = monitor.tick_until(monitor.pack_columns(seen))
        violated = [k for k, f in enumerate(flags) if f]
        last_tick_row = int(ticks[stepped - 1])
        upto = last_tick_row + 1 if violated else cut  # the rows taken
        for inp, m, column in zip(self._in, masks, columns, strict=True):
            taken = bulk.true_rows(m, upto)
            # a step clears every input's freshness; a message after the last step sets it
            inp.fresh = bool(len(taken)) and int(taken[-1]) > last_tick_row
            if not len(taken):
                continue
            last = int(taken[-1])
            inp.value, inp.has_value = coerce(column[last].item(), inp.spec.type)[0], True
            inp.last_ns = int(t[last])
            inp.messages += len(taken)
        keep = min(stepped, self.recent.maxlen or stepped)
        for k in range(stepped - keep, stepped):
            snap = {
                name: coerce(col[k].item(), vtype)[0]
                for name, col, vtype in zip(names, seen, types, strict=True)
            }
            # plain rows: a replay's record takes the whole encoding (docs/BENCHMARKS.md)
            self.recent.append({"tick": self.tick + k, **snap})
        self.tick += stepped
        self._pending_since = None
        result = None
        if violated:
            result = StepResult(self.tick - 1, int(t[last_tick_row]), violated, self.snapshot())
        return Bulk(upto, stepped, result)

    def reset_all(self) -> None:
        """Judge every requirement afresh from the next tick (operator reset)."""
        self.monitor.reset()
        if self.margin_monitor is not None:
            self.margin_monitor.reset()

    def reset_requirement(self, index: int) -> None:
        """Judge requirement ``index`` afresh from the next tick (replaces the
        thesis's node relaunch; no tick is skipped)."""
        self.monitor.reset_requirement(index)
        if self.margin_monitor is not None:
            self.margin_monitor.reset_requirement(index)

    def margins(self) -> Sequence[float]:
        """Each predicted requirement's margin after the last step, by requirement
        index (docs/reference/prediction.md, "What is fitted"): the margin monitor's."""
        margins: Sequence[float] = self.margin_monitor.margins()
        return margins
