"""Replay's fast path: a quiet stretch of a recording stepped in bulk.

While nothing but stepping can happen (no policy holds state, no timer can fall
due, every input has a value and none is stale, the values need no report), the
core would only set values and step the monitor.  Here that is done for a
stretch of messages at once: the values each tick sees come from numpy's
forward fill, the monitor is stepped in ONE C call up to the first violation
(``ss_tick_until``), and the runtime is left exactly as message-by-message
stepping leaves it.  A violating tick is handed to the policies as the core
hands it; from there the exact path goes on until things are quiet again.
Anything the fast path cannot prove quiet ends its stretch: a record or marker,
an input about to turn stale, a NaN, a value the input's type cannot hold
(docs/reference/commands.md, "replay").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from supervisor.daemon.core import Core
from supervisor.daemon.runtime import INT64_MAX, INT64_MIN, StepResult, coerce
from supervisor.tools.replay.sources import Batch

POLICIES = ("on_trigger", "on_message")  # stepped by messages alone
MIN_STRETCH = 64  # fewer rows are not worth the setup: the exact path takes them


def quiet(core: Core) -> bool:
    """Nothing but stepping can happen before the next message."""
    rt = core.session.runtime
    return (
        rt.policy in POLICIES
        and not core.supervision.active
        and rt.ready
        and not rt.stale_inputs()
        # an event is true for one step only, an age or a rate changes with time
        # alone: forward filling cannot say that
        and not any(inp.spec.event or inp.spec.kind != "value" for inp in rt._in)  # noqa: SLF001
    )


def forward(core: Core, batch: Batch, i: int, end: int, names: dict[int, list[str]]) -> int:
    """Step rows ``i``..``end - 1`` of ``batch`` (input rows only) in bulk, as far
    as they are quiet and up to the first violating tick, which goes to the
    policies.  Returns the first row not consumed (``i`` when none was)."""
    rt = core.session.runtime
    t = batch.t_ns[i:end]
    n = len(t)
    if n < MIN_STRETCH:
        return i
    inputs = rt._in  # noqa: SLF001 - the runtime's state, set here as on_values sets it
    masks, columns = [], []
    cut = n
    topic_of = {v: tid for tid, vs in names.items() for v in vs}
    for inp in inputs:
        mask, col = _column(batch, inp.spec.name, topic_of.get(inp.spec.name), i, end)
        masks.append(mask)
        columns.append(col)
        if mask is None:
            continue
        bad = _unfit(col[mask], inp.spec.type)
        if bad is not None:
            cut = min(cut, int(np.flatnonzero(mask)[bad]))
        after = rt.stale_after(inp.spec.name, core._stale_after_ns)  # noqa: SLF001
        if after is not None and inp.last_ns is not None:
            cut = min(cut, _stale_cut(inp.last_ns, t[mask], after, t))
    if cut < MIN_STRETCH:
        return i
    t = t[:cut]
    masks = [None if m is None else m[:cut] for m in masks]
    # The C type's values, converted as coerce converts them (all fit: checked above).
    columns = [
        None if c is None else c[:cut].astype(_DTYPE[inp.spec.type], copy=False)
        for c, inp in zip(columns, inputs, strict=True)
    ]
    ticks = _tick_rows(rt, masks, cut)
    if len(ticks) == 0:
        return i
    rows_at = np.arange(cut)
    last_seen = []  # per input: the row of its latest value at each tick (-1: before)
    for m in masks:
        if m is None:
            last_seen.append(None)
            continue
        seen = np.maximum.accumulate(np.where(m, rows_at, -1))
        last_seen.append(seen[ticks])
    cols = []
    for inp, seen, col in zip(inputs, last_seen, columns, strict=True):
        now = np.asarray(inp.value, dtype=_DTYPE[inp.spec.type])
        if seen is None:
            cols.append(np.full(len(ticks), now))
        else:
            cols.append(np.where(seen >= 0, col[np.maximum(seen, 0)], now))
    monitor = rt.monitor
    packed = monitor.pack_columns(cols)
    stepped, flags = monitor.tick_until(packed)
    violated = [k for k, f in enumerate(flags) if f]
    last_tick = stepped - 1
    upto = int(ticks[last_tick]) + 1 if violated else cut  # rows consumed
    _commit(core, t, masks, columns, ticks[:stepped], cols, upto, stepped)
    if violated:
        row = int(ticks[last_tick])
        inputs_now = {inp.spec.name: inp.value for inp in inputs}
        result = StepResult(rt.tick - 1, int(t[row]), violated, inputs_now)
        core._after_step(result)  # noqa: SLF001 - as Core.fields hands a step on
    return i + upto


_DTYPE = {"bool": np.bool_, "int64": np.int64, "double": np.float64}


def _column(batch: Batch, name: str, tid: int | None, i: int, end: int) -> tuple[Any, Any]:
    """Variable ``name``'s rows in ``[i, end)`` (a mask) and its values there."""
    col = batch.values.get(name)
    if col is None or tid is None:
        return None, None
    mask = batch.topic[i:end] == tid
    given = batch.given.get(name)
    if given is not None:
        mask = mask & given[i:end]
    return mask, col[i:end]


