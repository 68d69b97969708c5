"""The ``logging:`` section: where the violation log goes, how much context a record
keeps, how many records wait in memory while the log cannot be written, and when a
violation record is fsynced relative to its actions (docs/reference/config.md)."""

from __future__ import annotations

from mitigations.violationlog.format import DURABILITIES, DURABILITY, RETRY_BUFFER
from supervisor.config.fields import as_mapping, check_keys, error_at, whole_number
from supervisor.config.yamlload import LineDict

# stderr is accepted and not read: the daemon's warnings always go to stderr.
LOG_KEYS = {"violations", "recent", "stderr", "retry_buffer", "durability"}
# retry_buffer: records kept in memory while the log cannot be written; at a few KB
# each, a million is the most that is still a bounded amount of memory.
MAX_RETRY = 1_000_000
# recent: ticks of context each violation record carries (kept in memory per input).
MAX_RECENT = 10_000
RECENT = 10  # the default


def load_violation_log(doc: LineDict) -> tuple[str | None, int, int]:
    """(the violation log's path or None for the default, ticks of ``recent`` per
    record, records kept in memory while the log cannot be written)."""
    logging = as_mapping(doc.get("logging") or LineDict(), doc, "logging", "logging")
    if logging:
        check_keys(logging, LOG_KEYS, "logging")
    recent = whole_number(
        logging, "recent", "logging", default=RECENT, minimum=0, maximum=MAX_RECENT
    )
    retry_buffer = whole_number(
        logging, "retry_buffer", "logging", default=RETRY_BUFFER, minimum=1, maximum=MAX_RETRY
    )
    log_path = logging.get("violations")
    return (str(log_path) if log_path else None), recent, retry_buffer


def load_durability(doc: LineDict) -> str:
    """``logging.durability``: after_publish (the default) or before_action."""
    logging = doc.get("logging") or LineDict()
    value = logging.get("durability", DURABILITY) if isinstance(logging, dict) else DURABILITY
    if not isinstance(value, str) or value not in DURABILITIES:
        raise error_at(
            f"logging.durability must be one of {', '.join(DURABILITIES)}, not {value!r}",
            logging,
            "durability",
            "after_publish: the halt goes out before the fsync; before_action: the "
            "record is on disk before any action (docs/reference/log.md)",
        )
    return value
