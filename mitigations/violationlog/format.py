"""The violation log's on-disk format: record layout, hash chain, one-line rendering.

Format (written by :mod:`mitigations.violationlog.writer`, read by :mod:`mitigations.violationlog.reader`): JSON lines, ASCII, one object per
line, ``\\n``-terminated.  Every record starts with ``ts``, ``event``,
``component``, ``config_sha256``, ``prev_sha256``, ``seq`` and ends with ``line_sha256``.

``seq`` numbers the records one writer makes (1, 2, ...; across rotated files; a new
writer starts at 1).  A gap is accounted for by the ``supervisor`` record
``what=records_lost`` that follows it, naming the missing numbers (docs/reference/log.md).

Hash chain, per file:

* ``prev_sha256`` is the SHA-256 (hex) of the previous line's bytes including
  its newline; the first line of a file carries the hash of the empty string.
  Each file therefore verifies on its own (logrotate may compress or delete
  older files without breaking the newer ones).
* ``line_sha256`` is the SHA-256 of the line itself (including the newline)
  with this field's value replaced by 64 zeros.  It lets ``--verify`` name the
  line that was edited, rather than the line after it.
* Across rotation the files are linked, not chained: after ``reopen()`` the
  writer's first record in the (new) file is a ``supervisor`` record
  ``what="log_reopened"`` whose ``previous_last_sha256`` is the hash of the
  last line written to the old file.  ``--verify old new`` reports the link.
* A line left incomplete by a crash or a full disk is terminated by the writer
  when it next writes, and the next record chains over it, so such a line in
  the middle of a file is a warning, not a break.  An incomplete *final* line
  cannot be told from a truncated file and fails verification.

What the chain cannot show: a file whose last whole lines were removed (unless
a later file's link names them), or a file rewritten from scratch by someone
who recomputes the hashes; it has no key.

Non-finite floats, which JSON lacks, are written as the strings ``"nan"``,
``"inf"`` and ``"-inf"``.

This package uses the standard library only (the writer adds structlog), so the CLI stays quick to start.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping
from typing import Any

HEADER = ("ts", "event", "component", "config_sha256", "prev_sha256", "seq")
EMPTY_SHA256 = hashlib.sha256(b"").hexdigest()
ZERO_SHA256 = "0" * 64
EVENTS = ("violation", "mitigation", "reset", "supervisor")
RETRY_BUFFER = 1000  # records kept in memory while the log cannot be written (default)

_LINE_HASH_RE = re.compile(rb',"line_sha256":"([0-9a-f]{64})"\}\n\Z')
_PREV_RE = re.compile(rb'"prev_sha256":"([0-9a-f]{64})"')


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def seal_line(body: bytes) -> bytes:
    """Append ``line_sha256`` to a rendered JSON object ``{...}`` (no newline)."""
    assert body.endswith(b"}")
    placeholder = body[:-1] + b',"line_sha256":"' + ZERO_SHA256.encode() + b'"}\n'
    digest = sha256_hex(placeholder).encode()
    return placeholder[: -len(ZERO_SHA256) - 3] + digest + b'"}\n'


def line_seal_ok(line: bytes) -> bool | None:
    """True/False when the line carries a ``line_sha256``; None when it has none."""
    m = _LINE_HASH_RE.search(line)
    if m is None:
        return None
    zeroed = line[: m.start(1)] + ZERO_SHA256.encode() + line[m.end(1) :]
    return sha256_hex(zeroed) == m.group(1).decode()


def json_safe(value: Any) -> Any:
    """JSON has no NaN/Infinity: write them as the strings "nan", "inf", "-inf"."""
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [json_safe(v) for v in value]
    return value


def _fmt_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def details(rec: dict[str, Any]) -> str:
    """The event-specific part of a record, as ``key=value`` words."""
    ev = rec.get("event")
    if ev == "violation":
        parts = [f"tick={rec.get('tick')}"]
        parts += [f"{k}={_fmt_value(v)}" for k, v in (rec.get("inputs") or {}).items()]
        if rec.get("stale"):
            parts.append("stale=" + ",".join(map(str, rec["stale"])))
        return " ".join(parts)
    if ev == "mitigation":
        res = "ok" if rec.get("ok") else f"FAILED ({rec.get('error')})"
        return (
            f"{rec.get('kind')}:{rec.get('action')} {res} "
            f"latency_ms={rec.get('latency_ms')} attempt={rec.get('attempt')}"
        )
    if ev == "reset":
        return f"reason={rec.get('reason')}"
    skip = {*HEADER, "line_sha256", "what"}
    extra = [f"{k}={_fmt_value(v)}" for k, v in rec.items() if k not in skip and k[:1] != "_"]
    return " ".join([str(rec.get("what"))] + extra)


def describe(rec: dict[str, Any]) -> str:
    """One human-readable line for a record (stderr/journald), e.g.
    ``VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2``."""
    label = str(rec.get("event", "?")).upper()
    req = rec.get("requirement")
    return f"{label} {req} {details(rec)}" if req else f"{label} {details(rec)}"
