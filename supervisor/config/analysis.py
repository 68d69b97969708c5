"""The ``analysis:`` section: the trace length, z3's resource limit and the
wall-clock cap per solver call, and
whether ``check``, ``run`` and reload analyse at all (docs/reference/config.md).

Read with the rest of the file, so that its errors carry their line without the
file being read again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from monitors.errors import UserError
from monitors.verify.analysis.requirements import DEFAULT_RLIMIT, DEFAULT_TIMEOUT_S
from supervisor.config.fields import as_mapping
from supervisor.config.yamlload import LineDict

ANALYSIS_KEYS = {"k", "rlimit", "timeout_s", "enabled"}
MAX_K = 100_000  # ticks; far past what the analyses' memory limit lets run
MAX_RLIMIT = 2**32 - 1  # z3 takes the resource limit as an unsigned 32-bit number


@dataclass(frozen=True)
class AnalysisConfig:
    k: int | None = None  # None: the analyses' default_k
    timeout_s: float = DEFAULT_TIMEOUT_S  # wall-clock cap per solver call (a safety net)
    enabled: bool = True
    rlimit: int = DEFAULT_RLIMIT  # z3 resource units per solver call (deterministic)


def load_analysis(doc: LineDict, file: str) -> AnalysisConfig:
    """The section's settings; an unknown key or a bad value is an error at its line."""
    sec = as_mapping(doc.get("analysis") or {}, doc, "analysis", "analysis")

    def line(key: str) -> int | None:
        if isinstance(sec, LineDict):
            return sec.key_line(key)
        return doc.key_line("analysis") if isinstance(doc, LineDict) else None

    for key in sec:
        if key not in ANALYSIS_KEYS:
            raise UserError(
                f"unknown key '{key}' in analysis",
                file=file,
                line=line(key),
                hint=f"known keys: {', '.join(sorted(ANALYSIS_KEYS))}",
            )
    k: Any = sec.get("k")
    if k is not None:
        try:
            k = int(str(k))
        except ValueError:
            k = 0
        if not 1 <= k <= MAX_K:
            raise UserError(
                f"analysis.k must be a whole number of ticks from 1 to {MAX_K}",
                file=file,
                line=line("k"),
            )
    timeout: Any = sec.get("timeout_s", DEFAULT_TIMEOUT_S)
    try:
        timeout = float(str(timeout))
    except ValueError:
        timeout = -1.0
    if not timeout > 0 or math.isinf(timeout):
        raise UserError(
            "analysis.timeout_s must be a positive number of seconds",
            file=file,
            line=line("timeout_s"),
        )
    rlimit: Any = sec.get("rlimit", DEFAULT_RLIMIT)
    try:
        rlimit = int(str(rlimit))
    except ValueError:
        rlimit = 0
    if not 1 <= rlimit <= MAX_RLIMIT:
        raise UserError(
            f"analysis.rlimit must be a whole number of z3 resource units from 1 to {MAX_RLIMIT}",
            file=file,
            line=line("rlimit"),
        )
    enabled = str(sec.get("enabled", True)).lower() not in ("false", "no", "0", "off")
    return AnalysisConfig(k, timeout, enabled, rlimit)
