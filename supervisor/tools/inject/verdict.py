"""Checking the running supervisor's violation log for what an injection should
have made it report."""

from __future__ import annotations

from pathlib import Path

from mitigations.violationlog.reader import records_since
from supervisor.tools.inject.report import and_list


def log_size(path: Path) -> int:
    """Where the records an injection causes will start."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def violations_since(path: Path, offset: int) -> list[str]:
    """Requirement ids of the ``violation`` records written after byte ``offset``."""
    records, _ = records_since(path, offset)
    return [
        rec["requirement"]
        for rec in records
        if rec.get("event") == "violation" and isinstance(rec.get("requirement"), str)
    ]


def logged(ids: list[str]) -> str:
    """'a x2, b' (or 'none')."""
    counts: dict[str, int] = {}
    for i in ids:
        counts[i] = counts.get(i, 0) + 1
    return ", ".join(f"{i} x{c}" if c > 1 else i for i, c in counts.items()) or "none"


def verdict(got: list[str], expected: set[str], once: bool) -> str:
    """'ok' when the log has exactly the expected violations (each logged once when
    ``once``: the step policy steps once per tick), else 'MISMATCH: ...'."""
    if set(got) == expected and (not once or len(got) == len(expected)):
        return "ok"
    if not got:
        return "MISMATCH: nothing logged"
    if set(got) - expected:
        return f"MISMATCH: also {and_list(sorted(set(got) - expected))}"
    if expected - set(got):
        return f"MISMATCH: missing {and_list(sorted(expected - set(got)))}"
    return "MISMATCH: logged more than once"