def _unfit(values: Any, vtype: str) -> int | None:
    """The first value the fast path cannot take as is: a NaN (reported), one the
    type cannot hold (rejected); None when all fit."""
    kind = values.dtype.kind
    if vtype == "double" and kind == "f":
        bad = np.isnan(values)
    elif vtype == "double" and kind in "iu":
        bad = np.zeros(len(values), dtype=bool)
    elif vtype == "int64" and kind == "i":
        bad = np.zeros(len(values), dtype=bool)
    elif vtype == "int64" and kind == "u":
        bad = values > np.uint64(INT64_MAX)
    elif vtype == "int64" and kind == "f":
        fits = np.isfinite(values) & (np.floor(values) == values)
        bad = ~(fits & (values >= INT64_MIN) & (values <= INT64_MAX))
    elif vtype == "bool" and kind == "b":
        bad = np.zeros(len(values), dtype=bool)
    elif vtype == "bool" and kind in "iu":
        bad = (values != 0) & (values != 1)
    else:  # e.g. a bool for a number: rejected, the exact path reports it
        return 0 if len(values) else None
    hits = np.flatnonzero(bad)
    return int(hits[0]) if len(hits) else None


def _stale_cut(last_ns: int, times: Any, after: int, t: Any) -> int:
    """The first row at or after which this input may have turned stale: a gap
    longer than ``after`` before one of its messages, or after its last one."""
    prev = np.concatenate(([last_ns], times))
    deadline = prev + (after + 1)
    nxt = np.concatenate((times, [np.iinfo(np.int64).max]))
    late = np.flatnonzero(nxt >= deadline)
    first = int(deadline[late[0]])  # the silence that lasts (the last one always does)
    return int(np.searchsorted(t, first, side="left"))


def _tick_rows(rt: Any, masks: list[Any], n: int) -> Any:
    """The rows after which the policy steps."""
    if rt.policy == "on_message":
        any_input = np.zeros(n, dtype=bool)
        for m in masks:
            if m is not None:
                any_input |= m
        return np.flatnonzero(any_input)
    trigger = rt._index[rt.trigger]  # noqa: SLF001
    m = masks[trigger]
    return np.flatnonzero(m) if m is not None else np.zeros(0, dtype=np.intp)


def _commit(
    core: Core,
    t: Any,
    masks: list[Any],
    columns: list[Any],
    ticks: Any,
    tick_values: list[Any],
    upto: int,
    stepped: int,
) -> None:
    """The runtime as stepping rows ``0..upto-1`` one by one leaves it."""
    rt = core.session.runtime
    last_tick_row = int(ticks[-1]) if len(ticks) else -1
    for inp, m, col in zip(rt._in, masks, columns, strict=True):  # noqa: SLF001
        if m is None:
            continue
        rows = np.flatnonzero(m[:upto])
        if len(rows) == 0:
            continue
        last = int(rows[-1])
        value, _why = coerce(col[last].item(), inp.spec.type)
        inp.value, inp.has_value, inp.last_ns = value, True, int(t[last])
        inp.messages += len(rows)
    for inp, m in zip(rt._in, masks, strict=True):  # noqa: SLF001
        # a step clears every input's freshness; a message after the last step sets it
        rows = np.flatnonzero(m[:upto]) if m is not None else np.zeros(0, dtype=np.intp)
        inp.fresh = bool(len(rows)) and int(rows[-1]) > last_tick_row
    names = [inp.spec.name for inp in rt._in]  # noqa: SLF001
    keep = min(stepped, rt.recent.maxlen or stepped)
    for k in range(stepped - keep, stepped):
        snap = {
            name: coerce(col[k].item(), inp.spec.type)[0]
            for name, col, inp in zip(names, tick_values, rt._in, strict=True)  # noqa: SLF001
        }
        rt.recent.append({"tick": rt.tick + k, **snap})
    rt.tick += stepped
    rt._pending_since = None  # noqa: SLF001
    core.now = int(t[upto - 1])
    core._due = 0  # noqa: SLF001 - the next deadline is computed afresh
