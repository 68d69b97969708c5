"""The ``limits:`` section: how much memory and time ``check`` may spend on one config,
and how far ``replay`` may inflate one chunk of a bag.

A time bound is paid for in monitor state and in analysis size, so a typo such as
``within 100000 hours`` must be refused before anything is built
(docs/reference/config.md, limits; docs/reference/faults.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from supervisor.config.fields import as_mapping, check_keys, number
from supervisor.config.imported import (  # the bounds of the files, fixed, beside the settings
    MAX_CONFIG_BYTES,
    MAX_FORMULA_CHARS,
    MAX_ID_CHARS,
    MAX_IMPORT_BYTES,
    MAX_IMPORT_DEPTH,
    MAX_TEXT_CHARS,
)
from supervisor.config.yamlload import LineDict

LIMITS_KEYS = {
    "monitor_memory_mb",
    "analysis_budget_s",
    "analysis_memory_mb",
    "replay_chunk_mb",
    "replay_ratio",
}
MAXIMA = {"replay_chunk_mb": 65536.0, "replay_ratio": 1e6}
MB = 1 << 20


__all__ = [
    "MAX_CONFIG_BYTES",
    "MAX_FORMULA_CHARS",
    "MAX_ID_CHARS",
    "MAX_IMPORT_BYTES",
    "MAX_IMPORT_DEPTH",
    "MAX_TEXT_CHARS",
    "Limits",
    "load_limits",
]


@dataclass(frozen=True)
class Limits:
    # Static state of the compiled monitor (all requirements together).
    monitor_memory_mb: float = 64.0
    # Wall-clock time of all the analyses of one check/explain together; the unit's
    # TimeoutStartSec (60 s) has to cover check and the start of run.
    analysis_budget_s: float = 30.0
    # What z3 may hold during the analyses (its max_memory); reached, the analysis
    # running stops and the later ones are skipped, said as such.
    analysis_memory_mb: float = 512.0
    # One chunk of a bag as replay and report --bag inflate it: its size, and that
    # size over the compressed one (docs/reference/faults.md, "Trust"; a bag is input
    # anybody could have written).
    replay_chunk_mb: float = 64.0
    replay_ratio: float = 100.0
    line: int | None = None  # of 'limits:' (for errors about the whole monitor)

    @property
    def monitor_memory_bytes(self) -> int:
        return int(self.monitor_memory_mb * MB)

    @property
    def replay_chunk_bytes(self) -> int:
        return int(self.replay_chunk_mb * MB)


def load_limits(doc: LineDict) -> Limits:
    raw = doc.get("limits")
    if raw is None:
        return Limits()
    s = as_mapping(raw, doc, "limits", "limits")
    check_keys(s, LIMITS_KEYS, "limits")
    values: dict[str, float] = {}
    for key in sorted(LIMITS_KEYS):
        v = number(s, key, "limits", **({"maximum": MAXIMA[key]} if key in MAXIMA else {}))
        if v is not None:
            values[key] = v
    return Limits(**values, line=doc.key_line("limits"))
