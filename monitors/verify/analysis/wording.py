"""Small helpers for the findings' messages."""

from __future__ import annotations

from collections.abc import Iterable


def and_list(items: Iterable[str]) -> str:
    """'a, b and the range of x' for requirement ids and 'range:NAME' items."""
    out = []
    for i in items:
        out.append(f"the range of {i[6:]}" if i.startswith("range:") else i)
    if len(out) <= 1:
        return "".join(out)
    return ", ".join(out[:-1]) + " and " + out[-1]


def ticks(n: int) -> str:
    return f"{n} tick{'' if n == 1 else 's'}"


def first_false(v: list[bool]) -> int | None:
    """The tick of the first false verdict (where a note says a violation bites)."""
    return next((t for t, x in enumerate(v) if not x), None)
