"""What ``inject`` prints: a trace as a table, one row per tick, and what an
injection does."""

from __future__ import annotations

import math
from collections.abc import Sequence

from monitors.verify.interpret import Value
from supervisor.tools.inject.injection import Injection
from supervisor.tools.inject.target import Target


def fmt_value(v: Value) -> str:
    """A value as the tables print it (true/false, nan, repr of floats)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def and_list(items: Sequence[str]) -> str:
    """'a, b and c'."""
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def trace_table(
    inj: Injection, names: Sequence[str], extra: Sequence[Sequence[str]] | None = None
) -> list[str]:
    """One row per tick, one column per variable (changed values marked '*'), then the
    requirements the interpreter finds violated at that tick."""
    head = ["tick", *names, "violated"]
    rows = []
    for t, state in enumerate(inj.trace):
        cells = [str(t)]
        for n in names:
            mark = "*" if t and state[n] != inj.trace[t - 1][n] else ""
            cells.append(fmt_value(state[n]) + mark)
        cells.append(", ".join(inj.tick_violations[t]) or "-")
        rows.append(cells)
    if extra:
        head = [head[0], "at_ms", *head[1:]]
        rows = [[r[0], *e, *r[1:]] for r, e in zip(rows, extra, strict=True)]
    return columns(head, rows)


def columns(head: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """Left-aligned columns, two spaces apart (no cell contains two spaces)."""
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(head)]
    out = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip()]
    for r in rows:
        out.append("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    return out


def describe(inj: Injection, target: Target) -> list[str]:
    """Two lines: the requirement, then the ticks and how the step policy sees them."""
    sch = target.schedule
    how = {
        "on_trigger": f"each tick: the other topics, then {target.cfg.step.trigger} "
        "(on_trigger: the trigger ends the tick)",
        "synchronized": "each tick: every topic once (synchronized)",
        "periodic": "each tick held for 2 periods, every topic at the period (periodic)",
        "on_message": "each tick: every topic in turn, one step per message (on_message)",
    }[sch.policy]
    clean = not inj.broken and not inj.broken_ranges
    what = (
        f"tick {inj.k - 1} violates {inj.req} and nothing else"
        if clean
        else f"tick {inj.k - 1} violates {inj.req}; the supervisor should log {and_list(inj.expected)}"
    )
    return [f"{inj.req}: {inj.text}", f"{inj.k} ticks; {what}; {how}"]
