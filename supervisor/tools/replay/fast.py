"""Replay's fast path: a stretch of a recording handed to the core in bulk.

The rows of a batch become the runtime's :class:`~supervisor.daemon.runtime.Rows`
(per input, the rows its topic's messages set and their values) and go to
:meth:`Core.rows <supervisor.daemon.core.Core.rows>`, which steps them with the
daemon's own step policy (``Runtime.step_rows``) as far as they are quiet: the
monitor in ONE C call up to the first violation, which goes to the policies as
the core hands any step on.  What it does not take, the exact path steps message
by message (docs/reference/commands.md, "replay").  Nothing here decides when
the monitor steps: that is the runtime's alone.
"""

from __future__ import annotations

from typing import Any

from supervisor.daemon.core import Core
from supervisor.daemon.runtime import Rows
from supervisor.tools.replay.sources import Batch

MIN_STRETCH = 64  # fewer rows are not worth the setup: the exact path takes them


def quiet(core: Core) -> bool:
    """The core would take rows in bulk now (asked before building them)."""
    return core.quiet()


def forward(core: Core, batch: Batch, i: int, end: int, names: dict[int, list[str]]) -> int:
    """Step rows ``i``..``end - 1`` of ``batch`` (input rows only) in bulk, as far
    as they are quiet and up to the first violating tick, which goes to the
    policies.  Returns the first row not consumed (``i`` when none was)."""
    if end - i < MIN_STRETCH:
        return i
    values: dict[str, tuple[Any, Any]] = {}
    for tid, variables in names.items():
        rows = batch.topic[i:end] == tid
        for name in variables:
            column = batch.values.get(name)
            if column is None:
                continue
            given = batch.given.get(name)
            values[name] = (rows if given is None else rows & given[i:end], column[i:end])
    return i + core.rows(Rows(batch.t_ns[i:end], values), min_rows=MIN_STRETCH)
