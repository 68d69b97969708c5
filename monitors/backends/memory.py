"""The monitor's static memory, known from the spec before any C is written.

Every bound the generated C pays for per tick (a delay line of one byte per tick
of a lower time bound) is sized here from the native backend's own layout
(``c99.state_bytes``), so a requirement that would need gigabytes is refused at
its line instead of being generated, compiled and mapped (docs/reference/faults.md).
The Copilot backend's state is no larger, within a few bytes per temporal
operator: it delays by the same lower bounds with one ``bool`` per tick and
shares temporal streams between requirements, so the one check serves both.
"""

from __future__ import annotations

from collections.abc import Mapping

from monitors.backends.c99 import state_bytes
from monitors.errors import UserError
from monitors.ir.formula import max_bound
from monitors.ir.spec import MonitorSpec

Where = tuple[str, int | None]  # (file, line)


def human_bytes(n: float) -> str:
    """1536 -> '1.5 kB'; binary multiples, as the limits are given in MB."""
    for unit in ("bytes", "kB", "MB", "GB", "TB", "PB"):
        if n < 1024 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError


def memory_errors(
    spec: MonitorSpec,
    limit_bytes: int,
    where: Mapping[str, Where],
    whole: Where,
    setting: str,
) -> list[tuple[str | None, UserError]]:
    """(requirement id, error) for each requirement whose state alone exceeds
    ``limit_bytes`` (at its ``where``), else (None, error) for the monitor as a whole
    (at ``whole``) if all of them together do.  ``setting`` names the knob that raises
    the limit.  Raises the generator's own UserError (a reserved C name, ...)."""
    sizes = state_bytes(spec)
    limit = human_bytes(limit_bytes)
    errors: list[tuple[str | None, UserError]] = []
    for r in spec.requirements:
        n = sizes[r.id]
        if n <= limit_bytes:
            continue
        file, line = where.get(r.id, whole)
        errors.append(
            (
                r.id,
                UserError(
                    f"requirement '{r.id}' needs {human_bytes(n)} of monitor state, limit {limit} "
                    f"({setting}): a delay line keeps one byte per tick of a lower time "
                    f"bound, and its largest bound is {max_bound(r.formula)} ticks",
                    file=file,
                    line=line,
                    hint=f"use a longer tick (step.period_ms), a shorter time bound, or raise "
                    f"{setting}",
                ),
            )
        )
    total = sum(sizes.values())
    if not errors and total > limit_bytes:
        biggest = sorted(sizes, key=lambda rid: -sizes[rid])[:3]
        errors.append(
            (
                None,
                UserError(
                    f"the monitor needs {human_bytes(total)} of state for its "
                    f"{len(sizes)} requirements, limit {limit} ({setting}); largest: "
                    + ", ".join(f"{rid} {human_bytes(sizes[rid])}" for rid in biggest),
                    file=whole[0],
                    line=whole[1],
                    hint=f"use a longer tick (step.period_ms), shorter time bounds, or raise {setting}",
                ),
            )
        )
    return errors
