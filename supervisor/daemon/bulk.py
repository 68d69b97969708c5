"""Array helpers of :meth:`Runtime.step_rows <supervisor.daemon.runtime.Runtime.step_rows>`.

Pure functions of numpy arrays, no runtime state and no step policy: the runtime
decides which rows step (its own ``_steps_on``, asked once per distinct set of
inputs a row carries) and keeps its state; these only find where a batch stops
being quiet and what values each step sees.  numpy is imported here, never by
``runtime.py`` itself, so the daemon's core loads it only when a batch comes
(docs/ARCHITECTURE.md, "where to add a step policy").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1
DTYPE = {"bool": np.bool_, "int64": np.int64, "double": np.float64}
# Up to this many inputs a row's set of inputs is a small integer, counted with
# bincount; more inputs fall back to sorting the rows' masks.
_SMALL = 16


def unfit(values: Any, vtype: str) -> int | None:
    """The first value a bulk step cannot take as ``coerce`` would without a word:
    a NaN (reported), one the type cannot hold (rejected); None when all fit."""
    kind = values.dtype.kind
    if vtype == "double" and kind == "f":
        bad = np.isnan(values)
    elif (vtype == "double" and kind in "iu") or (vtype == "int64" and kind == "i"):
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
    else:  # e.g. a bool for a number: rejected, the message-by-message path reports it
        return 0 if len(values) else None
    hits = np.flatnonzero(bad)
    return int(hits[0]) if len(hits) else None


def stale_cut(last_ns: int, times: Any, after: int, t: Any) -> int:
    """The first row at or after which an input may have turned stale: a gap
    longer than ``after`` before one of its messages (``times``), or after its last
    one.  ``t``: every row's time."""
    prev = np.concatenate(([last_ns], times))
    deadline = prev + (after + 1)
    nxt = np.concatenate((times, [np.iinfo(np.int64).max]))
    late = np.flatnonzero(nxt >= deadline)
    first = int(deadline[late[0]])  # the silence that lasts (the last one always does)
    return int(np.searchsorted(t, first, side="left"))


def stepping_rows(
    masks: Sequence[Any | None],
    names: Sequence[str],
    steps_on: Callable[[list[str]], bool],
    n: int,
) -> Any:
    """The rows after which the monitor steps: ``steps_on`` (the runtime's own
    decision for one message) asked once per distinct set of inputs the rows
    carry, its answer spread over the rows with that set."""
    given = [(k, m) for k, m in enumerate(masks) if m is not None]
    if not given:
        return np.zeros(0, dtype=np.intp)

    def decide(on: Sequence[bool]) -> bool:
        return steps_on([names[k] for (k, _m), hit in zip(given, on, strict=True) if hit])

    if len(given) <= _SMALL:
        # each row's set of inputs as the bits of a small integer
        dtype = np.uint8 if len(given) <= 8 else np.uint16
        code = np.zeros(n, dtype=dtype)
        for bit, (_k, m) in enumerate(given):
            code |= m.view(np.uint8).astype(dtype, copy=False) << dtype(bit)
        seen = np.zeros(1 << len(given), dtype=bool)
        seen[code] = True
        table = np.zeros(len(seen), dtype=bool)
        for c in np.flatnonzero(seen):
            table[c] = decide([bool(c >> bit & 1) for bit in range(len(given))])
        return np.flatnonzero(table.take(code))
    # more inputs: each row's set as its packed bits, the distinct sets by sorting
    bits = np.packbits(np.stack([m for _k, m in given], axis=1), axis=1, bitorder="little")
    rows = np.ascontiguousarray(bits).view(np.dtype((np.void, bits.shape[1]))).reshape(-1)
    kinds, which = np.unique(rows, return_inverse=True)
    table = np.zeros(len(kinds), dtype=bool)
    for c, kind in enumerate(kinds):
        on = np.unpackbits(np.frombuffer(kind.tobytes(), dtype=np.uint8), bitorder="little")
        table[c] = decide([bool(x) for x in on[: len(given)]])
    return np.flatnonzero(table.take(which.reshape(-1)))


def nth_true(mask: Any, k: int) -> int:
    """The row of the ``k``-th true entry of ``mask``."""
    return int(np.flatnonzero(mask)[k])


def true_rows(mask: Any | None, upto: int) -> Any:
    """The rows before ``upto`` where ``mask`` is true (none for no mask)."""
    return np.zeros(0, dtype=np.intp) if mask is None else np.flatnonzero(mask[:upto])


def typed(columns: Sequence[Any | None], types: Sequence[str], n: int) -> list[Any | None]:
    """The first ``n`` values of each column as its input's C type, converted as
    ``coerce`` converts them (that they fit is :func:`unfit`'s to check)."""
    return [
        None if c is None else c[:n].astype(DTYPE[vtype], copy=False)
        for c, vtype in zip(columns, types, strict=True)
    ]


def tick_columns(
    masks: Sequence[Any | None],
    columns: Sequence[Any | None],
    now: Sequence[Any],
    types: Sequence[str],
    ticks: Any,
) -> list[Any]:
    """Per input, the value each step in ``ticks`` sees: its latest value in the
    rows up to that step (a forward fill), else ``now``, its value before them."""
    out = []
    rows_at = None
    for m, col, value, vtype in zip(masks, columns, now, types, strict=True):
        before = np.asarray(value, dtype=DTYPE[vtype])
        if m is None:
            out.append(np.full(len(ticks), before))
            continue
        if rows_at is None:
            rows_at = np.arange(len(m))
        seen = np.maximum.accumulate(np.where(m, rows_at, -1))[ticks]
        out.append(np.where(seen >= 0, col[np.maximum(seen, 0)], before))
    return out
