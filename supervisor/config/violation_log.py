"""The ``logging:`` section: where the violation log goes, and how much context a record keeps."""

from __future__ import annotations

from supervisor.config.fields import as_mapping, check_keys, error_at
from supervisor.config.yamlload import LineDict

# stderr is accepted and not read: the daemon's warnings always go to stderr.
LOG_KEYS = {"violations", "recent", "stderr"}


def load_violation_log(doc: LineDict) -> tuple[str | None, int]:
    """(the violation log's path or None for the default, ticks of ``recent`` per record)."""
    logging = as_mapping(doc.get("logging") or LineDict(), doc, "logging", "logging")
    if logging:
        check_keys(logging, LOG_KEYS, "logging")
    recent = int(logging.get("recent", 10)) if str(logging.get("recent", 10)).isdigit() else None
    if recent is None:
        raise error_at("logging.recent must be a whole number of ticks", logging, "recent")
    log_path = logging.get("violations")
    return (str(log_path) if log_path else None), recent
