"""Crafted violation logs for the trust-boundary tests: any record content, with the
hash chain recomputed as mitigations/violationlog/format.py defines it, so that a
log verifies whatever its records hold (the chain has no key: anyone can do this)."""

from __future__ import annotations

import json
from typing import Any

from mitigations.violationlog.format import EMPTY_SHA256, seal_line, sha256_hex

CONFIG_SHA = "ab" * 32
DEEP = "[" * 10_000 + "]" * 10_000  # deeper than any JSON parser's recursion


def record(event: str, seq: int = 0, **fields: Any) -> dict[str, Any]:
    """A well-formed record of ``event`` (the header as the writer makes it), with
    ``fields`` added or overriding; ``seq`` 0: numbered by :func:`chain`."""
    rec: dict[str, Any] = {
        "ts": f"2026-11-21T14:00:{seq % 60:02d}.000000Z",
        "event": event,
        "component": "R",
        "config_sha256": CONFIG_SHA,
        "prev_sha256": "",
        "seq": seq,
    }
    if event == "violation":
        rec |= {
            "requirement": "limit",
            "text": "R shall always satisfy speed <= 2.0",
            "formula": "(H (speed <= 2.0))",
            "tick": 2,
            "inputs": {"speed": 2.5},
            "recent": [{"tick": 1, "speed": 1.0}, {"tick": 2, "speed": 2.5}],
            "stale": [],
        }
    elif event == "mitigation":
        rec |= {
            "requirement": "limit",
            "action": "note",
            "kind": "log",
            "ok": True,
            "error": None,
            "latency_ms": 0.5,
            "attempt": 1,
        }
    elif event == "reset":
        rec |= {"requirement": "limit", "reason": "after_mitigation", "tick": 3}
    else:
        rec |= {"what": "start", "config": "/nonexistent/r.yaml", "pid": 1}
    for k, v in fields.items():
        rec[k] = v
    return rec


def chain(records: list[dict[str, Any]], raw: dict[str, str] | None = None) -> bytes:
    """The records as a log file whose hash chain and seals verify; ``raw``: JSON
    text put in place of a string value (``"@deep"`` -> 10,000 nested lists), for
    what ``json.dumps`` cannot write."""
    out: list[bytes] = []
    prev = EMPTY_SHA256
    for i, rec in enumerate(records, 1):
        rec = dict(rec)
        rec["prev_sha256"] = prev
        if not rec.get("seq") and "seq" in rec:
            rec["seq"] = i
        rec.pop("line_sha256", None)
        body = json.dumps(rec, separators=(",", ":"), ensure_ascii=True, allow_nan=True)
        for placeholder, text in (raw or {}).items():
            body = body.replace(json.dumps(placeholder), text)
        line = seal_line(body.encode("ascii"))
        prev = sha256_hex(line)
        out.append(line)
    return b"".join(out)
